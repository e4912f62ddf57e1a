"""A tiny stand-in for ``mrsph.simulation.Simulation``: same public surface, toy physics.

Used by the app tests and for developing the renderer without the real solver. The
fluid is a block on a lattice whose spacing doubles per level (finest at the free
surface, coarsest at the bottom), with a few virtual particles at the level
interfaces; ``advance_frame`` moves it ballistically with damped wall bounces, enough
to make videos move. It is not SPH and never claims to be.
"""

from __future__ import annotations

import time

import numpy as np

from mrsph.io.snapshot import Snapshot

# The stand-in produces the real snapshot type (Taichi-free, mrsph/io/snapshot.py).
FakeSnapshot = Snapshot


class FakeSimulation:
    """Stand-in with the Simulation API: advance_frame, step, reset, snapshot,
    set_param, set_disturbance, dim, levels, scene."""

    REST_DENSITY = 1000.0

    def __init__(
        self,
        dim: int = 2,
        levels: int = 3,
        spacing: float | None = None,
        fps: float = 30.0,
        seed: int = 0,
        obstacles: bool = True,
        build_s: float = 0.0,
    ):
        time.sleep(build_s)  # as long as a real scene's build, where a test asks
        self.dim, self.levels, self.fps = dim, levels, fps
        self.seed = seed
        if dim == 2:
            self.domain_min, self.domain_max = np.array([0.0, 0.0]), np.array([2.0, 1.0])
            self.block = (np.array([0.05, 0.02]), np.array([0.95, 0.75]))
            self.obstacles = (
                [
                    {"shape": "sphere", "center": (1.45, 0.22), "radius": 0.12},
                    {"shape": "box", "min": (1.75, 0.0), "max": (1.85, 0.35)},
                ]
                if obstacles
                else []
            )
            self.spacing0 = spacing or 0.008
        else:
            self.domain_min, self.domain_max = np.array([0.0, 0.0, 0.0]), np.array([1.2, 0.7, 0.6])
            self.block = (np.array([0.03, 0.02, 0.03]), np.array([0.5, 0.5, 0.57]))
            self.obstacles = (
                [
                    {"shape": "sphere", "center": (0.85, 0.12, 0.3), "radius": 0.1},
                    {"shape": "box", "min": (1.0, 0.0, 0.1), "max": (1.1, 0.25, 0.25)},
                ]
                if obstacles
                else []
            )
            self.spacing0 = spacing or 0.014
        self.scene = {"name": f"fake_{dim}d", "run": {"fps": fps}}
        self.gravity = np.zeros(dim)
        self.gravity[1] = -9.81
        self.params = {"fluid.viscosity": 0.01, "fluid.stiffness": 50.0, "pbf.xsph": 0.1, "adaptivity.enabled": True}
        self.disturbance = None
        self.steps_per_frame = 4
        self.reset()

    # -- setup -----------------------------------------------------------------------
    def reset(self) -> None:
        rng = np.random.default_rng(self.seed)
        lo, hi = self.block
        height = hi[1] - lo[1]
        xs, levels, kinds = [], [], []
        for lvl in range(self.levels):
            s = self.spacing0 * 2**lvl
            axes = [np.arange(lo[k] + s / 2, hi[k], s) for k in range(self.dim)]
            grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, self.dim)
            # Depth below the top of the block in "bands": band b holds level b, so the
            # top of the block is finest. Interfaces lie at whole band depths.
            depth = (hi[1] - grid[:, 1]) / height * self.levels
            band = np.clip(depth.astype(int), 0, self.levels - 1)
            mine = band == lvl
            xs.append(grid[mine])
            levels.append(np.full(mine.sum(), lvl))
            kinds.append(np.zeros(mine.sum(), int))
            # Virtual particles of this level, one spacing deep across each interface.
            for other, code in ((lvl - 1, 4), (lvl + 1, 5)):
                if 0 <= other < self.levels:
                    interface = max(lvl, other)
                    near = (band == other) & (np.abs(depth - interface) * height / self.levels < s)
                    xs.append(grid[near])
                    levels.append(np.full(near.sum(), lvl))
                    kinds.append(np.full(near.sum(), code))
        self.x = np.concatenate(xs).astype(np.float64)
        self.x += rng.normal(scale=0.05 * self.spacing0, size=self.x.shape)  # break the symmetry
        self.level = np.concatenate(levels).astype(np.int32)
        self.kind = np.concatenate(kinds).astype(np.int32)
        # A few transient states so the "kind" colour mode has something to show.
        real = np.nonzero(self.kind == 0)[0]
        self.kind[rng.choice(real, size=len(real) // 50, replace=False)] = rng.integers(1, 4, len(real) // 50)
        self.v = np.zeros_like(self.x)
        self.time, self.frame = 0.0, 0
        self.splits = self.merges = 0

    # -- Simulation API ------------------------------------------------------------------
    @property
    def radius(self) -> np.ndarray:
        return np.array([0.5 * self.spacing0 * 2**l for l in range(self.levels)])

    def set_param(self, key: str, value) -> None:
        if key == "physics.gravity":
            self.gravity = np.asarray(value, dtype=np.float64)
        elif key in self.params:
            self.params[key] = value
        else:
            raise KeyError(f"unknown parameter {key!r}")

    def set_disturbance(self, d) -> None:
        self.disturbance = d

    def step(self) -> None:
        dt = 1.0 / (self.fps * self.steps_per_frame)
        self.v += self.gravity * dt
        d = self.disturbance
        if d is not None:
            r = self.x - np.asarray(d.center)
            dist = np.linalg.norm(r, axis=1)
            inside = dist < d.radius
            if d.mode == "pull":
                self.v[inside] += -r[inside] * d.strength * dt * 10
            else:
                self.v[inside] += (np.asarray(d.velocity) - self.v[inside]) * min(d.strength * dt, 1.0)
        self.x += self.v * dt
        # Damped bounce on the domain walls (restitution 0.3 so the block settles).
        r = self.radius[self.level][:, None]
        low, high = self.domain_min + r, self.domain_max - r
        for bound, sign in ((low, 1), (high, -1)):
            hit = (self.x - bound) * sign < 0
            self.x = np.where(hit, bound, self.x)
            self.v = np.where(hit & (self.v * sign < 0), -0.3 * self.v, self.v)
        self.time += dt

    def advance_frame(self, wall_budget: float | None = None, seconds: float | None = None) -> None:
        deadline = time.perf_counter() + wall_budget if wall_budget is not None else None
        for _ in range(self.steps_per_frame):
            self.step()
            if deadline is not None and time.perf_counter() >= deadline:
                break
        self.frame += 1

    def snapshot(self) -> FakeSnapshot:
        n_real = int((self.kind < 4).sum())
        speed2 = (self.v**2).sum(axis=1)
        m = self.REST_DENSITY * (2 * self.radius[self.level]) ** self.dim
        stats = {
            "frame": self.frame,
            "time": self.time,
            "dt": 1.0 / (self.fps * self.steps_per_frame),
            "n_real": n_real,
            "n_virtual": len(self.kind) - n_real,
            "total_mass": float(m[self.kind < 4].sum()),
            "kinetic_energy": float(0.5 * (m * speed2)[self.kind < 4].sum()),
            "max_density_ratio": 1.01,
            "splits": self.splits,
            "merges": self.merges,
            "n_transient": int(((self.kind >= 1) & (self.kind <= 3)).sum()),
        }
        for l in range(self.levels):
            stats[f"n_level_{l}"] = int(((self.level == l) & (self.kind < 4)).sum())
            stats[f"n_virtual_level_{l}"] = int(((self.level == l) & (self.kind >= 4)).sum())
        rho = self.REST_DENSITY * (1.0 + 0.03 * np.sin(self.x[:, 0] * 20.0))
        return FakeSnapshot(
            dim=self.dim,
            levels=self.levels,
            time=self.time,
            frame=self.frame,
            x=self.x.astype(np.float32),
            v=self.v.astype(np.float32),
            m=m.astype(np.float32),
            rho=rho.astype(np.float32),
            level=self.level.copy(),
            kind=self.kind.copy(),
            radius=self.radius,
            domain_min=self.domain_min.copy(),
            domain_max=self.domain_max.copy(),
            obstacles=[dict(o) for o in self.obstacles],
            stats=stats,
        )

"""The simulation: ``Simulation`` builds the parts of the method and ``step()`` runs its
phases in order (METHOD.md §1–6):

    emit → adapt (criteria, split/merge) → neighbour grids → [virtual masses] → density
         → [virtual state] → [DFSPH: factors, divergence solve] → forces
         → [virtual coupling] → accelerations and time step → kick → [DFSPH: density solve]
         → drift → boundaries → advect virtual → nozzles

Where each phase lives (docs/ARCHITECTURE.md draws it):

- ``levels.py``: per-level constants; ``neighbours.py``: the neighbour visitor and lists;
- ``density.py``: density (Eq. 7) and the neighbour lists;
- ``pressure/``: the pressure solver (``wcsph``: equation of state, pair pressure term);
- ``forces.py``: the pair forces (the solver's pressure term, viscosity Eq. 19,
  artificial viscosity);
- ``integrator.py``: accelerations (body forces, disturbances), time step, kick, drift,
  collide, and the error reports;
- ``multires/``: the adaptivity pass (``topology.py``) and the level coupling
  (``coupling.py``, ``limiter.py``), whose hooks the passes call;
- ``seeding.py``, ``emitters.py``: particles in.

Each phase is one or a few Taichi kernels and can be timed on its own
(``Simulation(…, profile=True)``, used by ``python3 main.py bench``); unprofiled, a
weakly compressible step runs everything after the adaptivity pass as one launch
(``fused.py``).
"""

import math
import time as _time
import warnings
from types import SimpleNamespace

import numpy as np
import taichi as ti

from . import pressure as pressure_solvers
from . import runtime
from .io.snapshot import Snapshot
from .multires import COUNTERS, Multires, SplitFade, make_coupling
from .scene.criteria import Criteria
from .scene.emitters import Emitters
from .scene.interaction import MOUSE_SLOT, Disturbance, Disturbances, Paths, path_sample
from .scene.seeding import Seeder
from .sph.boundary import Boundary
from .sph.density import Density
from .sph.forces import Forces
from .sph.fused import FusedStep
from .sph.grid import CELLS_PER_SUPPORT, LevelGrids
from .sph.integrator import Integrator, SimulationError
from .sph.levels import Levels
from .sph.neighbours import Neighbours
from .sph.particles import ATTRIBUTES, DEAD, REGULAR, VIRTUAL_CHILD, ParticlePool

__all__ = ["Simulation", "SimulationError", "PHASES"]

PHASES = (
    "emit",
    "adapt",
    "grid",
    "density",
    "divergence",
    "forces",
    "virtual_coupling",
    "timestep",
    "pressure",
    "integrate",
    "boundaries",
    "virtual_advect",
)


def _as_scene(scene):
    from .scene.config import Scene, load_scene

    if isinstance(scene, Scene):
        return scene
    return load_scene(scene)


class Simulation:
    """One fluid scene on one Taichi arch. See the README for a usage example."""

    def __init__(self, scene, arch: str = "cpu", profile: bool = False, threads: int | None = None):
        self.scene = _as_scene(scene)
        s = self.scene.data
        self.arch_name = runtime.ensure(arch, s["particles"]["precision"], threads)
        self.threads = threads  # None: all cores (see runtime.auto_threads)
        self.dim = int(s["dim"])
        self.adaptive = bool(s["adaptivity"]["enabled"])
        self.levels = int(s["adaptivity"]["levels"]) if self.adaptive else 1
        self.profile = profile
        self.timers = {k: 0.0 for k in PHASES}
        self._build()
        self.reset()

    # ================================================================== set-up
    def _build(self):
        s = self.scene.data
        d, L = self.dim, self.levels
        part, a = s["particles"], s["adaptivity"]
        self.rest_density = float(s["fluid"]["rest_density"])
        self.pool = ParticlePool(d, int(part["capacity"]), unused=SplitFade.unused(s, self.adaptive))
        # a few slots more than asked, so that the per-particle arrays do not alias
        # (particles.storage_slots); every per-particle field has this length
        self.capacity = self.pool.capacity
        symmetric = self.adaptive and a["coupling"] == "symmetric"
        self.lev = Levels(d, L, float(part["spacing"]), float(part["support"]), self.rest_density, symmetric)
        self.s0, self.h0, self.m0 = self.lev.s0, self.lev.h0, self.lev.m0
        self.grids = LevelGrids(
            d,
            L,
            s["domain"]["min"],
            s["domain"]["max"],
            self.h0,
            self.capacity,
            CELLS_PER_SUPPORT[d],
            parallel=runtime.on_gpu(),
        )
        self.boundary = Boundary(
            d,
            s["domain"]["min"],
            s["domain"]["max"],
            s["obstacles"],
            s["domain"]["restitution"],
            s["domain"]["friction"],
        )
        self.disturbances = Disturbances(d)
        # band and background_level as config.py resolved them (given or automatic); a
        # uniform run (adaptivity off) has one level whatever the scene's background
        specs = s["criteria"] if self.adaptive else []
        # every waypoint path on the device: the stirrers', then the moving regions'
        stirring = [(st["path"], st["loop"]) for st in s["stirrers"]]
        self.paths = Paths(
            d, stirring + [(c["path"], c.get("loop", False)) for c in specs if c["type"] == "region" and c.get("path")]
        )
        self.criteria = Criteria(
            d, specs, float(a["band"]), float(min(a["background_level"], L - 1)), self.paths, len(stirring)
        )
        parts = SimpleNamespace(
            scene=s,
            dim=d,
            levels=L,
            adaptive=self.adaptive,
            pool=self.pool,
            lev=self.lev,
            grids=self.grids,
            boundary=self.boundary,
            disturbances=self.disturbances,
            criteria=self.criteria,
        )
        parts.neighbours = self.neighbours = Neighbours(d, self.pool, self.grids, self.boundary)
        parts.fade = SplitFade(parts)
        self.multires = Multires(parts) if self.adaptive else None
        parts.coupling = self.coupling = make_coupling(parts, self.multires.offsets if self.adaptive else None)
        self.pressure = pressure_solvers.make(s["fluid"]["solver"], parts)
        self.density = Density(parts)
        self.forces = Forces(parts, self.pressure)
        self.integrator = Integrator(parts, self.pressure, lambda: self.forces.viscosity)
        # the passes that call each other's device functions
        self.density.forces, self.density.pressure = self.forces, self.pressure
        self.forces.integrator = self.integrator
        self.coupling.forces, self.coupling.density = self.forces, self.density
        self.seeder = Seeder(parts, self.integrator.gravity, self.pressure.stiffness)
        self.emitters = Emitters(parts, self.seeder)
        self.pressure.warn = self._warn
        # a step in one launch where the solver allows it, when not profiled (see step)
        self.fused = (
            FusedStep(
                self.grids,
                self.pool,
                self.coupling,
                self.density,
                self.forces,
                self.integrator,
                self.disturbances,
                self.paths,
                len(s["stirrers"]),
            )
            if self.pressure.one_launch
            else None
        )

    # ================================================================== state
    def reset(self) -> None:
        """Back to t = 0: seed the fluid blocks, refine where the criteria ask."""
        s = self.scene.data
        self.pool.clear()
        self.pool.refused[None] = 0
        self.coupling.reset()
        self.emitters.reset()
        self.pressure.reset_counters()
        self.time = 0.0
        self.frame = 0
        self.steps = 0
        self.dt = float(s["physics"]["dt_max"])
        self.integrator.set_chosen_dt(self.dt)
        self._events = dict.fromkeys(COUNTERS, 0)
        self._refused_reported = 0  # pool.refused at the last stats row
        self._events_due = False
        self._refusal_warned = False
        self.warnings: list[str] = []
        for b in s["fluid"]["blocks"]:
            for level, xs in self.seeder.block_lattices(b["min"], b["max"]):
                ps = None
                if s["fluid"]["hydrostatic_start"]:
                    if self.pressure.implicit:  # an incompressible block: its pressure
                        ps = self.seeder.hydrostatic_pressure(xs, b["min"], b["max"])
                    xs = self.seeder.hydrostatic(xs, b["min"], b["max"])
                self.seeder.append(xs, np.tile(np.asarray(b["velocity"], np.float64), (len(xs), 1)), level, ps)
        self._stirrers(0.0)
        if self.adaptive:
            for _ in range(self.levels):
                self.multires.adapt(self.time)
            self.multires.take_counters()
        self.grids.sort(self.pool)
        if self.pool.refused[None] > 0:
            raise SimulationError(
                f"{self.scene.path}: particles.capacity = {self.scene.data['particles']['capacity']} is too "
                f"small for the initial fluid ({self.pool.refused[None]} claims refused); "
                "raise it or set 0 for automatic"
            )

    # ================================================================== the step
    def _phase(self, name, fn, *args, overhead: float = 0.0):
        """``fn(*args)``; when profiling, its wall time, less ``overhead`` (not below
        zero), is added to phase ``name``. ``name`` None: returns the time instead."""
        if not self.profile:
            return fn(*args)
        ti.sync()
        t0 = _time.perf_counter()
        out = fn(*args)
        ti.sync()
        took = _time.perf_counter() - t0
        if name is None:
            return took
        self.timers[name] += max(took - overhead, 0.0)
        return out

    def step(self, max_dt: float | None = None) -> float:
        """Advance by one time step (METHOD.md §1); returns the dt taken. ``max_dt``: cut
        the step to end there (the end of a frame).

        After the emitters and the adaptivity pass, the phases run as one launch
        (``FusedStep``, the same device functions in the same order) unless the step is
        profiled or the pressure solver solves on the host (DFSPH); then as below."""
        self._phase("emit", self._emit)
        if self.adaptive and self.steps % int(self.scene.data["adaptivity"]["interval"]) == 0:
            self._phase("adapt", self._adapt)
        stirred = int(self.disturbances.any_active())
        if self.fused is not None and not self.profile:
            dt = self.fused.run(max_dt, stirred, self.time)
            if dt < 0.0:
                self.integrator.refuse(self._where())
        else:
            n = self._phase("grid", self.grids.sort, self.pool)
            self._density_phase(n)
            self._force_phase(n, stirred)
            # accelerations, the time step, integration, boundaries, and (after the owners
            # moved, so that the anchors are current) the virtual particles' advection
            dt = self.integrator.finish(n, max_dt, stirred, self._phase, self.profile, self._where)
            self._follow_paths(self.time + dt)
        if self.emitters.any_on():
            self._phase("emit", self.emitters.hold, len(self.emitters.on))
        self.time += dt
        self.steps += 1
        self.dt = dt
        return dt

    def _where(self) -> str:
        """The step and time, for a refused step's message (built only then)."""
        return f"step {self.steps} (t = {self.time:.6g} s)"

    def _density_phase(self, n: int) -> None:
        """Density, with the coupling's passes on either side: the virtual masses (the
        limiter) before, the virtual state (variational coupling) after; then what the
        pressure solver takes from it (DFSPH: its factors and the divergence solve)."""
        for ps in self.coupling.before_density():
            self._phase(ps.timer, ps.kernel, n)
        self._phase("density", self.density.run, n)
        for ps in self.coupling.after_density():
            self._phase(ps.timer, ps.kernel, n)
        self.pressure.after_density(n, self.dt, self._phase)

    def _force_phase(self, n: int, stirred: int) -> None:
        """The pair forces, then the coupling's reactions and virtual velocities
        (symmetric coupling; the variational one hands its reactions on in the force pass)."""
        self._phase("forces", self.forces.run, n, self.pressure.signal_speed(), stirred)
        for ps in self.coupling.after_forces():
            self._phase(ps.timer, ps.kernel, n)

    def run_phases(self, *names: str) -> int:
        """Run the first phases of a step on the current state without integrating, for
        tests and tools that look inside a step: ``"grid"`` (sort the pool into the
        neighbour grids), ``"density"`` (density and neighbour lists, with the coupling's
        passes around it), ``"forces"`` (pair forces, left in each particle's ``a``).
        Phases run in the step's order whatever the order given; returns the particle
        count n of the sorted pool."""
        known = ("grid", "density", "forces")
        bad = [x for x in names if x not in known]
        if bad:
            raise ValueError(f"run_phases: unknown phase(s) {bad} (expected some of {known})")
        n = self.grids.sort(self.pool) if "grid" in names else self.pool.count()
        if "density" in names:
            self._density_phase(n)
        if "forces" in names:
            self._force_phase(n, int(self.disturbances.any_active()))
        ti.sync()
        return n

    def advance(self, seconds: float, wall_budget: float | None = None) -> int:
        """Advance by ``seconds`` of simulated time, ending exactly on it; returns steps.

        ``wall_budget`` (seconds of wall time): stop early, after the first step that ends
        past it (so at least one step, even with 0), so that an interactive window stays
        responsive on a machine too slow for its frames; the fluid then runs in slow
        motion. ``None``: no limit."""
        end = self.time + seconds
        deadline = None if wall_budget is None else _time.perf_counter() + wall_budget
        steps = 0
        while self.time < end - 1e-12:
            self.step(max_dt=end - self.time)
            steps += 1
            if deadline is not None and _time.perf_counter() >= deadline:
                break
        if self.time >= end - 1e-12:
            self.time = end
        self._collect_events()
        return steps

    def advance_frame(self, wall_budget: float | None = None) -> int:
        """Advance by one frame (1/fps simulated seconds), or less within ``wall_budget``
        (see :meth:`advance`; ``None``, the whole frame, is what recordings need). The
        frame counter counts calls: a frame cut short by the budget counts as one."""
        steps = self.advance(1.0 / float(self.scene.data["run"]["fps"]), wall_budget)
        self.frame += 1
        return steps

    # ------------------------------------------------------------------ emit / adapt
    def _emit(self):
        if self.emitters.emit(self.time, self.dt):
            self._warn_refused()

    def _adapt(self):
        self.multires.adapt(self.time)
        self._events_due = True

    def _collect_events(self):
        """Add the adaptivity passes' events since the last call to the frame's counts
        and warn (once) if a split was refused. Called by ``advance`` and ``stats``, not
        after every pass: a read of the counters costs ~50 µs, a twentieth of a step at
        a few thousand particles."""
        if not self._events_due:
            return
        self._events_due = False
        ev = self.multires.take_counters()
        for k, v in ev.items():
            self._events[k] += v
        if self.pool.refused[None] > 0:  # any claim of the passes (or emitters) refused
            self._warn_refused()

    def _warn_refused(self):
        if not self._refusal_warned:
            self._refusal_warned = True
            self._warn(
                f"particle pool full (particles.capacity = {self.capacity}): splits/emission "
                f"refused and counted in stats (refused); the simulation goes on coarser"
            )

    def _warn(self, msg: str) -> None:
        """A warning the app shows (``warnings``) and Python's warnings machinery reports."""
        self.warnings.append(msg)
        warnings.warn(msg, RuntimeWarning, stacklevel=4)

    def _stirrers(self, t):
        """The stirrers at time t: their slots are set once (radius, strength, mode; the
        host's copy keeps where each was then), then follow their paths on the device
        (each step: ``_follow_paths``, or the fused step's launch)."""
        stirrers = self.scene.data["stirrers"]  # at most MAX_STIRRERS (config)
        for i, st in enumerate(stirrers):
            if self.disturbances.get(1 + i) is None:
                pos, vel = path_sample(st["path"], t, st["loop"])
                self.disturbances.set(
                    1 + i, Disturbance(tuple(pos), st["radius"], st["strength"], st["mode"], tuple(vel))
                )
        self._follow_paths(t)

    def _follow_paths(self, t):
        if self.scene.data["stirrers"]:
            self.disturbances.follow(self.paths, 1, len(self.scene.data["stirrers"]), t)

    # ================================================================== reading out
    def particles(self, virtual: bool = True) -> dict:
        """Alive particles as numpy arrays: x, v, m, rho, p, level, kind, parent, drho, ..."""
        n = self.pool.count()
        p = ti.static(self.pool.p)
        out = {
            k: getattr(p, k).to_numpy()[:n]
            for k in ("x", "v", "m", "rho", "p", "level", "kind", "parent", "nchild", "lam", "drho")
        }
        keep = out["kind"] != DEAD
        if not virtual:
            keep &= out["kind"] < VIRTUAL_CHILD
        if not keep.all():
            out = {k: v[keep] for k, v in out.items()}
        return out

    def stats(self, parts: dict | None = None) -> dict:
        """The stats row (the columns of stats.csv). ``splits``, ``merges`` and ``refused``
        count since the last call; ``refused`` counts claims the pool could not hold: a
        split refused, or a particle an emitter could not place."""
        parts = parts if parts is not None else self.particles()
        real = parts["kind"] < VIRTUAL_CHILD
        m = parts["m"][real].astype(np.float64)
        v = parts["v"][real].astype(np.float64)
        mom = (m[:, None] * v).sum(axis=0) if len(m) else np.zeros(self.dim)
        # before the first step there is no step to report: dt 0, not dt_max
        row = {
            "frame": self.frame,
            "time": self.time,
            "dt": self.integrator.chosen_dt() if self.steps else 0.0,
            "n_real": int(real.sum()),
            "n_virtual": int((~real).sum()),
            "total_mass": math.fsum(m.tolist()),
        }
        for k, ax in enumerate("xyz"[: self.dim]):
            row[f"momentum_{ax}"] = float(mom[k])
        row["kinetic_energy"] = float(0.5 * (m * (v * v).sum(axis=1)).sum())
        # the density the pressure reads: less the split fade's offset drho (a sampling error)
        rho = parts["rho"][real] - np.maximum(parts["drho"][real], 0.0) if "drho" in parts else parts["rho"][real]
        row["max_density_ratio"] = float(rho.max() / self.rest_density) if len(rho) else 0.0
        lv = parts["level"]
        for l in range(self.levels):
            row[f"n_level_{l}"] = int(((lv == l) & real).sum())
        for l in range(self.levels):
            row[f"n_virtual_level_{l}"] = int(((lv == l) & ~real).sum())
        row["n_transient"] = int((real & (parts["kind"] > REGULAR)).sum())
        # the pressure solver: mean iterations a step of each solve since the last row, the
        # average density error (DFSPH: the density solve's last, of the predicted density;
        # WCSPH: the real particles' mean compression), solves stopped at their maximum
        solve = self.pressure.take_stats()
        if solve["density_error"] is None:
            solve["density_error"] = (
                float(np.maximum(rho - self.rest_density, 0.0).mean() / self.rest_density) if len(rho) else 0.0
            )
        row["solver"] = self.scene.data["fluid"]["solver"]
        row["density_iterations"] = solve["density_iterations"]
        row["divergence_iterations"] = solve["divergence_iterations"]
        row["density_error"] = solve["density_error"]
        row["unconverged"] = solve["unconverged"]
        self._collect_events()
        row["splits"] = self._events["splits"]
        row["merges"] = self._events["merges"]
        row["absorbed"] = self._events["absorbed"]  # of the merges: groups given to a neighbour
        refused = int(self.pool.refused[None])  # a running total in the pool
        row["refused"] = refused - self._refused_reported
        self._refused_reported = refused
        for k in self._events:
            self._events[k] = 0
        return row

    def snapshot(self, stats: bool = True) -> Snapshot:
        parts = self.particles()
        s = self.scene.data
        return Snapshot(
            dim=self.dim,
            levels=self.levels,
            time=self.time,
            frame=self.frame,
            x=parts["x"],
            v=parts["v"],  # the simulation's precision: dumps keep f64
            m=parts["m"],
            rho=parts["rho"],
            level=parts["level"],
            kind=parts["kind"],
            radius=np.array([0.5 * self.s0 * 2**l for l in range(self.levels)]),
            domain_min=np.asarray(s["domain"]["min"], float),
            domain_max=np.asarray(s["domain"]["max"], float),
            obstacles=[dict(o) for o in s["obstacles"]],
            stats=self.stats(parts) if stats else {},
            p=parts["p"],
        )

    def save_state(self) -> dict:
        """The simulation's state in memory (numpy copies): every particle attribute, the
        links, the clocks and the emitters' progress. :meth:`restore_state` puts it back
        into a Simulation of the same scene, here or in another Taichi program; the scene's
        parameters, live-tuned ones included, and the mouse's disturbance are not part of
        it. ``bench`` uses it to time an adaptive run and its uniform twin turn about
        from the same warm state."""
        p = self.pool.p
        return {
            "attributes": {a.name: getattr(p, a.name).to_numpy() for a in ATTRIBUTES},
            "children": self.pool.children.to_numpy(),
            "n": self.pool.count(),
            "refused": int(self.pool.refused[None]),
            "clock": (self.time, self.frame, self.steps, self.dt, self.integrator.chosen_dt()),
            "emitters": list(self.emitters.progress),
            "capacity": self.capacity,
            "dim": self.dim,
        }

    def restore_state(self, state: dict) -> None:
        """Put back a :meth:`save_state` of a Simulation of the same scene."""
        if (state["dim"], state["capacity"]) != (self.dim, self.capacity):
            raise ValueError(
                f"restore_state: a {state['dim']}D state of capacity {state['capacity']} "
                f"does not fit this {self.dim}D pool of capacity {self.capacity}"
            )
        for name, values in state["attributes"].items():
            getattr(self.pool.p, name).from_numpy(values)
        self.pool.children.from_numpy(state["children"])
        self.pool.n[None] = state["n"]
        self.pool.refused[None] = state["refused"]
        self._refused_reported = state["refused"]
        self.time, self.frame, self.steps, self.dt, chosen_dt = state["clock"]
        self.integrator.set_chosen_dt(chosen_dt)
        self.emitters.progress = list(state["emitters"])
        self.coupling.reset()
        self._stirrers(self.time)

    # ================================================================== interaction
    def set_disturbance(self, d: Disturbance | None) -> None:
        self.disturbances.set(MOUSE_SLOT, d)

    def _live(self):
        """Live-tunable keys and the part that owns each."""
        owners = (self.forces, self.pressure, self.integrator, self.coupling)
        return {k: part for part in owners for k in part.live_keys}

    @property
    def LIVE_KEYS(self) -> tuple:
        return tuple(self._live())

    def set_param(self, key: str, value) -> None:
        """Change a parameter while running (validated like the scene file)."""
        if key == "adaptivity.enabled":
            raise ValueError(
                "adaptivity.enabled: changes the particle levels; rebuild the "
                "Simulation with scene.with_overrides({...}) instead"
            )
        live = self._live()
        if key not in live:
            raise ValueError(f"{key}: not live-tunable (expected one of {', '.join(live)})")
        self.scene = self.scene.with_overrides({key: value})
        live[key].set_param(key, self.scene.get(key))
        if live[key] is self.pressure:  # the artificial viscosity follows the signal speed
            self.forces.update_signal_speed()

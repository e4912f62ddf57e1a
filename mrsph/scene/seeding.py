"""Seeding the fluid blocks (METHOD.md §1 set-up, §6 for the levels): lattices of the
finest spacing's fluid laid as whole coarse cells where they fit, in hydrostatic
equilibrium, and the one way particles enter the pool (``append``), which emitters use too.
"""

import math

import numpy as np
import taichi as ti

from mrsph.limits import LATTICE_EPS
from mrsph.pressure.eos import hydrostatic_heights
from mrsph.sph.particles import REGULAR


@ti.data_oriented
class Seeder:
    def __init__(self, core, fluid, gravity, stiffness):
        """fluid: the scene's [fluid] params (the equation of state of the hydrostatic
        start); gravity: the integrator's field; stiffness: () -> k, the solver's."""
        self.dim, self.levels = core.dim, core.levels
        self.pool, self.lev = core.pool, core.lev
        self.capacity = core.pool.capacity
        self.rest_density = core.lev.rest_density
        self.eos, self.gamma = fluid.eos, fluid.gamma
        self.gravity = gravity  # a field of the integrator's
        self.stiffness = stiffness  # () -> k, the pressure solver's

    def block_lattices(self, lo, hi) -> list[tuple[int, np.ndarray]]:
        """(level, lattice points) filling the block [lo, hi] with the fluid of a uniform
        run at the finest spacing: whole cells of the coarsest level from ``lo``, and in
        the slabs left over towards ``hi`` (a block side that is not a multiple of the
        coarsest spacing) the next finer level, down to the finest, which leaves what a
        uniform run leaves. Seeding only the coarsest lattice held up to 2^(L-1) - 1 fine
        layers less fluid per side: a 0.3 m 3D pool at 4 cm seeded 7 columns of 28 cm,
        19 % less fluid than its uniform twin, and the gap made it slump. The adaptivity
        pass then merges the finer seeds where the criteria want coarse (§6)."""
        out = []
        s0 = self.lev.s0
        boxes = [(np.asarray(lo, np.float64), np.asarray(hi, np.float64))]
        for level in range(self.levels - 1, -1, -1):
            s = s0 * 2**level
            finer = []
            eps = LATTICE_EPS * s0 / s  # the uniform run's tolerance, in cells of s
            for blo, bhi in boxes:
                counts = np.floor((bhi - blo) / s + eps).astype(int)
                if level > 0 and counts.min() == 0:
                    finer.append((blo, bhi))  # not one whole cell: all of it goes finer
                    continue
                out.append((level, lattice(blo, counts, s)))
                covered = blo + counts * s
                for k in range(self.dim):  # box minus covered box, as disjoint slabs
                    if bhi[k] - covered[k] > LATTICE_EPS * s0:
                        slo, shi = blo.copy(), bhi.copy()
                        slo[k] = covered[k]
                        shi[:k] = covered[:k]
                        finer.append((slo, shi))
            boxes = finer
        return [(level, xs) for level, xs in out if len(xs)]

    def seed_blocks(self, blocks, hydrostatic: bool, incompressible: bool, compress: bool) -> None:
        """Append every fluid block's lattices (``block_lattices``) at the block's velocity.
        With a ``hydrostatic`` start an ``incompressible`` solver's particles start at the
        block's pressure, and with ``compress`` (a uniform start; an adaptive one is
        compressed after its splits, ``hydrostatic_pool``) the lattices are compressed."""
        for b in blocks:
            v = np.asarray(b.velocity, np.float64)
            for level, xs in self.block_lattices(b.min, b.max):
                ps = None
                if hydrostatic and incompressible:
                    ps = self.hydrostatic_pressure(xs, b.min, b.max)
                if hydrostatic and compress:
                    xs = self.hydrostatic(xs, b.min, b.max)
                self.append(xs, np.tile(v, (len(xs), 1)), level, ps)

    def hydrostatic(self, xs: np.ndarray, lo, hi) -> np.ndarray:
        """Lattice points of the block [lo, hi] moved along gravity to hydrostatic equilibrium.

        A uniform lattice at ρ0 under gravity is not in equilibrium: it falls by the
        compression of its lower layers and then rings in its first acoustic mode
        (period 4H/c), which the viscosity, acting on velocity differences between
        neighbours, hardly damps (in the 0.3 m tank of tests/test_physics.py: 0.035
        sqrt(gH) of mean speed, undiminished after 1.5 s). So each particle is put where
        the weight of the fluid above it, ρ0 |g| depth, compresses it to
        (``eos.hydrostatic_heights``), depth counted from the block's top; across gravity
        the lattice is unchanged. Masses are unchanged too: the block holds the same
        fluid, a little lower.
        """
        g = np.asarray(self.gravity[None].to_numpy(), np.float64)
        gn = float(np.linalg.norm(g))
        if gn == 0.0 or len(xs) == 0:
            return xs
        up = -g / gn
        corners = np.stack(np.meshgrid(*zip(lo, hi), indexing="ij"), -1).reshape(-1, self.dim)
        heights = corners @ up
        top, bottom = float(heights.max()), float(heights.min())
        along = xs @ up
        z = hydrostatic_heights(
            top - along, top - bottom, gn, self.rest_density, self.stiffness(), self.eos, self.gamma
        )
        return xs + np.outer(bottom + z - along, up)

    def hydrostatic_pool(self, blocks) -> None:
        """Move every particle in the pool (real and virtual) that lies in one of the
        fluid ``blocks`` to hydrostatic equilibrium, as ``hydrostatic`` moves a lattice.

        For an adaptive start, after the first adaptivity passes: the blocks are seeded
        as uniform lattices and split where the criteria want the fluid finer, and a
        split puts its children at fixed offsets from their parent. Compressed before the
        split, each pair of sibling rows kept its parent's compression between them and
        none within, so the fine rows pushed alternately up and down at ±0.4 g (the 2D
        deep tank, one step from t = 0); compressed after it, the fine rows sit where a
        uniform fine run puts them."""
        n = self.pool.count()
        if n == 0:
            return
        x = self.pool.p.x.to_numpy()
        pts = x[:n].astype(np.float64)
        for b in blocks:
            lo, hi = np.asarray(b.min, np.float64), np.asarray(b.max, np.float64)
            inside = np.all((pts >= lo) & (pts <= hi), axis=1)
            pts[inside] = self.hydrostatic(pts[inside], lo, hi)
        x[:n] = pts
        self.pool.p.x.from_numpy(x)

    def hydrostatic_pressure(self, xs: np.ndarray, lo, hi) -> np.ndarray:
        """ρ0 |g| depth of each point below the top of the block [lo, hi] (depth along
        gravity): the pressure of a block at rest, which an implicit solver starts from
        (its first steps would otherwise build it up layer by layer, one layer an
        iteration)."""
        g = np.asarray(self.gravity[None].to_numpy(), np.float64)
        gn = float(np.linalg.norm(g))
        if gn == 0.0 or len(xs) == 0:
            return np.zeros(len(xs))
        up = -g / gn
        corners = np.stack(np.meshgrid(*zip(lo, hi), indexing="ij"), -1).reshape(-1, self.dim)
        top = float((corners @ up).max())
        return self.rest_density * gn * np.maximum(top - xs @ up, 0.0)

    def append(self, xs: np.ndarray, vs: np.ndarray, level: int, ps: np.ndarray | None = None) -> int:
        """Append regular particles of one level (pressures ``ps``, default 0); returns how
        many fitted (the others are counted in the pool's ``refused``)."""
        if len(xs) == 0:
            return 0
        n0 = self.pool.count()
        room = self.capacity - n0
        take = min(room, len(xs))
        if take < len(xs):
            self.pool.refused[None] += len(xs) - take
        if take > 0:
            ps = np.zeros(take) if ps is None else ps[:take]
            self._append_kernel(
                np.ascontiguousarray(xs[:take], dtype=np.float64),
                np.ascontiguousarray(vs[:take], dtype=np.float64),
                np.ascontiguousarray(ps, dtype=np.float64),
                level,
                n0,
            )
        return take

    @ti.kernel
    def _append_kernel(
        self, xs: ti.types.ndarray(), vs: ti.types.ndarray(), ps: ti.types.ndarray(), level: ti.i32, n0: ti.i32
    ):
        m = self.lev.m[level]
        for r in range(xs.shape[0]):
            i = n0 + r
            xv = ti.Vector.zero(float, self.dim)
            vv = ti.Vector.zero(float, self.dim)
            for k in ti.static(range(self.dim)):
                xv[k] = ti.cast(xs[r, k], float)
                vv[k] = ti.cast(vs[r, k], float)
            p = ti.static(self.pool.p)
            p[i].x = xv
            p[i].v = vv
            p[i].a = ti.Vector.zero(float, self.dim)
            p[i].m = m
            p[i].rho = self.rest_density
            p[i].p = ti.cast(ps[r], float)
            p[i].lam = 0.0
            p[i].drho = 0.0
            p[i].rho_ref = 0.0
            p[i].level = level
            p[i].parent = -1
            p[i].slot = 0
            p[i].nchild = 0
            p[i].flags = 0
            p[i].kind = REGULAR
        self.pool.n[None] = n0 + xs.shape[0]


def lattice(lo, counts, spacing):
    """Cell centres of ``counts`` cells of the given spacing per axis from ``lo``."""
    axes = [lo[k] + (np.arange(counts[k]) + 0.5) * spacing for k in range(len(lo))]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(lo))


def settle(sim, seconds: float, rate: float) -> int:
    """``fluid.settle``: step ``sim`` for ``seconds`` with every velocity multiplied by
    exp(−rate dt) after each step, so that the pool finds the discrete equilibrium its
    seeded lattice is not (a 3D cubic lattice under 80 layers rearranges at ~0.05 s; a
    level interface relaxes over ~0.4 s) with the energy that sets free damped instead of
    left ringing in the first acoustic mode. Returns the steps taken; the caller starts
    the clocks at 0 after it."""
    done, steps = 0.0, 0
    while done < seconds - 1e-12:
        dt = sim.step(max_dt=seconds - done)
        sim.pool.damp_velocities(math.exp(-rate * dt))
        done += dt
        steps += 1
    return steps

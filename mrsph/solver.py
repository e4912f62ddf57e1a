"""The SPH solver: ``Simulation.step()`` reads like METHOD.md.

    emit → adapt (criteria, split/merge) → neighbour grids → virtual masses → density
         → virtual state → forces (variational coupling: + reactions handed to the owners)
         → [symmetric coupling: virtual coupling] → accelerations and time step
         → integrate → boundaries → advect virtual

Each phase is one or a few Taichi kernels and can be timed on its own
(``Simulation(…, profile=True)``, used by ``python3 main.py bench``).

Physics (METHOD.md §1, thesis ch. 3): density by poly6 over same-level particles (self
included, Eq. 7); pressure from the equation of state (``eos.py``); the symmetric pressure
force F_i = −m_i Σ_j m_j (p_i/ρ_i² + p_j/ρ_j²) ∇W_spiky (Eq. 16, times the volume m_i/ρ_i)
and the symmetrised viscosity force F_i = μ m_i Σ_j m_j (u_j − u_i)/(ρ_i ρ_j) ∇²W_visc
(Eq. 19); Monaghan's artificial viscosity on approaching pairs (``fluid.artificial_viscosity``,
see ``_pair_force_values``); gravity and disturbances as accelerations (Eq. 22–23);
symplectic Euler; a time step from the CFL condition dt ≤ λ h/(c + |u|) and the force
condition dt ≤ λ_f sqrt(h/|a|), each particle with its own level's h. Fluid blocks start
in hydrostatic equilibrium (``fluid.hydrostatic_start``, see ``_hydrostatic``).
"""

import math
import time as _time

import numpy as np
import taichi as ti

from . import runtime
from .boundary import Boundary
from .config import LATTICE_EPS, MAX_NEIGHBOURS   # the lists' length, which bounds the pool
from .config import emitter_disc
from .criteria import Criteria
from .eos import hydrostatic_heights, pressure, sound_speed
from .grid import LevelGrids
from .interaction import MOUSE_SLOT, Disturbance, Disturbances, path_sample
from .kernels import constants, lattice_density_sum, lattice_gradient_factor, poly6
from .multires import COUNTERS, Multires
from .particles import (ATTRIBUTES, DEAD, REGULAR, ROLE_PARENT, VIRTUAL_CHILD, VIRTUAL_PARENT,
                        ParticlePool, is_real, is_virtual)
from .snapshot import Snapshot

# Symmetric coupling (adaptivity.coupling = "symmetric", METHOD.md §4's form): each pair
# of real particles on either side of a level interface must interact exactly once. (The
# default, variational coupling lets the pair meet twice, each time with one particle's
# own pressure: see ``_partner_pressure``.) A fine particle i and a coarse particle P
# could meet twice: at the fine level through P's virtual children (reaction to P) and at
# the coarse level through i's virtual parent (reaction to i). Counting both pushes the
# two sides apart with an extra pressure·area at every interface, which pumps energy into
# the flow. So the pair interacts at the finer level whenever P carries virtual children
# (the fine particle then sees a complete fine neighbourhood, as in uniform SPH), and
# through the virtual parent only when P has none. Virtual parents always give the
# coarse side its density.


# Monaghan's artificial viscosity divides by r² + AV_EPS h² so that a pair at (nearly)
# the same position gets a bounded force; 0.01 is Monaghan's value (1992).
AV_EPS = 0.01

# An acceleration this large (m/s²) is a blow-up: a step refuses it as it refuses NaN.
# (In f32, |a| overflows already from 1.8e19 m/s², as its square passes the float range.)
ACCEL_OVERFLOW = 1e30

# A transient parent's virtual children lie within sqrt(d)/2 fine spacings of it and reach
# one fine support beyond; measured with a uniform-pressure probe (no gravity, a refined
# box inside a block), factors >= 1.2 leave transient children balanced to 0.1 % of
# p/(rho s), smaller ones double-count groups near the parent. 1.5 keeps a margin.
REACH_FACTOR = 1.5


# Density loop without a branch per candidate, in both dimensions. In 2D a third of the
# candidates of the 3x3 cells are neighbours and, once the fluid flows, which ones is
# unpredictable: the mispredictions cost more than computing W for every candidate (dam
# break, 50k particles, one thread: 7.6 -> 4.9 ms a pass). In 3D, with cells of a whole
# support, one candidate in six was a neighbour and the branch won (30k: 15.1 ms with it,
# 16.3 without); with half-support cells it was one in four, and on the flowing 30k dam
# break (t = 0.2 s, two threads) the pass took 11.2-13.4 ms with the branch, 8.8-9.5
# without. (The cells are now CELLS_PER_SUPPORT's, below, fewer candidates again.) On the
# initial lattice, where the branch is predictable, it is the other way round (5.2
# against 7.4 ms at t = 0.05 s): what matters is the fluid once it moves.
BRANCH_FREE = True

# Cells per support radius of the neighbour grids (grid.py), per axis: whole supports
# across the rows and 2 (2D) or 4 (3D) cells a support along them (the last axis). A
# block is then 3^(d-1) rows of (2k+1)/k supports each: fewer candidates than whole-support
# cells (3 supports a row) with as few rows. What pays is the number of rows, not of
# candidates: half-support cells on every axis (25 rows in 3D) had cut the candidates
# from 27 h³ to 125/8 h³ and the 3D density pass only from 12.7 to 9.9 ms (30k dam break,
# one thread), and (2, 2, 4) cells, 10 % fewer candidates again, saved nothing.
# Measured with DENSITY_CLUSTER, the flowing dam break (3D ~100k at t = 0.2 s, 2D ~50k
# at 0.25 s), one thread, density pass alone, 10th percentile of 10: 3D (1, 1, 4) 22.6 ms,
# (1, 1, 2) 24.8, (1, 1, 8) 22.9, 1 27.4, 2 27.7; 2D (1, 2) 2.07 ms, 1 2.25, (1, 4) 2.02
# (more cells for the sort to clear).
CELLS_PER_SUPPORT = {2: (1, 2), 3: (1, 1, 4)}

# The density pass takes particles DENSITY_CLUSTER at a time: consecutive particles of a
# column of cells share their block's rows, so one walk of those rows (over the union of
# their spans) serves them all, each candidate loaded once and its distance to each of
# them computed side by side (``_scan_cluster``). The row set-up, the loop-exit
# mispredictions and the loads are shared, and the K distances vectorise. Same runs as
# above, density pass, one thread: 3D K = 1 49.0 ms, 2 40.4, 3 40.6, 4 28.4, 6 32.8,
# 8 33.2 (half-support cells); 2D K = 1 4.65 ms, 2 3.95, 4 2.56, 8 2.25 (cells of h).
# Whole steps, two threads, median of 3 x 30 (3D) or 100 (2D) steps: 3D 100k 40.5 ->
# 24.8 ms (2.36 -> 3.85 M particle-steps/s), 2D 50k 10.2 M particle-steps/s.
DENSITY_CLUSTER = {2: 8, 3: 4}

REDUCTION_BLOCKS = 256   # blocks of the time-step reduction (see ``_accelerations``)


@ti.func
def skip_reach2(kind_i, reach2):
    """The squared distance within which real particle i skips virtual parents: its
    level's ``reach2`` for a transient parent, since that pair already meets at the finer
    level through its virtual children; -1 (none) for any other particle. Taken once per
    particle, not per pair."""
    return ti.select((kind_i & ROLE_PARENT) != 0, reach2, -1.0)


@ti.func
def interacts(kind_j, r2, skip2):
    """Does real particle i take a force from same-level particle j at squared distance
    r2, given i's ``skip_reach2``?"""
    return r2 >= skip2 or kind_j != VIRTUAL_PARENT


# Parts of ``_end_step``: one launch runs them all, a profiled step one a call.
END_TIMESTEP, END_INTEGRATE, END_BOUNDARIES, END_ADVECT = 1, 2, 4, 8

PHASES = ("emit", "adapt", "grid", "density", "forces", "virtual_coupling", "timestep",
          "integrate", "boundaries", "virtual_advect")


class SimulationError(RuntimeError):
    """The simulation cannot go on (NaN, a time step below dt_min, a full pool at start)."""


def _as_scene(scene):
    from .config import Scene, load_scene
    if isinstance(scene, Scene):
        return scene
    return load_scene(scene)


@ti.data_oriented
class Simulation:
    """One fluid scene on one Taichi arch. See the README for a usage example."""

    def __init__(self, scene, arch: str = "cpu", profile: bool = False, threads: int | None = None):
        self.scene = _as_scene(scene)
        s = self.scene.data
        self.arch_name = runtime.ensure(arch, s["particles"]["precision"], threads)
        self.threads = threads      # None: all cores (see runtime.auto_threads)
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
        part, fl, ph = s["particles"], s["fluid"], s["physics"]
        # see _partner_pressure; without adaptivity there are no virtual particles
        self.variational = self.adaptive and s["adaptivity"]["coupling"] == "variational"
        self.limit_virtual = self.adaptive and bool(s["adaptivity"]["limit_virtual_density"])
        self.virtual_tolerance = float(s["adaptivity"]["virtual_density_tolerance"])
        self.s0 = float(part["spacing"])
        self.h0 = float(part["support"]) * self.s0
        self.rest_density = float(fl["rest_density"])
        self.m0 = self.rest_density / lattice_density_sum(self.s0, self.h0, d)
        self.eos = fl["eos"]
        self.tait = self.eos == "tait"
        self.clamp = bool(fl["clamp_negative_pressure"])
        self.gamma = float(fl["gamma"])

        self.pool = ParticlePool(d, int(part["capacity"]))
        # a few slots more than asked, so that the per-particle arrays do not alias
        # (particles.storage_slots); every per-particle field has this length
        self.capacity = self.pool.capacity
        self.grids = LevelGrids(d, L, s["domain"]["min"], s["domain"]["max"], self.h0, self.capacity,
                                CELLS_PER_SUPPORT[d])
        self.boundary = Boundary(d, s["domain"]["min"], s["domain"]["max"], s["obstacles"],
                                 s["domain"]["restitution"], s["domain"]["friction"])
        self.disturbances = Disturbances(d)
        a = s["adaptivity"]
        # band and background_level as config.py resolved them (given or automatic); a
        # uniform run (adaptivity off) has one level whatever the scene's background
        self.criteria = Criteria(d, s["criteria"] if self.adaptive else [], float(a["band"]),
                                 float(min(a["background_level"], L - 1)))

        # the emitters' nozzles (see _hold_in_nozzles): centre, unit normal, velocity,
        # radius and half-length of each, and whether it emits this step
        ne = max(len(s["emitters"]), 1)
        self.nozzle_c = ti.Vector.field(d, float, shape=ne)
        self.nozzle_n = ti.Vector.field(d, float, shape=ne)
        self.nozzle_u = ti.Vector.field(d, float, shape=ne)
        self.nozzle_r = ti.field(float, shape=ne)
        self.nozzle_len = ti.field(float, shape=ne)
        self.nozzle_on = ti.field(ti.i32, shape=ne)
        self._nozzles_on = [False] * len(s["emitters"])

        # per-level constants (no powers in the inner loops)
        self.lev_h = ti.field(float, shape=L)
        self.lev_s = ti.field(float, shape=L)
        self.lev_m = ti.field(float, shape=L)
        self.lev_poly6 = ti.field(float, shape=L)
        self.lev_spiky = ti.field(float, shape=L)
        self.lev_visc = ti.field(float, shape=L)
        # squared distance within which a transient parent of level l meets a virtual
        # parent's children through its own virtual children (see ``interacts``)
        self.lev_reach2 = ti.field(float, shape=L)
        # s/h is the same at every level, so one lattice calibration serves them all
        self.grad_factor = lattice_gradient_factor(self.s0, self.h0, d)
        for l in range(L):
            h = self.h0 * 2**l
            c = constants(h, d)
            self.lev_h[l], self.lev_s[l] = h, self.s0 * 2**l
            self.lev_m[l] = self.m0 * 2 ** (d * l)
            self.lev_poly6[l], self.lev_visc[l] = c["poly6"], c["visc"]
            self.lev_spiky[l] = c["spiky"] / self.grad_factor
            if l > 0 and not self.variational:
                fine_h, fine_s = self.h0 * 2 ** (l - 1), self.s0 * 2 ** (l - 1)
                self.lev_reach2[l] = (REACH_FACTOR * (fine_h + 0.5 * math.sqrt(d) * fine_s)) ** 2
        for e_idx, e in enumerate(s["emitters"]):
            vel = np.asarray(e["velocity"], np.float64)
            level = min(int(e["level"]), L - 1)
            self.nozzle_c[e_idx] = list(map(float, e["center"]))
            self.nozzle_n[e_idx] = (vel / np.linalg.norm(vel)).tolist()
            self.nozzle_u[e_idx] = vel.tolist()
            self.nozzle_r[e_idx] = float(e["radius"]) + 0.5 * self.s0 * 2**level
            self.nozzle_len[e_idx] = self.h0 * 2**level

        # live-tunable parameters (fields, so that changing them does not recompile)
        self.k = ti.field(float, shape=())
        self.mu = ti.field(float, shape=())
        self.gravity = ti.Vector.field(d, float, shape=())
        self.spring_rate = ti.field(float, shape=())
        # alpha c of the artificial viscosity (c the sound speed, which follows k)
        self.av_alpha = float(fl["artificial_viscosity"])
        self.av_coef = ti.field(float, shape=())
        self.k[None] = float(fl["stiffness"])
        # host copy for dt, from the stored (possibly f32) k that the pressure kernel uses
        self._c_sound = sound_speed(float(self.k[None]), self.eos)
        self.av_coef[None] = self.av_alpha * self._c_sound
        self.mu[None] = float(fl["viscosity"])
        # physics.max_speed: a real particle faster than this is reported as a blow-up
        self.speed_limit = ti.field(float, shape=())
        self.speed_limit[None] = float(ph["max_speed"])
        self.gravity[None] = list(map(float, ph["gravity"]))
        self.spring_rate[None] = float(a["spring_rate"])

        # reductions of the time-step phase: [max (c+|u|)/h, max |a|/h, bad count, first bad]
        self.red_f = ti.field(float, shape=2)
        self.red_i = ti.field(ti.i32, shape=2)
        # the step's dt (f64, so that a step cut to the end of a frame ends on it), and
        # whether the step may move the particles (no NaN, dt not below dt_min)
        self.step_dt = ti.field(ti.f64, shape=())
        self.step_go = ti.field(ti.i32, shape=())
        # what the host reads when a step does not go: (dt before the cut to the frame's
        # end, force limit, bad count, first bad); a field, not the kernel's result,
        # which costs more to pass back (see ``_end_step``)
        self.step_report = ti.field(ti.f64, shape=4)
        # without adaptivity the force pass also takes the accelerations (see _forces)
        self.fused_accelerations = not self.adaptive
        self._end_parts = END_TIMESTEP | END_INTEGRATE | END_BOUNDARIES | (END_ADVECT if self.adaptive else 0)

        # neighbour lists (same level, r < h), filled by the density pass and read by the
        # force and coupling passes, which then visit ~13 (2D) / ~33 (3D) neighbours
        # instead of the ~36 / ~125 candidates of the grid block. A particle with more
        # neighbours than the list holds (a fluid compressed ~3x) falls back to the grid.
        self.max_neighbours = MAX_NEIGHBOURS[d]
        # one spare slot: the density pass writes every candidate and keeps the neighbours
        self.neighbours = ti.field(ti.i32, shape=(self.capacity, self.max_neighbours + 1))
        self.neighbour_count = ti.field(ti.i32, shape=self.capacity)
        # variational coupling: reactions of the forces from virtual particles, handed on
        # to their owners during the force pass (see ``_hand_on``)
        self.reaction = ti.Vector.field(d, float, shape=self.capacity) if self.variational else None
        # per-step pair-force factors, set with the density: 1/ρ, and p/ρ² with the
        # pressure a particle shows its neighbours (``_partner_pressure``); they take
        # three divisions out of every pair
        self.inv_rho = ti.field(float, shape=self.capacity)
        self.press_term = ti.field(float, shape=self.capacity)
        # per slot, for one step: the share of their nominal mass that the virtual children
        # near real particle i may carry, and the least share a virtual child got
        # (see ``_limit_virtual_mass``)
        self.virtual_share = ti.field(float, shape=self.capacity) if self.limit_virtual else None
        if self.limit_virtual:
            self.virtual_share.fill(1.0)

        self.multires = Multires(self) if self.adaptive else None

    # ================================================================== state
    def reset(self) -> None:
        """Back to t = 0: seed the fluid blocks, refine where the criteria ask."""
        s = self.scene.data
        self.pool.clear()
        self.pool.refused[None] = 0
        if self.reaction is not None:   # zero between steps (see _accelerate)
            self.reaction.fill(0.0)
        self.time = 0.0
        self.frame = 0
        self.steps = 0
        self.dt = float(s["physics"]["dt_max"])
        self.chosen_dt = self.dt    # the last step as its bounds chose it (not cut to a frame)
        self._events = dict.fromkeys(COUNTERS, 0)
        self._refused_reported = 0   # pool.refused at the last stats row
        self._events_due = False
        self._emit_acc = [0.0] * len(s["emitters"])
        self._refusal_warned = False
        self.warnings: list[str] = []
        for b in s["fluid"]["blocks"]:
            for level, xs in self._block_lattices(b["min"], b["max"]):
                if s["fluid"]["hydrostatic_start"]:
                    xs = self._hydrostatic(xs, b["min"], b["max"])
                self._append(xs, np.tile(np.asarray(b["velocity"], np.float64), (len(xs), 1)), level)
        self._stirrers(0.0)
        if self.adaptive:
            for _ in range(self.levels):
                self.multires.adapt()
            self.multires.take_counters()
        self.grids.sort(self.pool)
        if self.pool.refused[None] > 0:
            raise SimulationError(
                f"{self.scene.path}: particles.capacity = {self.scene.data['particles']['capacity']} is too small for the "
                f"initial fluid ({self.pool.refused[None]} claims refused); raise it or set 0 for automatic")

    def _block_lattices(self, lo, hi) -> list[tuple[int, np.ndarray]]:
        """(level, lattice points) filling the block [lo, hi] with the fluid of a uniform
        run at the finest spacing: whole cells of the coarsest level from ``lo``, and in
        the slabs left over towards ``hi`` (a block side that is not a multiple of the
        coarsest spacing) the next finer level, down to the finest, which leaves what a
        uniform run leaves. Seeding only the coarsest lattice held up to 2^(L-1) - 1 fine
        layers less fluid per side: a 0.3 m 3D pool at 4 cm seeded 7 columns of 28 cm,
        19 % less fluid than its uniform twin, and the gap made it slump. The adaptivity
        pass then merges the finer seeds where the criteria want coarse (§6)."""
        out = []
        boxes = [(np.asarray(lo, np.float64), np.asarray(hi, np.float64))]
        for level in range(self.levels - 1, -1, -1):
            s = self.s0 * 2**level
            finer = []
            eps = LATTICE_EPS * self.s0 / s    # the uniform run's tolerance, in cells of s
            for blo, bhi in boxes:
                counts = np.floor((bhi - blo) / s + eps).astype(int)
                if level > 0 and counts.min() == 0:
                    finer.append((blo, bhi))      # not one whole cell: all of it goes finer
                    continue
                out.append((level, self._lattice(blo, counts, s)))
                covered = blo + counts * s
                for k in range(self.dim):         # box minus covered box, as disjoint slabs
                    if bhi[k] - covered[k] > LATTICE_EPS * self.s0:
                        slo, shi = blo.copy(), bhi.copy()
                        slo[k] = covered[k]
                        shi[:k] = covered[:k]
                        finer.append((slo, shi))
            boxes = finer
        return [(level, xs) for level, xs in out if len(xs)]

    @staticmethod
    def _lattice(lo, counts, spacing):
        """Cell centres of ``counts`` cells of the given spacing per axis from ``lo``."""
        axes = [lo[k] + (np.arange(counts[k]) + 0.5) * spacing for k in range(len(lo))]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(lo))

    def _hydrostatic(self, xs: np.ndarray, lo, hi) -> np.ndarray:
        """Lattice points of the block [lo, hi] moved along gravity to hydrostatic equilibrium.

        A uniform lattice at ρ0 under gravity is not in equilibrium: it falls by the
        compression of its lower layers and then rings in its first acoustic mode
        (period 4H/c), which the viscosity, acting on velocity differences between
        neighbours, hardly damps (measured in the 0.3 m tank of tests/test_physics.py:
        0.035 sqrt(gH) of mean speed, undiminished after 1.5 s). So each particle is put
        where the weight of the fluid above it, ρ0 |g| depth, compresses it to
        (``eos.hydrostatic_heights``), depth counted from the block's top; across gravity
        the lattice is unchanged. Masses are unchanged too: the block holds the same fluid,
        a little lower.
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
        z = hydrostatic_heights(top - along, top - bottom, gn, self.rest_density,
                                float(self.k[None]), self.eos, self.gamma)
        return xs + np.outer(bottom + z - along, up)

    def _append(self, xs: np.ndarray, vs: np.ndarray, level: int) -> int:
        """Append regular particles of one level; returns how many fitted."""
        if len(xs) == 0:
            return 0
        n0 = self.pool.count()
        room = self.capacity - n0
        take = min(room, len(xs))
        if take < len(xs):
            self.pool.refused[None] += len(xs) - take
        if take > 0:
            self._append_kernel(np.ascontiguousarray(xs[:take], dtype=np.float64),
                                np.ascontiguousarray(vs[:take], dtype=np.float64), level, n0)
        return take

    @ti.kernel
    def _append_kernel(self, xs: ti.types.ndarray(), vs: ti.types.ndarray(), level: ti.i32, n0: ti.i32):
        m = self.lev_m[level]
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
            p[i].p = 0.0
            p[i].lam = 0.0
            p[i].level = level
            p[i].parent = -1
            p[i].slot = 0
            p[i].nchild = 0
            p[i].flags = 0
            p[i].kind = REGULAR
        self.pool.n[None] = n0 + xs.shape[0]

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
        """Advance by one time step (METHOD.md §1); returns the dt taken."""
        self._phase("emit", self._emit)
        if self.adaptive and self.steps % int(self.scene.data["adaptivity"]["interval"]) == 0:
            self._phase("adapt", self._adapt)
        n = self._phase("grid", self.grids.sort, self.pool)
        # the virtual particles' masses and state are coupling work, timed as such; the
        # limiter reads the neighbour lists of the fine particles, listed ahead of density
        if self.limit_virtual:
            self._phase("density", self._list_fine_neighbours, n)
            self._phase("virtual_coupling", self._limit_virtual_mass, n)
        self._phase("density", self._density, n)
        if self.adaptive and self.variational:
            self._phase("virtual_coupling", self._virtual_state, n)
        stirred = int(self.disturbances.any_active())
        # variational: with the reactions handed on; uniform: with the accelerations
        self._phase("forces", self._forces, n, self._c_sound, stirred)
        if self.adaptive and not self.variational:
            self._phase("virtual_coupling", self._virtual_coupling, n)
        # the time step, integration, boundaries, and (after the owners moved, so that
        # the anchors are current) the virtual particles' advection
        dt = self._finish_step(n, max_dt, stirred)
        if any(self._nozzles_on):
            self._phase("emit", self._hold_in_nozzles, n, len(self._nozzles_on))
        self.time += dt
        self.steps += 1
        self.dt = dt
        if max_dt is None or dt < max_dt:       # else cut short to end on the frame
            self.chosen_dt = dt
        self._stirrers(self.time)
        return dt

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
        for e_idx, e in enumerate(self.scene.data["emitters"]):
            on = bool(e["start"] <= self.time < e["stop"])
            if on != self._nozzles_on[e_idx]:
                self._nozzles_on[e_idx] = on
                self.nozzle_on[e_idx] = int(on)
            if not on:
                continue
            vel = np.asarray(e["velocity"], np.float64)
            speed = float(np.linalg.norm(vel))
            level = min(int(e["level"]), self.levels - 1)
            s = self.s0 * 2**level
            self._emit_acc[e_idx] += speed * self.dt
            while self._emit_acc[e_idx] >= s:
                self._emit_acc[e_idx] -= s
                xs = self._emitter_layer(e, s, vel / speed, self._emit_acc[e_idx])
                took = self._append(xs, np.tile(vel, (len(xs), 1)), level)
                if took < len(xs):
                    self._warn_refused()

    @ti.kernel
    def _hold_in_nozzles(self, n: ti.i32, count: ti.i32):
        """The emitters' nozzles: every real particle within one support (of the emitted
        level) of an emitting disc, ahead of it or behind, and within its radius (plus half
        a spacing), leaves the step at the emitter's velocity.

        Why: an emitter places a layer of its disc every s / |U| seconds whatever the fluid
        ahead does. Without a nozzle a layer that pressure slowed was caught up by the next
        one, which landed closer, was slowed more and pushed back: a free horizontal jet
        (2D, 1.5 m/s, no gravity) was thrown back out of its outlet at 2 m/s after 0.3 s,
        and a 1 m/s hose in pour_2d turned sideways sprayed 145 of 1440 particles behind its
        disc. The nozzle is the inflow's external force (METHOD.md §1, Eq. 21): it holds the
        fluid it contains at the inflow velocity, as the pipe of a real hose does."""
        p = ti.static(self.pool.p)
        for i in range(n):
            if is_real(p[i].kind):
                for e in range(count):
                    if self.nozzle_on[e]:
                        d = p[i].x - self.nozzle_c[e]
                        along = d.dot(self.nozzle_n[e])
                        if ti.abs(along) < self.nozzle_len[e] and \
                                (d - along * self.nozzle_n[e]).norm() <= self.nozzle_r[e]:
                            p[i].v = self.nozzle_u[e]

    def _emitter_layer(self, e, s, normal, advance):
        """Lattice points of the emitting disc (segment in 2D), moved ``advance`` along it."""
        return emitter_disc(e["center"], float(e["radius"]), normal, s) + advance * normal

    def _adapt(self):
        self.multires.adapt()
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
        if self.pool.refused[None] > 0:     # any claim of the passes (or emitters) refused
            self._warn_refused()

    def _warn_refused(self):
        if not self._refusal_warned:
            self._refusal_warned = True
            import warnings
            msg = (f"particle pool full (particles.capacity = {self.capacity}): splits/emission "
                   f"refused and counted in stats (refused); the simulation goes on coarser")
            self.warnings.append(msg)
            warnings.warn(msg, RuntimeWarning, stacklevel=3)

    def _stirrers(self, t):
        for i, st in enumerate(self.scene.data["stirrers"]):     # at most MAX_STIRRERS (config)
            pos, vel = path_sample(st["path"], t, st["loop"])
            self.disturbances.set(1 + i, Disturbance(tuple(pos), st["radius"], st["strength"],
                                                     st["mode"], tuple(vel)))

    # ------------------------------------------------------------------ kernels
    @ti.func
    def _image_in_solid(self, xj, p0, nrm):
        """Is x_j's mirror image across the plane (p0, nrm) inside an obstacle? Near a
        convex corner the tangent-plane mirror puts some images back in the fluid; those
        must not count, or the corner pushes fluid away."""
        img = xj - 2.0 * (xj - p0).dot(nrm) * nrm
        phi, _n = self.boundary.obstacle_sdf(img)
        return phi < 0.0

    @ti.func
    def _density_sum(self, xq, l, h2, c6, p0, nrm, check: ti.template(), i, record: ti.template()):
        """Σ_j m_j W_poly6(xq − x_j) over level l (real and virtual), for xq a particle's
        position or one of its wall images (``check``: obstacle images, see above).
        ``record``: xq is particle i itself; list its neighbours and count them."""
        p = ti.static(self.pool.p)
        rho = 0.0
        count = 0
        last = ti.static(self.max_neighbours)   # the spare slot past the list
        base = self.grids.around(xq, l)
        for o in ti.grouped(ti.ndrange(*self.grids.row_axes)):
            lo, hi = self.grids.row(base, o, l)
            for j in range(lo, hi):
                r2 = (xq - p[j].x).norm_sqr()
                if ti.static(BRANCH_FREE and not check):
                    d = h2 - r2
                    d = ti.max(d, 0.0)
                    rho += self._sum_mass(j) * (d * d * d)
                    if ti.static(record):
                        # written every time, kept only when counted; a list that
                        # overflowed into the spare slot is not read (forces use the grid)
                        self.neighbours[i, ti.min(count, last)] = j
                        count += ti.cast(r2 < h2 and j != i, ti.i32)
                elif r2 < h2:
                    ok = True
                    if ti.static(check):
                        ok = self._image_in_solid(p[j].x, p0, nrm)
                    if ok:
                        rho += self._sum_mass(j) * poly6(r2, h2, 1.0)
                    if ti.static(record):
                        if j != i:
                            self.neighbours[i, ti.min(count, last)] = j
                            count += 1
        if ti.static(record):
            self.neighbour_count[i] = count
        return rho * c6 * self._sum_scale()

    @ti.func
    def _sum_mass(self, j):
        """m_j as a density or force sum weighs particle j. Without adaptivity every
        particle has the nominal mass m0 (one level, no split or merge): the sums count 1
        and are scaled by m0 (m0² for the pair forces) once (``_sum_scale``), one load
        fewer per candidate or pair (from the flowing dam break, two threads, 10th
        percentile of 100-300 steps timed one by one, median of 4 alternated runs: 3D
        30k particles 12.66 -> 12.23 ms a step, 2D 50k 5.28 -> 5.17 ms)."""
        m = 1.0
        if ti.static(self.adaptive):
            m = self.pool.p[j].m
        return m

    @ti.func
    def _sum_scale(self):
        s = 1.0
        if ti.static(not self.adaptive):
            s = self.lev_m[0]
        return s

    @ti.func
    def _listed_density(self, xr, i, h2, c6):
        """Σ m_j W(xr − x_j) over i and its listed neighbours, xr a mirror image of x_i
        across domain walls. That is every particle within h of xr: mirroring across a
        wall only moves a point on the fluid side away from the others on that side, so
        |xr − x_j| < h implies |x_i − x_j| < h. (Virtual particles may sit inside a wall;
        their images are not counted.) Near walls this replaces a scan of the grid block
        around xr: a quarter of the particles of the 3D dam break have an image."""
        p = ti.static(self.pool.p)
        r2 = (xr - p[i].x).norm_sqr()
        rho = self._sum_mass(i) * poly6(r2, h2, 1.0) if r2 < h2 else 0.0
        for q in range(self.neighbour_count[i]):
            j = self.neighbours[i, q]
            r2 = (xr - p[j].x).norm_sqr()
            if r2 < h2:
                rho += self._sum_mass(j) * poly6(r2, h2, 1.0)
        return rho * c6 * self._sum_scale()

    @ti.kernel
    def _density(self, n: ti.i32):
        """ρ_i = Σ_j m_j W(x_i − x_j, h_l) over the own level (Eq. 7), walls as ghosts.

        The same pass records each particle's neighbours (same level, r < h, itself
        excluded) for the force and coupling phases; the pool is sorted and nothing has
        moved since, so [0, n) holds no DEAD slot and every cell lists live particles.
        Particles go DENSITY_CLUSTER at a time through one scan of the grid where they
        can (``_scan_cluster``), else one by one.
        With the virtual-mass limiter on, ``_list_fine_neighbours`` has already listed the
        neighbours of every real particle below the coarsest level this step (by
        clusters as well); those sum over their list instead of scanning the grid again.
        Measured on the adaptive 3D
        15 mm pair from t = 0.2 s, one thread, three windows of 300 steps: 2.08, 3.25,
        4.34 ms a step when the limiter and the density pass each scanned the grid; 1.98,
        2.90, 3.73 when the limiter's scan listed for the density pass; 1.90, 2.70, 3.46 as
        here, the search in its own branch-free kernel and the limiter reading the lists
        (virtual coupling 1.69 -> 0.47 ms a step). The 2D 3.5 mm pair, a fifth of its
        particles below the coarsest level, went from 1.34 to 1.41 ms (one more launch)."""
        p = ti.static(self.pool.p)
        K = ti.static(DENSITY_CLUSTER[self.dim])
        for t in range((n + K - 1) // K):
            i0 = K * t
            scanned = 0
            if i0 + K <= n:
                scanned = self._scan_cluster(i0, False)
            for q in range(K):      # not unrolled: one copy of the code below
                i = i0 + q
                if i < n and not self._density_skip(i):
                    l, h, h2, c6 = self._support(i)
                    rho = 0.0
                    if (scanned >> q) & 1:
                        rho = p[i].rho          # its sum, left there by the cluster's scan
                    elif self._listed_already(i):
                        rho = self._listed_density(p[i].x, i, h2, c6)
                    else:
                        zero = ti.Vector.zero(float, self.dim)
                        rho = self._density_sum(p[i].x, l, h2, c6, zero, zero, False, i, True)
                    self._density_finish(i, rho)

    @ti.func
    def _density_skip(self, i):
        """Particles the density pass leaves alone."""
        p = ti.static(self.pool.p)
        skip = p[i].kind == DEAD
        if ti.static(self.variational):
            # a virtual particle's state comes from its owners (_virtual_state), and
            # its reactions are handed on by the force pass: no sum, no list
            skip = skip or is_virtual(p[i].kind)
        return skip

    @ti.func
    def _listed_already(self, i):
        """Has ``_list_fine_neighbours`` listed i's neighbours this step (see ``_density``)?"""
        listed = False
        if ti.static(self.limit_virtual):
            listed = self._fine_real(i) and self.neighbour_count[i] <= ti.static(self.max_neighbours)
        return listed

    @ti.func
    def _scan_cluster(self, i0, list_only: ti.template()):
        """One scan of the grid for the K particles i0 … i0+K−1 (``DENSITY_CLUSTER``): the
        density pass's sums and neighbour lists for those that need a scan (not skipped,
        not listed already), or, with ``list_only``, the lists of the fine real particles
        (``_list_fine_neighbours``). It applies if those particles share a level and a
        column of cells (the same cell on every axis but the last): their blocks of cells
        then have the same rows, and the scan walks each row once over the union of their
        spans, K distances a candidate. Returns the scanned members as bits (bit q:
        i0 + q), each with its list written and its own-level sum in ``rho`` (the density
        pass adds its wall images); 0, having done nothing, if they do not share a
        column: the caller then takes them one by one. A candidate outside a particle's
        support adds exactly zero to its sum and is not listed, so the result is the
        one-by-one sum up to rounding (the same candidates in the same order, zeros
        between). The other members ride along: their sums are dropped and their list
        writes go to the spare slot."""
        p = ti.static(self.pool.p)
        K = ti.static(DENSITY_CLUSTER[self.dim])
        D = ti.static(self.dim - 1)     # the axis along the rows
        l = p[i0].level
        base = self.grids.around(p[i0].x, l)
        ok = True
        found = False
        lo_c, hi_c = 0, 0
        scans = ti.Vector.zero(ti.i32, K)
        scanned = 0
        for q in ti.static(range(K)):
            i = i0 + q
            scan = False
            if ti.static(list_only):
                scan = self._fine_real(i)
            else:
                scan = not (self._density_skip(i) or self._listed_already(i))
            if scan:
                scans[q] = 1
                b = self.grids.around(p[i].x, l)
                if not found:
                    found = True
                    base, lo_c, hi_c = b, b[D], b[D]
                ok = ok and p[i].level == l
                for a in ti.static(range(D)):
                    ok = ok and b[a] == base[a]
                lo_c = ti.min(lo_c, b[D])
                hi_c = ti.max(hi_c, b[D])
        if ok and found:
            h = self.lev_h[l]
            h2, c6 = h * h, self.lev_poly6[l]
            last = ti.static(self.max_neighbours)   # the spare slot past the list
            base[D] = lo_c
            span = hi_c - lo_c + ti.static(2 * self.grids.reach + 1)
            xs = ti.Matrix.rows([p[i0 + q].x for q in ti.static(range(K))])
            rho = ti.Vector.zero(float, K)
            count = ti.Vector.zero(ti.i32, K)
            for o in ti.grouped(ti.ndrange(*self.grids.row_axes)):
                lo, hi = self.grids.row_span(base, o, l, span)
                for j in range(lo, hi):
                    xj = p[j].x
                    m = self._sum_mass(j)
                    for q in ti.static(range(K)):
                        r2 = 0.0
                        for a in ti.static(range(self.dim)):
                            r2 += (xs[q, a] - xj[a]) ** 2
                        if ti.static(not list_only):
                            d = ti.max(h2 - r2, 0.0)
                            rho[q] += m * (d * d * d)
                        # written every time, kept only when counted (see _density_sum)
                        self.neighbours[i0 + q, ti.select(scans[q] != 0, ti.min(count[q], last), last)] = j
                        count[q] += ti.cast(r2 < h2 and j != i0 + q, ti.i32)
            scale = c6 * self._sum_scale()
            for q in ti.static(range(K)):
                if scans[q] != 0:
                    self.neighbour_count[i0 + q] = count[q]
                    if ti.static(not list_only):
                        p[i0 + q].rho = rho[q] * scale
                    scanned |= 1 << q
        return scanned

    @ti.func
    def _density_finish(self, i, rho_own):
        """Particle i's density from its own-level sum plus its wall images (its
        neighbour list written), then its pressure and the factors the force pass reads."""
        p = ti.static(self.pool.p)
        l, h, h2, c6 = self._support(i)
        xi = p[i].x
        zero = ti.Vector.zero(float, self.dim)
        rho = rho_own
        listed = self.neighbour_count[i] <= ti.static(self.max_neighbours)
        for mask in range(1, 2 ** self.dim):
            ok, xr, _s = self.boundary.domain_image(xi, h, mask)
            if ok:
                if listed:
                    rho += self._listed_density(xr, i, h2, c6)
                else:
                    rho += self._density_sum(xr, l, h2, c6, zero, zero, False, i, False)
        ok, xo, nrm = self.boundary.obstacle_image(xi, h)
        if ok:
            rho += self._density_sum(xo, l, h2, c6, 0.5 * (xi + xo), nrm, True, i, False)
        p[i].rho = rho
        p[i].p = pressure(rho, self.rest_density, self.k[None], self.gamma, self.tait, self.clamp)
        self._pair_factors(i)

    @ti.func
    def _support(self, i):
        """Particle i's level, its support h, h² and poly6 constant."""
        l = self.pool.p[i].level
        h = self.lev_h[l]
        return l, h, h * h, self.lev_poly6[l]

    @ti.func
    def _pair_factors(self, i):
        p = ti.static(self.pool.p)
        inv = 1.0 / p[i].rho
        self.inv_rho[i] = inv
        self.press_term[i] = self._partner_pressure(p[i].kind, p[i].p) * inv * inv

    @ti.func
    def _share_term(self, j, r2, h2, c6):
        """Particle j's part of ``_share_sums`` at squared distance r2 < h2."""
        p = ti.static(self.pool.p)
        acc = ti.Vector.zero(float, 3)
        w = poly6(r2, h2, c6)
        if p[j].kind == VIRTUAL_CHILD:
            par = p[j].parent
            wv = p[par].m / ti.static(2 ** self.dim) * w
            acc = ti.Vector([0.0, wv, wv * p[par].rho])
        else:
            acc[0] = p[j].m * w
        return acc

    @ti.func
    def _share_sums(self, xq, l, h2, c6, p0, nrm, check: ti.template()):
        """(Σ m_j W over level l's particles other than virtual children, Σ m̂_j W over its
        virtual children with m̂_j = 2^-d of the parent's mass, Σ m̂_j W ρ_parent), at xq
        (a particle or one of its wall images, as in ``_density_sum``), over the grid."""
        p = ti.static(self.pool.p)
        acc = ti.Vector.zero(float, 3)
        base = self.grids.around(xq, l)
        for o in ti.grouped(ti.ndrange(*self.grids.row_axes)):
            lo, hi = self.grids.row(base, o, l)
            for j in range(lo, hi):
                r2 = (xq - p[j].x).norm_sqr()
                if r2 < h2:
                    ok = True
                    if ti.static(check):
                        ok = self._image_in_solid(p[j].x, p0, nrm)
                    if ok:
                        acc += self._share_term(j, r2, h2, c6)
        return acc

    @ti.func
    def _listed_share_sums(self, xr, i, h2, c6):
        """``_share_sums`` at x_i or one of its domain-wall images, over i and its listed
        neighbours (every particle within h of such an image, see ``_listed_density``)."""
        p = ti.static(self.pool.p)
        acc = ti.Vector.zero(float, 3)
        r2 = (xr - p[i].x).norm_sqr()
        if r2 < h2:
            acc += self._share_term(i, r2, h2, c6)
        for q in range(self.neighbour_count[i]):
            j = self.neighbours[i, q]
            r2 = (xr - p[j].x).norm_sqr()
            if r2 < h2:
                acc += self._share_term(j, r2, h2, c6)
        return acc

    @ti.func
    def _fine_real(self, i):
        """A real particle below the coarsest level: the particles the limiter bounds and
        ``_list_fine_neighbours`` lists, whose lists ``_density`` then reads."""
        return is_real(self.pool.p[i].kind) and self.pool.p[i].level < self.levels - 1

    @ti.kernel
    def _list_fine_neighbours(self, n: ti.i32):
        """The density pass's neighbour search for the real particles below the coarsest
        level, done ahead of it because the virtual-mass limiter reads the lists first:
        the grid scan and recording of ``_density_sum``, its sum not kept (the virtual
        masses it summed are last step's), taken ``DENSITY_CLUSTER`` particles at a time
        where they share a column of cells, as the density pass does. ``_density`` then
        sums over these lists."""
        p = ti.static(self.pool.p)
        K = ti.static(DENSITY_CLUSTER[self.dim])
        for t in range((n + K - 1) // K):
            i0 = K * t
            scanned = 0
            if i0 + K <= n:
                scanned = self._scan_cluster(i0, True)
            for q in range(K):      # not unrolled
                i = i0 + q
                if i < n and self._fine_real(i) and not (scanned >> q) & 1:
                    l, h, h2, c6 = self._support(i)
                    zero = ti.Vector.zero(float, self.dim)
                    self._density_sum(p[i].x, l, h2, c6, zero, zero, False, i, True)

    @ti.kernel
    def _limit_virtual_mass(self, n: ti.i32):
        """Scale each virtual child's mass for this step so that no real particle's
        density is pushed past its target by virtual children: 2^-d of its parent's mass
        times the least share s_i allowed by the real particles i within its support.

        s_i in [0, 1], for a real particle i below the coarsest level, is the largest share
        of their nominal masses that the virtual children around i may carry so that
        ρ_i = R_i + s_i V_i stays at or below the target ρ_t (R_i: from the other particles
        of the level, V_i: from the virtual children at nominal mass). ρ_t is the largest of
        (1 + τ) times the mean density of the parents of those virtual children, weighted
        as in V_i (τ = ``adaptivity.virtual_density_tolerance``); i's own density of the
        last step, so that a fine particle compressed by its real neighbours keeps its
        virtual ones; and ρ0, below which the pressure is clamped and no force comes of the
        virtual mass. Each real particle hands s_i to the virtual children it lists (a
        virtual child keeps the least), reading the neighbour lists of
        ``_list_fine_neighbours`` (the grid where a list overflowed, and for obstacle images).

        Why: virtual children sit on a fixed lattice around their parents, but coarse
        particles are often closer than their spacing (in a thin sheet the coarse density
        is below rho0 and its pressure clamped to 0, so nothing keeps them apart); their
        lattices then overlap each other and the real fine particles already there.
        Measured in the 2D dam break of tests/test_adaptive_flow.py: when the neighbour of
        a split particle became a transient parent, the fine density of the new children
        jumped from 0.79 to 1.25 rho0 and they were thrown off at 5.9 m/s in a 2.4 m/s
        front. Virtual masses are not part of the fluid's mass (METHOD.md §3), and a force
        on a virtual child still goes to its parent, so mass and momentum are kept.

        Why the tolerance and the floor: with ρ_t the parents' density alone the limiter
        ratchets in a resting pool (a cut virtual mass lowers the fine pressure beside it,
        fine particles move in, which cuts more), and it cuts in a sheet where the fine
        density is below ρ0 and no pressure comes of it anyway. Measured with
        tests/test_adaptive_flow.py's scenes, gathers where the coarse level is wanted
        (``gather_coarse_only``): pool mean speed 0.033 → 0.012 sqrt(gH) (2D) and 0.050 →
        0.032 (3D), means of three viscosities; the 2D dam break front within +0.5..+1.2 %
        of the uniform run's (98 % mass quantile, three viscosities), where it varied from
        -5 % to +10 % before. The tolerance is bounded by the spray: at τ = 0.1 the 2D dam
        break throws particles at 7.6 m/s again (uniform: 4.0 m/s). The target must not be
        i's own density times (1 + τ): that lets it grow by τ each step, a ratchet upwards
        (measured: spray at 6 m/s).
        """
        p = ti.static(self.pool.p)
        # virtual_share is 1 everywhere between calls (filled at the start, put back by
        # the last loop), which saves a loop that set it
        for i in range(n):
            if self._fine_real(i):
                l, h, h2, c6 = self._support(i)
                xi = p[i].x
                zero = ti.Vector.zero(float, self.dim)
                listed = self.neighbour_count[i] <= ti.static(self.max_neighbours)
                acc = ti.Vector.zero(float, 3)
                if listed:
                    acc = self._listed_share_sums(xi, i, h2, c6)
                else:
                    acc = self._share_sums(xi, l, h2, c6, zero, zero, False)
                for mask in range(1, 2 ** self.dim):
                    ok, xr, _s = self.boundary.domain_image(xi, h, mask)
                    if ok:
                        if listed:
                            acc += self._listed_share_sums(xr, i, h2, c6)
                        else:
                            acc += self._share_sums(xr, l, h2, c6, zero, zero, False)
                ok, xo, nrm = self.boundary.obstacle_image(xi, h)
                if ok:
                    acc += self._share_sums(xo, l, h2, c6, 0.5 * (xi + xo), nrm, True)
                if acc[1] > 0.0:
                    target = ti.max(acc[2] / acc[1] * ti.static(1.0 + self.virtual_tolerance),
                                    p[i].rho, ti.static(self.rest_density))
                    share = ti.min(ti.max((target - acc[0]) / acc[1], 0.0), 1.0)
                    if share < 1.0:
                        count = self.neighbour_count[i]
                        if count <= ti.static(self.max_neighbours):
                            for q in range(count):
                                j = self.neighbours[i, q]
                                if p[j].kind == VIRTUAL_CHILD:
                                    ti.atomic_min(self.virtual_share[j], share)
                        else:
                            base = self.grids.around(xi, l)
                            for o in ti.grouped(ti.ndrange(*self.grids.row_axes)):
                                lo, hi = self.grids.row(base, o, l)
                                for j in range(lo, hi):
                                    if p[j].kind == VIRTUAL_CHILD and (xi - p[j].x).norm_sqr() < h2:
                                        ti.atomic_min(self.virtual_share[j], share)
        for j in range(n):
            if p[j].kind == VIRTUAL_CHILD:
                p[j].m = self.virtual_share[j] * p[p[j].parent].m / ti.static(2 ** self.dim)
            self.virtual_share[j] = 1.0

    @ti.kernel
    def _virtual_state(self, n: ti.i32):
        """Variational coupling: a virtual particle is a piece of real matter seen from
        another level (a virtual child 1/2^d of its transient parent, a virtual parent the
        sum of its transient children), so it takes their density, pressure and velocity
        (mass-weighted for a virtual parent), not those of its own neighbourhood, where
        virtual children of neighbouring parents overlap each other and the walls."""
        p = ti.static(self.pool.p)
        for j in range(n):
            kj = p[j].kind
            if kj == VIRTUAL_CHILD:
                par = p[j].parent
                p[j].rho = p[par].rho
                p[j].p = p[par].p
                p[j].v = p[par].v
                self._pair_factors(j)
            elif kj == VIRTUAL_PARENT:
                m, r, pr = 0.0, 0.0, 0.0
                mv = ti.Vector.zero(float, self.dim)
                for q in range(p[j].nchild):
                    ch = self.pool.children[j, q]
                    m += p[ch].m
                    r += p[ch].m * p[ch].rho
                    pr += p[ch].m * p[ch].p
                    mv += p[ch].m * p[ch].v
                if m > 0.0:
                    p[j].rho = r / m
                    p[j].p = pr / m
                    p[j].v = mv / m
                    self._pair_factors(j)

    @ti.func
    def _ghost_force(self, i, xq, L, l, h, cs, cv, mu, skip2, p0, nrm, check: ti.template(), listed):
        """Force on i from the mirror images of its level's particles: xq is i's image and
        L the reflection's linear part, so x_i − x_j' = L (xq − x_j) and u_j' = L u_j.
        ``listed``: the images of i and its neighbour list are all there are (domain
        walls, see ``_listed_density``); otherwise the cells around xq are scanned."""
        f = ti.Vector.zero(float, self.dim)
        if listed:
            f = self._ghost_pair(i, i, xq, L, h, cs, cv, mu, skip2, p0, nrm, check)
            for q in range(self.neighbour_count[i]):
                f += self._ghost_pair(i, self.neighbours[i, q], xq, L, h, cs, cv, mu, skip2, p0, nrm, check)
        else:
            base = self.grids.around(xq, l)
            for o in ti.grouped(ti.ndrange(*self.grids.row_axes)):
                lo, hi = self.grids.row(base, o, l)
                for j in range(lo, hi):
                    f += self._ghost_pair(i, j, xq, L, h, cs, cv, mu, skip2, p0, nrm, check)
        return f

    @ti.func
    def _ghost_pair(self, i, j, xq, L, h, cs, cv, mu, skip2, p0, nrm, check: ti.template()):
        p = ti.static(self.pool.p)
        rq = xq - p[j].x
        r2 = rq.norm_sqr()
        ok = 0.0 < r2 < h * h and self._interacts(j, r2, skip2)
        if ti.static(check):
            if ok:
                ok = self._image_in_solid(p[j].x, p0, nrm)
        return self._force_if(ok, i, j, p[i].v, L @ p[j].v, L @ rq, r2, h, cs, cv, mu)

    @ti.func
    def _force_if(self, ok, i, j, vi, vj, r, r2, h, cs, cv, mu):
        """``_pair_force_values`` where ``ok``, else zero. Branch-free in a uniform run:
        computed for every candidate with |r| kept in (0, h] (finite for any r2, and zero
        beyond h, where h - |r| = 0) and masked, which also drops a pair at r = 0 as the
        branch does; the listed neighbours are all within h, so little is
        wasted, and which wall images are in reach is unpredictable. One thread, forces
        of the 2D 50k dam break 4.5 -> 3.8-3.9 ms, of the 3D 100k one 28.0 -> 18.4 ms (the
        wall images' share of that: 19.0-19.6 -> 18.4). With a branch in an adaptive run,
        where masking cost more than it saved (3D 15 mm pair: 1.06 -> 1.15 ms)."""
        f = ti.Vector.zero(float, self.dim)
        if ti.static(self.adaptive):
            if ok:
                f = self._pair_force_values(i, j, vi, vj, r, ti.sqrt(r2), h, cs, cv, mu)
        else:
            rn = ti.min(ti.sqrt(ti.max(r2, 1e-30)), h)
            f = self._pair_force_values(i, j, vi, vj, r, rn, h, cs, cv, mu) * ti.cast(ok, float)
        return f

    @ti.func
    def _pair_force_values(self, i, j, vi, vj, r, rn, h, cs, cv, mu):
        """Force on i from j: pressure (Eq. 16), viscosity (Eq. 19) and artificial viscosity,
        times i's volume.

        The artificial viscosity is Monaghan's (1992), F_i = m_i m_j α c h (u_ij·r_ij) /
        (ρ̄_ij (r² + 0.01 h²)) ∇W_spiky for approaching pairs (u_ij·r_ij < 0), ρ̄ the mean
        density. Why: a resting pool's square lattice is not a stable packing under
        pressure (the pair pressure forces push a row sliding along its neighbours
        further), so it rearranges within a second and the energy set free rings on as
        particle-scale motion that the viscosity, μ ∇²u, damps too slowly at μ = 2 Pa s
        (measured in the tank of tests/test_physics.py: 0.011–0.028 sqrt(gH) of mean
        speed at 1.5 s; 0.0002 with α = 0.2). Like the pressure term it is antisymmetric
        in the pair and along r, so momentum is still conserved.

        Written for speed (it runs ~11 times per particle in 2D, ~33 in 3D): p/ρ² and 1/ρ
        come from ``_pair_factors``, no branch on the approach (the artificial term is
        scaled by min(u_ij·r_ij, 0)), and one division, 1/(|r| ρ̄ (r² + ε h²)), serves
        both the kernel gradient's 1/|r| and the artificial term.
        """
        p = ti.static(self.pool.p)
        mm = self._sum_mass(i) * self._sum_mass(j)
        rho_bar = 0.5 * (p[i].rho + p[j].rho)
        soft = rn * rn + AV_EPS * h * h
        inv = 1.0 / (rn * rho_bar * soft)        # = 1 / (|r| ρ̄ (r² + ε h²))
        d = h - rn
        grad = -3.0 * cs * d * d * (rho_bar * soft * inv)    # ∇W_spiky = grad · r
        approach = ti.min((vi - vj).dot(r), 0.0)
        along = (-(self.press_term[i] + self.press_term[j]) * grad
                 + self.av_coef[None] * h * approach * (-3.0 * cs * d * d * inv))
        visc = mu * cv * d * self.inv_rho[i] * self.inv_rho[j]
        return mm * (along * r + visc * (vj - vi))

    @ti.func
    def _pair_force(self, i, j, r, rn, h, cs, cv, mu):
        p = ti.static(self.pool.p)
        return self._pair_force_values(i, j, p[i].v, p[j].v, r, rn, h, cs, cv, mu)

    @ti.func
    def _partner_pressure(self, kind_j, p_j):
        """The pressure of particle j as it enters the pair force on a real particle.

        Variational coupling (``adaptivity.coupling``): 0 for a virtual j. The pressure
        forces then derive from one energy, Σ over real particles of m u(ρ), in which
        each real particle's density sums its own level, virtual particles included, and
        each virtual position is a function of its owners' (``_advect_one``): a real
        particle's pressure pushes its same-level neighbours, real or virtual, and the
        virtual ones hand the reaction to their owners. A fine–coarse pair thus meets
        twice, once with each particle's own pressure, and its pressure acts once.
        Its viscous and artificial-viscosity terms are whole pair terms in both meetings,
        so the shear across a level interface is coupled twice over. Halving them for
        virtual partners, as the pressure is halved, was measured (tests/
        test_adaptive_flow.py, session of 2026-11-22): the refined pool's mean speed
        0.0086 sqrt(gH) in 2D (0.0032-0.0063 as here) and 0.0062 in 3D (0.0061-0.0077),
        the dam-break fronts +5.0 % in 2D (then +3.7 % without) and +4.3 % in 3D (+3.6 %):
        with less damping at the interface the fine fluid runs further ahead, so the
        interface keeps the extra damping.
        Measured then in a resting pool with a refined box (2D, 2 levels, no adaptivity after
        the start): mean speed 0.0069 sqrt(gH), against 0.017 with the symmetric form,
        whose virtual pressures come from virtual densities that reach 1.3 ρ0 where
        virtual children overlap each other and the walls.
        """
        result = p_j
        if ti.static(self.variational):
            if is_virtual(kind_j):
                result = 0.0
        return result

    @ti.func
    def _interacts(self, j, r2, skip2):
        """``interacts`` for particle j; in a uniform run (no virtual particles) always
        true, without the load of j's kind and the test per pair (forces of the 2D 50k dam
        break on one thread: 5.9 -> 4.5 ms)."""
        ok = True
        if ti.static(self.adaptive):
            ok = interacts(self.pool.p[j].kind, r2, skip2)
        return ok

    @ti.func
    def _force_from(self, i, j, xi, h, cs, cv, mu, skip2):
        """Force on real particle i from same-level particle j (zero beyond h, or when the
        pair meets at the finer level instead, see ``interacts``)."""
        p = ti.static(self.pool.p)
        r = xi - p[j].x
        r2 = r.norm_sqr()
        ok = 0.0 < r2 < h * h and self._interacts(j, r2, skip2)
        return self._force_if(ok, i, j, p[i].v, p[j].v, r, r2, h, cs, cv, mu)

    @ti.func
    def _coupling_from(self, j, i, xj, h, h2, cs, cv, c6, mu, reach2):
        """Virtual particle j and real particle i: (reaction on j, interpolation weight of
        i for j's velocity)."""
        p = ti.static(self.pool.p)
        reaction = ti.Vector.zero(float, self.dim)
        w = 0.0
        r = p[i].x - xj
        r2 = r.norm_sqr()
        if r2 < h2 and is_real(p[i].kind):
            if r2 > 0.0 and self._interacts(j, r2, skip_reach2(p[i].kind, reach2)):
                reaction = -self._pair_force(i, j, r, ti.sqrt(r2), h, cs, cv, mu)
            w = p[i].m / p[i].rho * poly6(r2, h2, c6)
        return reaction, w

    @ti.func
    def _hand_on(self, j, r, into: ti.template()):
        """Add the reaction r on virtual particle j to ``into`` of the real particle(s) j
        stands for, split evenly (METHOD.md §4, thesis Fig. 7): a virtual child's
        transient parent, or a virtual parent's children."""
        p = ti.static(self.pool.p)
        if p[j].kind == VIRTUAL_CHILD:
            ti.atomic_add(into[p[j].parent], r)
        else:
            share = r / ti.max(p[j].nchild, 1)
            for q in range(p[j].nchild):
                ti.atomic_add(into[self.pool.children[j, q]], share)

    @ti.func
    def _force_and_reaction(self, i, j, xi, h, cs, cv, mu, skip2):
        """``_force_from``; with the variational coupling a virtual j also hands the
        reaction on to its owners here, since it computes no force of its own."""
        f = self._force_from(i, j, xi, h, cs, cv, mu, skip2)
        if ti.static(self.variational):
            if is_virtual(self.pool.p[j].kind):
                self._hand_on(j, -f, self.reaction)
        return f

    @ti.kernel
    def _forces(self, n: ti.i32, c_sound: float, stirred: ti.i32):
        """Internal forces on real particles from every same-level neighbour, real or
        virtual. With the variational coupling the reactions of the virtual ones are
        handed on to their owners in the same pass (the symmetric coupling does it in
        ``_virtual_coupling``, which also needs the virtual velocities first); they are
        added to the owners' forces with the accelerations, in ``_end_step``.

        Without adaptivity nothing else adds to a particle's force once its own iteration
        is done, so the same loop turns it into an acceleration and takes the time-step
        limits (``_accelerate``): one parallel loop fewer a step, each of which costs
        50-100 µs of thread wake-ups on two cores (uniform 2D dam break, 50k particles, two
        threads, from t = 0.25 s: 5.42 -> 5.31 ms a step, 10th percentile of 300 steps
        timed one by one, median of 4 alternated runs)."""
        p = ti.static(self.pool.p)
        mu = self.mu[None]
        g = self.gravity[None]
        mm = self._sum_scale() * self._sum_scale()   # m_i m_j, when every pair term left it out
        if ti.static(self.fused_accelerations):
            self._clear_reductions()
        for i in range(n):
            f = ti.Vector.zero(float, self.dim)
            if is_real(p[i].kind):
                l = p[i].level
                h = self.lev_h[l]
                cs, cv = self.lev_spiky[l], self.lev_visc[l]
                skip2 = skip_reach2(p[i].kind, self.lev_reach2[l])
                xi = p[i].x
                count = self.neighbour_count[i]
                listed = count <= ti.static(self.max_neighbours)
                if listed:
                    for q in range(count):
                        f += self._force_and_reaction(i, self.neighbours[i, q], xi, h, cs, cv, mu, skip2)
                else:   # more neighbours than the list holds: the grid, as the density did
                    base = self.grids.around(xi, l)
                    for o in ti.grouped(ti.ndrange(*self.grids.row_axes)):
                        lo, hi = self.grids.row(base, o, l)
                        for j in range(lo, hi):
                            f += self._force_and_reaction(i, j, xi, h, cs, cv, mu, skip2)
                # walls: forces from the mirror images of the neighbours (boundary.py)
                for mask in range(1, 2 ** self.dim):
                    ok, xr, sgn = self.boundary.domain_image(xi, h, mask)
                    if ok:
                        Ld = ti.Matrix.zero(float, self.dim, self.dim)
                        for k in ti.static(range(self.dim)):
                            Ld[k, k] = sgn[k]
                        f += self._ghost_force(i, xr, Ld, l, h, cs, cv, mu, skip2, xi, xi, False, listed)
                ok, xo, nrm = self.boundary.obstacle_image(xi, h)
                if ok:
                    Lo = ti.Matrix.identity(float, self.dim) - 2.0 * nrm.outer_product(nrm)
                    f += self._ghost_force(i, xo, Lo, l, h, cs, cv, mu, skip2, 0.5 * (xi + xo), nrm, True, False)
            p[i].a = f * mm
            if ti.static(self.fused_accelerations):
                if is_real(p[i].kind):
                    cfl, force, bad = self._accelerate(i, g, c_sound, stirred)
                    if bad:
                        ti.atomic_add(self.red_i[0], 1)
                        ti.atomic_min(self.red_i[1], i)
                    else:
                        # test first: the maxima rarely grow, and an atomic float max is
                        # a compare-and-swap loop on a line both threads share
                        if cfl > self.red_f[0]:
                            ti.atomic_max(self.red_f[0], cfl)
                        if force > self.red_f[1]:
                            ti.atomic_max(self.red_f[1], force)

    @ti.kernel
    def _virtual_coupling(self, n: ti.i32):
        """Hand the reaction of each real–virtual force to the real particles the virtual one
        stands for, split evenly (METHOD.md §4, thesis Fig. 7), and interpolate the
        virtual particle's velocity from the real particles of its level.

        Symmetric coupling only; the variational coupling hands its reactions on in the
        force pass (``_hand_on``) and takes its velocities from the owners.
        """
        p = ti.static(self.pool.p)
        mu = self.mu[None]
        for j in range(n):
            kj = p[j].kind
            if is_virtual(kj):
                l = p[j].level
                h = self.lev_h[l]
                h2 = h * h
                cs, cv, c6 = self.lev_spiky[l], self.lev_visc[l], self.lev_poly6[l]
                reach2 = self.lev_reach2[l]
                xj = p[j].x
                reaction = ti.Vector.zero(float, self.dim)
                vsum = ti.Vector.zero(float, self.dim)
                wsum = 0.0
                count = self.neighbour_count[j]
                if count <= ti.static(self.max_neighbours):
                    for q in range(count):
                        i = self.neighbours[j, q]
                        dr, w = self._coupling_from(j, i, xj, h, h2, cs, cv, c6, mu, reach2)
                        reaction += dr
                        vsum += w * p[i].v
                        wsum += w
                else:
                    base = self.grids.around(xj, l)
                    for o in ti.grouped(ti.ndrange(*self.grids.row_axes)):
                        lo, hi = self.grids.row(base, o, l)
                        for i in range(lo, hi):
                            if i != j:
                                dr, w = self._coupling_from(j, i, xj, h, h2, cs, cv, c6, mu, reach2)
                                reaction += dr
                                vsum += w * p[i].v
                                wsum += w
                self._hand_on(j, reaction, p.a)
                # the velocity interpolated from the real particles of the level
                if wsum > 0.0:
                    p[j].v = vsum / wsum
                elif kj == VIRTUAL_CHILD:
                    p[j].v = p[p[j].parent].v
                else:
                    vm = ti.Vector.zero(float, self.dim)
                    for q in range(p[j].nchild):
                        vm += p[self.pool.children[j, q]].v
                    p[j].v = vm / ti.max(p[j].nchild, 1)

    # ------------------------------------------------------------------ end of the step
    def _finish_step(self, n: int, max_dt: float | None, stirred: int) -> float:
        """Accelerations, the time step, integration, boundaries and (adaptive runs) the
        virtual particles' advection: one kernel launch, integration and boundaries in one
        loop, or when profiling one call a phase, each timed as its own. Returns dt.

        dt = min(dt_max, CFL bound, force bound, viscous bound, disturbance bound), then
        cut to ``max_dt`` (the end of a frame) after the check against ``physics.dt_min``.

        The viscous bound: Eq. 19 relaxes a particle's velocity towards its neighbours' at
        a rate μ/ρ Σ_j V_j ∇²W ≈ 15 μ/(ρ h²) (3D; 13.3 in 2D), and the shortest mode, a
        particle against its neighbours, twice as fast; explicit Euler on that mode needs
        dt < h²ρ/(15 μ) ≈ 0.067 h²ρ/μ, so ``viscous_factor`` 0.03 keeps half of it in
        hand (as Morris et al. 1997's 0.125 h²/ν with their h, half our support). At the
        scenes' viscosities it is far above the CFL bound; it binds when the viscosity
        is raised live, which would otherwise blow up."""
        ph = self.scene.data["physics"]
        cap = float(ph["dt_max"])
        strength = self.disturbances.max_strength()
        if strength > 0:
            cap = min(cap, 0.5 / strength)   # the disturbance relaxation stays stable
        mu = float(self.scene.data["fluid"]["viscosity"])
        viscous_dt = math.inf
        if mu > 0:
            viscous_dt = float(ph["viscous_factor"]) * self.h0 ** 2 * self.rest_density / mu
            cap = min(cap, viscous_dt)
        args = (n, self._c_sound, stirred, float(ph["cfl"]), float(ph["force_factor"]), cap,
                float(ph["dt_min"]), math.inf if max_dt is None else float(max_dt))
        if self.profile:
            # One launch a part, so that each is timed; the fixed cost of a launch (its
            # arguments, result and sync), timed on an empty one, is charged once, to the
            # time step, as the fused launch pays it once. Charged to every part, it made
            # a few-µs loop look like ~25 µs: the 2D three-level pair's virtual advection
            # read 5 % of the step where its loop is 0.5 % (kernel profiler).
            fixed = self._phase(None, self._end_step, *args, 0)
            dt = self._phase("timestep", self._end_step, *args, END_TIMESTEP)
            for name, part in (("integrate", END_INTEGRATE), ("boundaries", END_BOUNDARIES),
                               ("virtual_advect", END_ADVECT)):
                if part & self._end_parts:
                    self._phase(name, self._end_step, *args, part, overhead=fixed)
        else:
            dt = self._end_step(*args, self._end_parts)
        if dt >= 0.0:
            return dt
        stable_dt, force_lim, bad, first_bad = self.step_report.to_numpy().tolist()
        if bad > 0:
            self._report_bad(int(first_bad), int(bad))
        if not stable_dt >= float(ph["dt_min"]):     # as the kernel decided (NaN included)
            if viscous_dt < float(ph["dt_min"]):
                raise SimulationError(
                    f"step {self.steps} (t = {self.time:.6g} s): the viscous time-step bound "
                    f"{viscous_dt:.3g} s is below physics.dt_min = {ph['dt_min']:g} s: "
                    f"fluid.viscosity = {mu:g} Pa s is too high for this resolution")
            raise SimulationError(
                f"step {self.steps} (t = {self.time:.6g} s): time step {stable_dt:.3g} s is below "
                f"physics.dt_min = {ph['dt_min']:g} s: {self._dt_cause(stable_dt, force_lim)}")
        raise AssertionError("a step that did not go left no reason in step_report")

    def _dt_cause(self, dt: float, force_lim: float) -> str:
        """Which bound of ``_finish_step`` made ``dt``: the disturbance cap, read from the
        disturbances, or one of the reduced rates: the force rate |a|/h is reported, and the
        CFL rate (c + |u|)/h is cfl / dt. Which level
        h belongs to is not reported, so a speed is given as at the finest one."""
        ph = self.scene.data["physics"]
        c = self._c_sound
        strength = self.disturbances.max_strength()
        if strength > 0 and dt >= 0.999 * 0.5 / strength:
            return (f"the disturbance bound 0.5/strength sets it (strength {strength:.3g} 1/s, "
                    "the mouse's or a stirrer's): lower that strength or physics.dt_min")
        force_dt = float(ph["force_factor"]) / math.sqrt(force_lim) if force_lim > 0 else math.inf
        if dt >= 0.999 * force_dt:
            return (f"the force bound sets it (largest |a|/h = {force_lim:.3g} 1/s^2): the fluid "
                    "is blowing up; lower the disturbance strength or physics.cfl")
        rate = float(ph["cfl"]) / dt
        speed = rate * self.h0 - c            # |u| if the fastest particle is at level 0
        if speed <= 0.01 * c:
            return (f"the sound speed sqrt(fluid.stiffness) = {c:.3g} m/s sets it (physics.cfl "
                    f"h / c, h0 = {self.h0:.3g} m); lower fluid.stiffness or physics.dt_min")
        return (f"the CFL bound sets it ((c + |u|)/h = {rate:.3g} 1/s with c = {c:.3g} m/s: a "
                f"particle at about {speed:.3g} m/s if at the finest level): the fluid is "
                "blowing up; lower the disturbance strength or physics.cfl")

    @ti.kernel
    def _end_step(self, n: ti.i32, c_sound: float, stirred: ti.i32, cfl: ti.f64, force_factor: ti.f64,
                  cap: ti.f64, dt_min: ti.f64, max_dt: ti.f64, parts: ti.template()) -> ti.f64:
        """The phases after the forces, those in ``parts`` (END_* bits):

        - timestep: a = F/m + g + disturbances, the CFL and force limits, NaN/Inf (in a
          uniform run the force pass has taken these), and dt = min(cap, cfl / CFL
          rate, force_factor / sqrt(force rate)), then cut to ``max_dt``;
        - integrate: symplectic Euler, u += dt a, then x += dt u;
        - boundaries: walls and obstacles (in integrate's loop when both are asked);
        - advect: virtual particles follow their owners (see ``_advect_one``).

        Nothing moves when a particle is bad or dt is below ``dt_min``: the host reports it
        with the particles as the step found them. Returns the dt taken, or -1 when the
        step does not go (the reasons are in ``step_report``); 0 without timestep. Scalars
        in and one out: on the CPU, a vector argument and a vector result cost ~50 µs a
        launch between them, more than integrating a few thousand particles."""
        p = ti.static(self.pool.p)
        out = ti.cast(0.0, ti.f64)
        if ti.static(parts & END_TIMESTEP):
            if ti.static(not self.fused_accelerations):
                self._accelerations(n, c_sound, stirred)
            cfl_lim = ti.cast(self.red_f[0], ti.f64)
            force_lim = ti.cast(self.red_f[1], ti.f64)
            dt = cap
            if cfl_lim > 0.0:
                dt = ti.min(dt, cfl / cfl_lim)
            if force_lim > 0.0:
                dt = ti.min(dt, force_factor / ti.sqrt(force_lim))
            self.step_go[None] = ti.cast(self.red_i[0] == 0 and dt >= dt_min, ti.i32)
            self.step_dt[None] = ti.min(dt, max_dt)
            out = self.step_dt[None]
            if not self.step_go[None]:
                out = -1.0
                self.step_report[0] = dt
                self.step_report[1] = force_lim
                self.step_report[2] = ti.cast(self.red_i[0], ti.f64)
                self.step_report[3] = ti.cast(self.red_i[1], ti.f64)
        if ti.static(parts & (END_INTEGRATE | END_BOUNDARIES)):
            for i in range(n):
                if self.step_go[None] and is_real(p[i].kind):
                    x, v = p[i].x, p[i].v
                    if ti.static(parts & END_INTEGRATE):
                        v += ti.cast(self.step_dt[None], float) * p[i].a
                        x += ti.cast(self.step_dt[None], float) * v
                    if ti.static(parts & END_BOUNDARIES):
                        x, v = self.boundary.collide(x, v)
                    p[i].x = x
                    p[i].v = v
        if ti.static(parts & END_ADVECT):
            for j in range(n):
                if self.step_go[None] and is_virtual(p[j].kind):
                    self._advect_one(j, ti.cast(self.step_dt[None], float))
        return out

    @ti.func
    def _clear_reductions(self):
        self.red_f[0] = 0.0
        self.red_f[1] = 0.0
        self.red_i[0] = 0
        self.red_i[1] = 2147483647

    @ti.func
    def _accelerate(self, i, g, c_sound, stirred):
        """a_i = F_i/m_i + g + disturbances for real particle i, F_i with the reactions
        handed on to it (variational coupling; zeroed here for the next force pass, which
        hands them only to real particles). Returns i's CFL rate (c + |u|)/h, its force
        rate |a|/h, and whether it is bad: NaN/Inf velocity or acceleration, or a speed
        above ``physics.max_speed``."""
        p = ti.static(self.pool.p)
        f = p[i].a
        if ti.static(self.variational):
            f += self.reaction[i]
            self.reaction[i] = ti.Vector.zero(float, self.dim)
        acc = f / p[i].m + g
        if stirred:
            acc += self.disturbances.accel(p[i].x, p[i].v)
        p[i].a = acc
        h = self.lev_h[p[i].level]
        speed = p[i].v.norm()
        an = acc.norm()
        # NaN fails both comparisons; Inf and speeds past physics.max_speed fail the first
        bad = not (speed <= self.speed_limit[None] and an < ACCEL_OVERFLOW)
        return (c_sound + speed) / h, an / h, bad

    @ti.func
    def _accelerations(self, n, c_sound, stirred):
        """``_accelerate`` every real particle and reduce the CFL and force limits and
        the NaN/Inf count. ``stirred``: some disturbance is active (else its per-particle
        loop over the slots is skipped)."""
        p = ti.static(self.pool.p)
        g = self.gravity[None]
        self._clear_reductions()
        # reduced per block of particles, then across blocks: float atomic max is a
        # compare-and-swap loop, ten times the cost of the loop body when taken per particle
        blocks = ti.static(REDUCTION_BLOCKS)
        for b in range(blocks):
            cfl, force, bad_count, first_bad = 0.0, 0.0, 0, 2147483647
            # block b's share of the pool, in 64 bits: b * n passes 2^31 from 8.4M particles
            lo = ti.cast(ti.cast(b, ti.i64) * n // blocks, ti.i32)
            hi = ti.cast(ti.cast(b + 1, ti.i64) * n // blocks, ti.i32)
            for i in range(lo, hi):
                if is_real(p[i].kind):
                    cfl_i, force_i, bad = self._accelerate(i, g, c_sound, stirred)
                    if bad:
                        bad_count += 1
                        first_bad = ti.min(first_bad, i)
                    else:
                        cfl = ti.max(cfl, cfl_i)
                        force = ti.max(force, force_i)
            ti.atomic_max(self.red_f[0], cfl)
            ti.atomic_max(self.red_f[1], force)
            ti.atomic_add(self.red_i[0], bad_count)
            ti.atomic_min(self.red_i[1], first_bad)

    def _report_bad(self, i: int, count: int):
        def vec(field):
            val = field[i]
            return np.asarray(val.to_numpy() if hasattr(val, "to_numpy") else val, float)
        x, v, a = vec(self.pool.p.x), vec(self.pool.p.v), vec(self.pool.p.a)
        limit = float(self.scene.data["physics"]["max_speed"])
        speed = np.linalg.norm(v)
        if not (np.isfinite(v).all() and np.isfinite(a).all()):
            what = "NaN/Inf velocity or acceleration"
        elif speed > limit:
            what = f"speed {speed:.4g} m/s above physics.max_speed = {limit:g} m/s"
        else:   # |a| >= ACCEL_OVERFLOW, or |a|² past the float's range (f32: |a| > 1.8e19)
            what = f"acceleration {np.linalg.norm(a):.4g} m/s^2, past what the step can take"
        raise SimulationError(
            f"step {self.steps} (t = {self.time:.6g} s): {count} particle(s) with NaN/Inf velocity "
            f"or acceleration, an acceleration of {ACCEL_OVERFLOW:g} m/s^2 or more, or a speed "
            f"above physics.max_speed; first: particle {i}, "
            f"level {int(self.pool.p.level[i])}, "
            f"kind {int(self.pool.p.kind[i])}, x = {np.round(x, 4).tolist()}: {what}")

    @ti.func
    def _advect_one(self, j, dt):
        """Virtual particle j follows its level's flow, tied by a Hooke spring (Eq. 24):
        a virtual child to its transient parent at its sampling offset (rest length half
        the level spacing per axis), a virtual parent to its children's barycentre (rest
        length zero). The springs act on virtual particles only."""
        p = ti.static(self.pool.p)
        relax = ti.min(self.spring_rate[None] * dt, 1.0)
        anchor = p[j].x
        if p[j].kind == VIRTUAL_CHILD:
            par = p[j].parent
            anchor = p[par].x + self.multires.offsets[p[j].slot] * self.lev_s[p[j].level]
        else:
            mass = 0.0
            acc = ti.Vector.zero(float, self.dim)
            for q in range(p[j].nchild):
                ch = self.pool.children[j, q]
                acc += p[ch].m * p[ch].x
                mass += p[ch].m
            if mass > 0.0:
                anchor = acc / mass
        # advected, then pulled towards the anchor by the spring, integrated implicitly
        # (a relaxation by k dt, capped at 1) so that any stiffness is stable; at
        # k dt >= 1 the virtual particle sits on its anchor, an exact function of its
        # owners' positions, as the energy balance of the coupling needs (see
        # ``_partner_pressure``)
        x = p[j].x + dt * p[j].v
        x += relax * (anchor - x)
        # not projected out of walls: a virtual particle stands for part of its owner's
        # mass at a fixed offset; projecting it would stack the children of neighbouring
        # parents onto the same wall points (measured: virtual density 1.8 rho0 on the
        # floor of demo_2d within 0.05 s). The grid is padded by two cells, so a
        # position slightly inside a wall is still binned.
        p[j].x = x

    # ================================================================== reading out
    def particles(self, virtual: bool = True) -> dict:
        """Alive particles as numpy arrays: x, v, m, rho, p, level, kind (and parent)."""
        n = self.pool.count()
        p = ti.static(self.pool.p)
        out = {"x": p.x.to_numpy()[:n], "v": p.v.to_numpy()[:n], "m": p.m.to_numpy()[:n],
               "rho": p.rho.to_numpy()[:n], "p": p.p.to_numpy()[:n],
               "level": p.level.to_numpy()[:n], "kind": p.kind.to_numpy()[:n],
               "parent": p.parent.to_numpy()[:n], "nchild": p.nchild.to_numpy()[:n],
               "lam": p.lam.to_numpy()[:n]}
        keep = out["kind"] != DEAD
        if not virtual:
            keep &= out["kind"] < VIRTUAL_CHILD
        if not keep.all():
            out = {k: v[keep] for k, v in out.items()}
        return out

    def children(self) -> np.ndarray:
        """Children slots per pool slot; only the first ``nchild`` entries of a row count."""
        n = self.pool.count()
        return self.pool.children.to_numpy()[:n]

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
        row = {"frame": self.frame, "time": self.time, "dt": self.chosen_dt if self.steps else 0.0,
               "n_real": int(real.sum()), "n_virtual": int((~real).sum()),
               "total_mass": math.fsum(m.tolist())}
        for k, ax in enumerate("xyz"[: self.dim]):
            row[f"momentum_{ax}"] = float(mom[k])
        row["kinetic_energy"] = float(0.5 * (m * (v * v).sum(axis=1)).sum())
        rho = parts["rho"][real]
        row["max_density_ratio"] = float(rho.max() / self.rest_density) if len(rho) else 0.0
        lv = parts["level"]
        for l in range(self.levels):
            row[f"n_level_{l}"] = int(((lv == l) & real).sum())
        for l in range(self.levels):
            row[f"n_virtual_level_{l}"] = int(((lv == l) & ~real).sum())
        row["n_transient"] = int((real & (parts["kind"] > REGULAR)).sum())
        self._collect_events()
        row["splits"] = self._events["splits"]
        row["merges"] = self._events["merges"]
        refused = int(self.pool.refused[None])    # a running total in the pool
        row["refused"] = refused - self._refused_reported
        self._refused_reported = refused
        for k in self._events:
            self._events[k] = 0
        return row

    def snapshot(self, stats: bool = True) -> Snapshot:
        parts = self.particles()
        s = self.scene.data
        return Snapshot(
            dim=self.dim, levels=self.levels, time=self.time, frame=self.frame,
            x=parts["x"], v=parts["v"],       # the simulation's precision: dumps keep f64
            m=parts["m"], rho=parts["rho"], level=parts["level"], kind=parts["kind"],
            radius=np.array([0.5 * self.s0 * 2**l for l in range(self.levels)]),
            domain_min=np.asarray(s["domain"]["min"], float), domain_max=np.asarray(s["domain"]["max"], float),
            obstacles=[dict(o) for o in s["obstacles"]],
            stats=self.stats(parts) if stats else {})

    def save_state(self) -> dict:
        """The simulation's state in memory (numpy copies): every particle attribute, the
        links, the clocks and the emitters' progress. :meth:`restore_state` puts it back
        into a Simulation of the same scene, here or in another Taichi program; the scene's
        parameters, live-tuned ones included, and the mouse's disturbance are not part of
        it. ``bench`` uses it to time an adaptive run and its uniform twin turn about
        from the same warm state."""
        p = self.pool.p
        return {"attributes": {a.name: getattr(p, a.name).to_numpy() for a in ATTRIBUTES},
                "children": self.pool.children.to_numpy(), "n": self.pool.count(),
                "refused": int(self.pool.refused[None]),
                "clock": (self.time, self.frame, self.steps, self.dt, self.chosen_dt),
                "emitters": list(self._emit_acc), "capacity": self.capacity, "dim": self.dim}

    def restore_state(self, state: dict) -> None:
        """Put back a :meth:`save_state` of a Simulation of the same scene."""
        if (state["dim"], state["capacity"]) != (self.dim, self.capacity):
            raise ValueError(f"restore_state: a {state['dim']}D state of capacity {state['capacity']} "
                             f"does not fit this {self.dim}D pool of capacity {self.capacity}")
        for name, values in state["attributes"].items():
            getattr(self.pool.p, name).from_numpy(values)
        self.pool.children.from_numpy(state["children"])
        self.pool.n[None] = state["n"]
        self.pool.refused[None] = state["refused"]
        self._refused_reported = state["refused"]
        self.time, self.frame, self.steps, self.dt, self.chosen_dt = state["clock"]
        self._emit_acc = list(state["emitters"])
        if self.reaction is not None:
            self.reaction.fill(0.0)
        self._stirrers(self.time)

    # ================================================================== interaction
    def set_disturbance(self, d: Disturbance | None) -> None:
        self.disturbances.set(MOUSE_SLOT, d)

    LIVE_KEYS = ("fluid.viscosity", "fluid.stiffness", "physics.gravity", "adaptivity.spring_rate")

    def set_param(self, key: str, value) -> None:
        """Change a parameter while running (validated like the scene file)."""
        if key == "adaptivity.enabled":
            raise ValueError("adaptivity.enabled: changes the particle levels; rebuild the "
                             "Simulation with scene.with_overrides({...}) instead")
        if key not in self.LIVE_KEYS:
            raise ValueError(f"{key}: not live-tunable (expected one of {', '.join(self.LIVE_KEYS)})")
        self.scene = self.scene.with_overrides({key: value})
        v = self.scene.get(key)
        if key == "fluid.viscosity":
            self.mu[None] = float(v)
        elif key == "fluid.stiffness":
            self.k[None] = float(v)
            self._c_sound = sound_speed(float(self.k[None]), self.eos)
            self.av_coef[None] = self.av_alpha * self._c_sound
        elif key == "physics.gravity":
            self.gravity[None] = list(map(float, v))
        else:
            self.spring_rate[None] = float(v)

"""Position based fluids (Macklin & Müller, "Position Based Fluids", SIGGRAPH 2013; the
mass-weighted constraint gradients of Macklin et al. 2014): the density of every real
particle is a constraint C_i = ρ_i/ρ0 − 1 <= 0, projected on the positions by a few
Jacobi iterations a step, with a time step tied to the frame (``pbf.substeps`` a frame),
not to a sound speed or a CFL bound.

The step, in mrsph's order (``simulation.py`` schedules these passes; docs/METHOD.md §17):
there is no force pass. The kick adds gravity and disturbances, ``pbf_clamp`` keeps each
particle within ``pbf.max_displacement`` of its spacing a step (counted), the drift
predicts x* = x + dt u, and the pool is sorted and its density measured at x*. Then

0. ``pbf_begin``: the accumulated multiplier q_i (a displacement per unit of Σ m ∇W,
   q = dt² p / ρ²) starts at ``pbf.warm_start`` of the last step's pressure and its
   correction is applied, as DFSPH's warm start, so that the iterations correct what it
   leaves; the same pass smooths the velocities: XSPH (u_i += c Σ_j 2 m_j/(ρ_i + ρ_j)
   (u_j − u_i) W_ij, symmetric in the pair so that it keeps momentum) and, with
   ``pbf.viscosity = "scene"``, the scene's viscosity over the step;

and ``pbf_iterate`` runs up to ``pbf.iterations`` times

1. the multipliers: ρ_i and D_i = |Σ_j m_j ∇W_ij|² + m_i Σ_j m_j |∇W_ij|² over i's
   neighbourhood (virtual particles and mirror images included, ``gradients.py``), and
   the Jacobi step on q_i, kept at q >= 0 (the constraint is one-sided, so a free
   surface is never pulled in):  q_i ← max(q_i + ω (ρ_i − ρ0 − δρ_i) / (D_i + ε D_0), 0),
   δq_i its change (δρ: a split child's sampling offset, multires/fade.py);
2. the corrections: Δx_i = −Σ_j m_j (δq_i + δq'_j + s_corr,ij) ∇W_ij, δq'_j the
   multiplier j shows (the coupling's: 0 for a virtual particle, whose reaction
   m_i Σ m_j δq_i ∇W_ij is handed back to the real particles it stands for,
   ``coupling.hand_on``, so that the corrections over the real particles sum to zero);
   s_corr is the tensile correction (``tensile.py``);
3. x_i += Δx_i and u_i += Δx_i / dt (the velocity from the position change), the walls
   and obstacles (collide), the virtual particles back on their owners;

and ``pbf_end`` sets p_i = q_i ρ_i² / dt², the pressure whose force would move x by q in a
step: the next step's warm start. So part of the pressure that carries the water's weight
is carried over and the iterations correct the rest: without it, the weight is carried by
each step's iterations alone and a column H deep compresses by about
g H D_0 dt² / (ρ0 iterations), 30 % at the bottom of demo_2d's 7 mm level. Dumps add the
tensile correction's share to p, and read the last iteration's ρ.
"""

import numpy as np
import taichi as ti

from mrsph.sph.forces import viscous_dt
from mrsph.sph.kernels import poly6
from mrsph.sph.neighbours import ImageNeighbours
from mrsph.sph.particles import VIRTUAL_CHILD, is_real, is_virtual
from mrsph.sph.step import Pass

from ..base import PressureSolver, TimeStepBound
from ..eos import sound_speed
from ..gradients import PairGradients
from .counts import StepCounts
from .tensile import TensileCorrection

# knobs[]: scene values the kernels read from a field, so that changing one does not
# compile the solver's kernels again
WARM, OMEGA, EPS, XSPH, AP, CLAMP, VISC = range(7)


def rest_denominator(s: float, h: float, m: float, spiky: float, dim: int) -> float:
    """D of a particle in a rest lattice (spacing s, support h, masses m):
    m² Σ_j |∇W_ij|², the first term of D vanishing by symmetry; ``spiky`` the level's
    calibrated constant (∇W = −3 c (h − r)² r̂)."""
    reach = int(np.ceil(h / s))
    axes = np.arange(-reach, reach + 1) * s
    pts = np.stack(np.meshgrid(*([axes] * dim), indexing="ij"), axis=-1).reshape(-1, dim)
    r = np.linalg.norm(pts, axis=1)
    r = r[(r > 0) & (r < h)]
    return float(m * m * np.sum((3.0 * spiky * (h - r) ** 2) ** 2))


@ti.data_oriented
class PBF(PressureSolver):
    name = "pbf"
    incompressible = True
    predicts = True  # the step predicts, then sorts, measures and projects (Macklin & Müller's order)
    uses_forces = False  # its pressure and viscosity act in the projection, not in a force pass

    def __init__(self, core, params, coupling, fade, state, warn):
        cfg = params.pbf
        self.cfg, self.warn = cfg, warn
        self.dim, self.adaptive, self.levels = core.dim, core.adaptive, core.levels
        self.pool, self.lev, self.nb, self.boundary = core.pool, core.lev, core.nb, core.boundary
        self.coupling, self.fade, self.state = coupling, fade, state
        self.rest_density = core.lev.rest_density
        self.frame_dt = cfg.dt if cfg.dt > 0.0 else 1.0 / (params.run.fps * cfg.substeps)
        self.iterations = cfg.iterations
        self.scene_viscosity = cfg.viscosity == "scene"
        # the smoothing, and the scene's viscosity where it acts (in the projection), live
        self.live_keys = ("pbf.xsph", "fluid.viscosity") if self.scene_viscosity else ("pbf.xsph",)
        fl = params.fluid
        self._damping_c = sound_speed(fl.stiffness, fl.eos)
        self._viscous = lambda mu: viscous_dt(params.physics.viscous_factor, core.lev.h0, self.rest_density, mu)
        self.mu = fl.viscosity if self.scene_viscosity else 0.0
        self.pairs = PairGradients(core, coupling)
        cap = core.pool.capacity
        self.q = ti.field(float, shape=cap)  # the step's accumulated multiplier
        self.rho = ti.field(float, shape=cap)  # ρ at the last iteration's positions
        self.dq = ti.field(float, shape=cap)  # this iteration's change of it
        self.dx = ti.Vector.field(self.dim, float, shape=cap)  # this iteration's correction
        self.dv = ti.Vector.field(self.dim, float, shape=cap)  # XSPH's and the viscosity's velocity change
        L = core.levels
        self.den_rest = ti.field(float, shape=L)  # D of a rest lattice, per level
        for l in range(L):
            h, s = self.lev.support(l), self.lev.spacing(l)
            self.den_rest[l] = rest_denominator(s, h, self.lev.m[l], self.lev.spiky[l], self.dim)
        self.knobs = ti.field(float, shape=7)
        for k, v in ((WARM, cfg.warm_start), (OMEGA, cfg.over_relaxation), (EPS, cfg.relaxation),
                     (XSPH, cfg.xsph), (AP, cfg.artificial_pressure),
                     (CLAMP, cfg.max_displacement), (VISC, self.mu)):  # fmt: skip
            self.knobs[k] = v
        self.tensile = TensileCorrection(core, cfg, self.knobs, AP, self.den_rest)
        self.err = ti.field(ti.f64, shape=())  # Σ of this iteration's errors
        self.iteration = ti.field(ti.i32, shape=())  # of the step's, the one running
        self.n_real = ti.field(ti.i32, shape=())
        self.measured = ti.field(ti.i32, shape=())  # the slots whose ρ (``rho``) the last step measured
        self.counts = StepCounts(warn)
        self.running = ti.field(ti.i32, shape=())  # the step's solve goes on
        self.avg = ti.field(ti.f64, shape=())  # its last measured average error
        self.peak = ti.field(float, shape=())  # and largest
        # each launch corrects once: a step makes at least one
        self.min_iterations = cfg.iterations if cfg.min_iterations < 0 else max(1, cfg.min_iterations)
        self.tolerance = ti.field(ti.f64, shape=())
        self.tolerance[None] = cfg.tolerance
        self.max_error = ti.field(float, shape=())  # the largest particle error allowed; inf: none
        self.max_error[None] = cfg.max_density_error if cfg.max_density_error > 0.0 else float("inf")
        self._lambda_images = ImageNeighbours(self.nb, self._lambda_pair)
        self._correct_images = ImageNeighbours(self.nb, self._correct_image)

    # ------------------------------------------------------------------ interface
    @property
    def step_dt(self) -> float:
        """The frame's share, or the viscous bound of the viscosity now set where it is shorter."""
        return min(self.frame_dt, self._viscous(self.mu))

    def bound(self) -> TimeStepBound:
        """dt = the frame's share (``pbf.substeps``) or ``pbf.dt``: no CFL and no force bound."""
        key = "pbf.dt" if self.cfg.dt > 0.0 else "pbf.substeps"
        says = f"the frame ({key}: dt = {self.step_dt:.3g} s)"
        if self.step_dt < self.frame_dt:
            says = f"the viscous bound (fluid.viscosity = {self.mu:g} Pa s: dt = {self.step_dt:.3g} s)"
        return TimeStepBound(key, 0.0, 0.0, "s", self.step_dt, says, even_last_steps=True, force_limited=False)

    def damping_speed(self) -> float:
        """The sound speed ``fluid.stiffness`` gives the scene: the mouse's cap (no force
        pass, so no artificial viscosity)."""
        return self._damping_c

    def force_viscosity(self, fluid) -> float:
        """No force pass: the viscosity (``pbf.viscosity``) acts in the projection."""
        return 0.0

    def set_param(self, key: str, value) -> None:
        """``pbf.xsph``, the smoothing's c; ``fluid.viscosity`` with ``pbf.viscosity =
        "scene"``: μ in the projection, and the step its explicit bound allows."""
        if key not in self.live_keys:
            super().set_param(key, value)
        elif key == "pbf.xsph":
            self.knobs[XSPH] = float(value)
        else:
            self.mu = float(value)
            self.knobs[VISC] = self.mu

    def reset_counters(self) -> None:
        self.counts.reset()

    def take_stats(self) -> dict:
        return self.counts.take(self.iterations, self.cfg.tolerance, float(self.max_error[None]))

    def after_density(self) -> list:
        """The projection of the predicted positions (this solver predicts first, so the
        density pass measured them): its start, ``pbf.min_iterations`` launches of one
        Jacobi iteration each (a kernel compiled once, whatever the count) and more while
        the solve runs, up to ``pbf.iterations``, its end."""
        iterate = Pass(
            "pbf_iterate", "pressure", self.iterate, self.iterate_func, repeat=self.min_iterations, alone=True, loops=2
        )
        if self.min_iterations < self.iterations:
            # the rest launched while the solve runs: a host read a launch, not an empty launch
            iterate = iterate._replace(again=self.solving, most=self.iterations)
        return [
            Pass("pbf_begin", "pressure", self.begin, self.begin_func, loops=1),
            iterate,
            Pass("pbf_end", "pressure", self.end, self.end_func),
        ]

    def reported_pressure(self, p: np.ndarray) -> np.ndarray:
        """p plus the last step's tensile corrections as a pressure, slot by slot."""
        return self.tensile.reported(p, self.rho.to_numpy(), float(self.state.dt[None]))

    def reported_density(self, rho: np.ndarray, kind: np.ndarray) -> np.ndarray:
        """The real particles' ρ as the last iteration measured it, the density the step's
        pressure and its error read (its correction after it is not measured): the pool's
        is the density pass's, at the predicted positions, before the projection."""
        k = min(int(self.measured[None]), len(rho))
        out = rho.copy()
        real = (kind[:k] >= 0) & (kind[:k] < VIRTUAL_CHILD)
        out[:k][real] = self.rho.to_numpy()[:k][real]
        return out

    def forget_step(self) -> None:
        self.tensile.forget()
        self.measured[None] = 0

    def solving(self) -> bool:
        """Whether the step's solve goes on (its stop is decided on the device)."""
        return self.running[None] != 0

    def solve_loops(self, stats: dict) -> float:
        """The neighbour loops of the iterations past pbf.min_iterations (stats: a stats row)."""
        return 2.0 * max(0.0, (stats.get("density_iterations") or 0.0) - self.min_iterations)

    def after_kick(self) -> list:
        return [Pass("pbf_clamp", "integrate", self.clamp, self.clamp_func)]

    # ------------------------------------------------------------------ device: the iterations
    @ti.func
    def _lambda_pair(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """j's part of i's factor sums and of its density (acc: Σ m ∇W, the reaction term,
        Σ m (h² − r²)³); for an obstacle image only a candidate whose image is in the solid."""
        ok, g = self.pairs.grad(i, j, xq, L, p0, nrm, check, ctx)
        p = ti.static(self.pool.p)
        if ok:
            self.pairs.add_factor(i, j, p[j].m * g, g, acc)
        h = ctx[0]
        r2 = (xq - p[j].x).norm_sqr()
        counts = r2 < h * h
        if ti.static(check):
            if counts:
                counts = self.nb.image_in_solid(p[j].x, p0, nrm)
        if counts:
            d = h * h - r2
            acc[self.dim + 1] += self.coupling.sum_mass(j) * (d * d * d)

    @ti.func
    def _visit(self, i, pair: ti.template(), images: ti.template(), ctx: ti.template(), acc: ti.template()):
        """``pair`` over i's own level (its list, itself first, or the grid block) and
        ``images`` over its wall and obstacle images."""
        p = ti.static(self.pool.p)
        xi = p[i].x
        eye = ti.Matrix.identity(float, self.dim)
        if self.nb.is_listed(i):
            self.nb.listed_candidates(i, xi, eye, xi, xi, False, True, pair, ctx, acc)
        else:
            self.nb.grid_candidates(i, xi, eye, xi, xi, False, p[i].level, pair, ctx, acc)
        self.nb.images(i, ctx[0], images, ctx, acc)

    @ti.func
    def _multipliers(self, n):
        """Step 1 for every real particle: ρ_i, D_i, the Jacobi step's δq_i (added to q_i
        with the correction); the average error into ``err``, the largest into ``peak``."""
        p = ti.static(self.pool.p)
        rho0 = ti.static(self.rest_density)
        if n > 0:  # a launch after the solve stopped keeps the last measure
            self.err[None] = 0.0
            self.peak[None] = 0.0
            self.n_real[None] = 0
        for i in range(n):
            if is_real(p[i].kind):
                l, h, ctx = self.pairs.ctx(i)
                acc = ti.Vector.zero(float, self.dim + 2)
                self._visit(i, self._lambda_pair, self._lambda_images.visit, ctx, acc)
                rho = acc[self.dim + 1] * self.lev.poly6[l] * self.coupling.sum_scale()
                den = self.pairs.denominator(acc)
                q = self.q[i]
                e = rho - rho0 - self.fade.excess(i)
                step = 0.0
                if den > 1e-12 * rho * rho:  # an isolated particle has nothing to push
                    step = e / (den + self.knobs[EPS] * self.den_rest[l])
                self.dq[i] = ti.max(q + self.knobs[OMEGA] * step, 0.0) - q  # applied with the correction
                self.rho[i] = rho
                c = ti.max(e, 0.0) / rho0
                self.err[None] += ti.cast(c, ti.f64)
                self.n_real[None] += 1
                if c > self.peak[None]:
                    ti.atomic_max(self.peak[None], c)

    @ti.func
    def _push(self, i, j, g, corr):
        """m_j (δq_i + δq'_j + s_corr) ∇W_ij."""
        p = ti.static(self.pool.p)
        shown = self.coupling.partner_pressure(p[j].kind, self.dq[j])
        return p[j].m * (self.dq[i] + shown + corr) * g

    @ti.func
    def _correct_pair(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """An own-level neighbour: its part of i's correction (acc[:d]), the reaction of a
        virtual j handed to its owners, and the velocity smoothing's (acc[d:2d])."""
        ok, g = self.pairs.grad(i, j, xq, L, p0, nrm, check, ctx)
        p = ti.static(self.pool.p)
        if ok:
            corr = self.tensile.term(i, j, xq, ctx[0])
            f = self._push(i, j, g, corr)
            for k in ti.static(range(self.dim)):
                acc[k] += f[k]
            self.tensile.tally(j, g, corr, acc, 2 * self.dim)
            self.coupling.hand_reaction(j, -p[i].m * f)
        r2 = (p[i].x - p[j].x).norm_sqr()
        h = ctx[0]
        if r2 < h * h and j != i and is_real(p[j].kind):
            # XSPH with 2 m_j / (ρ_i + ρ_j), symmetric in the pair so that the smoothing
            # keeps momentum, and the viscosity of Eq. 19 over the step, μ dt m_j (h − r)
            # ∇²W / (ρ_i ρ_j) (``pbf.viscosity = "scene"``; 0 otherwise); between real
            # particles only, each pair twice, so that neither hands anything on
            l = p[i].level
            m_j = self.coupling.sum_mass(j) * self.coupling.sum_scale()
            xsph = self.knobs[XSPH] * 2.0 * m_j * self.lev.poly6[l] / (p[i].rho + p[j].rho) * poly6(r2, h * h, 1.0)
            dt = ti.cast(self.state.dt[None], float)
            visc = self.knobs[VISC] * dt * m_j * self.lev.visc[l] * (h - ti.sqrt(r2)) / (p[i].rho * p[j].rho)
            dv = (p[j].v - p[i].v) * (xsph + visc)
            for k in ti.static(range(self.dim)):
                acc[self.dim + k] += dv[k]

    @ti.func
    def _correct_image(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """A mirror image: its part of the correction; the walls are external, nothing is
        handed on (and XSPH leaves the walls free-slip)."""
        ok, g = self.pairs.grad(i, j, xq, L, p0, nrm, check, ctx)
        if ok:
            corr = self.tensile.term(i, j, xq, ctx[0])
            f = self._push(i, j, g, corr)
            for k in ti.static(range(self.dim)):
                acc[k] += f[k]
            self.tensile.tally(j, g, corr, acc, 2 * self.dim)

    @ti.func
    def _corrections(self, n):
        """Step 2: Δx_i for every real particle (and the smoothing's Δu, applied in the
        last iteration)."""
        p = ti.static(self.pool.p)
        for i in range(n):
            if is_real(p[i].kind):
                l, h, ctx = self.pairs.ctx(i)
                acc = ti.Vector.zero(float, 2 * self.dim + 2)
                self._visit(i, self._correct_pair, self._correct_images.visit, ctx, acc)
                self.tensile.close(i, acc, 2 * self.dim)
                self.dx[i] = -ti.Vector([acc[k] for k in ti.static(range(self.dim))])
                self.dv[i] = ti.Vector([acc[self.dim + k] for k in ti.static(range(self.dim))])

    @ti.func
    def _apply(self, n, smooth: ti.template()):
        """Step 3: the corrections (with the reactions handed to i) into x and u, q_i += δq_i,
        the walls; then the virtual particles back on their owners. ``smooth``: add the
        velocity smoothing's Δu (the warm start's pass, which computes it)."""
        p = ti.static(self.pool.p)
        dt = ti.cast(self.state.dt[None], float)
        for i in range(n):
            if is_real(p[i].kind):
                d = self.dx[i] + self.coupling.take_reaction(i, ti.Vector.zero(float, self.dim)) / p[i].m
                x, v = p[i].x + d, p[i].v + d / dt
                if ti.static(smooth):
                    v += self.dv[i]
                else:
                    self.q[i] += self.dq[i]
                x, v = self.boundary.collide(x, v)
                p[i].x = x
                p[i].v = v
        if ti.static(self.adaptive):
            for j in range(n):
                if is_virtual(p[j].kind):
                    self.coupling.place(j)

    @ti.kernel
    def begin(self, n: ti.i32):
        self.begin_func(n)

    @ti.func
    def begin_func(self, n):
        """The warm start, q from ``pbf.warm_start`` of the last step's pressure, and its
        correction applied before the first iteration measures (as DFSPH's warm start),
        so that the iterations correct what it leaves; the same pass smooths the
        velocities (XSPH, the viscosity)."""
        p = ti.static(self.pool.p)
        dt = ti.cast(self.state.dt[None], float)
        self.iteration[None] = 0
        self.running[None] = 1
        for i in range(n):
            q = 0.0
            if is_real(p[i].kind):
                q = self.knobs[WARM] * p[i].p * dt * dt / (p[i].rho * p[i].rho)
            self.q[i] = q
            self.dq[i] = q
            self.tensile.start(i)
        self._corrections(n)
        self._apply(n, True)

    @ti.kernel
    def iterate(self, n: ti.i32):
        self.iterate_func(n)

    @ti.func
    def iterate_func(self, n):
        """One Jacobi iteration, steps 1-3, while the step's solve runs: it stops after a
        correction, once at least ``pbf.min_iterations`` were made and the error measured
        before it is within both ``pbf.tolerance`` (the average) and
        ``pbf.max_density_error`` (the largest), or after ``pbf.iterations``; decided here,
        on the device (the loops' bounds 0 once it stops). The error is the one measured
        for the correction, so that a step that stops pays no measure of its own."""
        go = self.running[None] != 0
        self._multipliers(ti.select(go, n, 0))
        m = ti.select(go, n, 0)
        self._corrections(m)
        self._apply(m, False)
        if go:
            avg = self.err[None] / ti.max(self.n_real[None], 1)
            self.avg[None] = avg
            self.iteration[None] += 1
            within = avg <= self.tolerance[None] and self.peak[None] <= self.max_error[None]
            if within and self.iteration[None] >= self.min_iterations:
                self.running[None] = 0

    @ti.kernel
    def end(self, n: ti.i32):
        self.end_func(n)

    @ti.func
    def end_func(self, n):
        """The pressure whose force would move x by q in a step (the next step's warm
        start) and the step's last measured error into the stats."""
        p = ti.static(self.pool.p)
        dt = ti.cast(self.state.dt[None], float)
        for i in range(n):
            if is_real(p[i].kind):
                rho = self.rho[i]
                p[i].p = self.q[i] * rho * rho / (dt * dt)
        if self.state.go[None]:  # a refused step is not one of the stats' (fused, n = 0 here)
            self.measured[None] = n
            avg, peak = self.avg[None], self.peak[None]
            short = avg > self.tolerance[None] or peak > self.max_error[None]
            self.counts.step(avg, peak, self.iteration[None], short)

    @ti.kernel
    def clamp(self, n: ti.i32):
        self.clamp_func(n)

    @ti.func
    def clamp_func(self, n):
        """|u| <= max_displacement s / dt for every real particle, on the kicked velocity
        (the drift's), those it slows counted."""
        p = ti.static(self.pool.p)
        dt = ti.cast(self.state.dt[None], float)
        for i in range(n):
            if self.state.go[None] and is_real(p[i].kind):
                vmax = self.knobs[CLAMP] * self.lev.s[p[i].level] / dt
                speed = p[i].v.norm()
                if speed > vmax:
                    p[i].v *= vmax / speed
                    self.counts.clamped()

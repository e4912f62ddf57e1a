"""Divergence-free SPH (Bender & Koschier, "Divergence-Free SPH for Incompressible and
Viscous Fluids", SCA 2015 / TVCG 2017): an implicit pressure solver whose time step is set
by the flow speed, not by a sound speed.

Its passes in a step (``simulation.py`` schedules them):

1. ``after_density``, ``dfsph_factors`` and ``divergence_solve``: the factor of each real particle,
   α_i = ρ_i / (|Σ_j m_j ∇W_ij|² + m_i Σ_j m_j |∇W_ij|²) (the second sum is the reaction
   of i's pressure on its neighbours; with equal masses it is the paper's Σ_j |m_j ∇W_ij|²,
   see ``gradients.py``), then the divergence solve (``dfsph.divergence_solve``, with the
   last step's dt; Jacobi sweeps, ``jacobi.py``) until the density's rate of change,
   Dρ_i/Dt = Σ_j m_j (u_i − u_j)·∇W_ij (compression only), averaged over the real
   particles, times the step, is within ``dfsph.divergence_tolerance`` of ρ0;
2. non-pressure accelerations (``forces.py`` with a zero pressure term, the integrator's
   gravity and disturbances), the time step: dt = λ s_l / |u| (``dfsph.cfl``, s_l the
   particle's level spacing), dt <= λ_p s_l / sqrt(p_i/ρ_i) (``dfsph.pressure_cfl``, the
   pressure's hold on the lattice, ``step_rate``), dt_max and the force and viscous
   bounds, and the kick u* = u + dt a;
3. ``after_kick``, ``density_solve``: the constant-density solve, a pressure κ = p/ρ with
   u = u* − dt Σ_j m_j (κ_i/ρ_i + κ'_j/ρ_j) ∇W_ij such that the predicted density
   ρ*_i = ρ_i + dt Σ_j m_j (u_i − u_j')·∇W_ij is ρ0 where the fluid is compressed, to the
   stopping rule (``tolerance.py``): by conjugate gradients on the whole pressure from the
   last one (``krylov.py``, the default) or by the paper's Jacobi sweeps (``jacobi.py``);
   a solve that stops at its maximum is run again on a step half as long;
4. drift, collide and the virtual particles' advection (integrator).

Both solves keep m_j inside every sum (particles of one level may differ in mass after a
partial merge) and visit the walls and obstacles as mirror images and the other levels
through their virtual particles (``operator.py``). The pressure a particle shows (``p``, in
dumps) is ρ_i κ_i of the density solve: the p of u −= dt Σ m_j (p_i/ρ_i² + p_j/ρ_j²) ∇W.
A solve that stops at its maximum iterations is counted (``stats``) and warned about once.
"""

import taichi as ti

from mrsph.sph.neighbours import ImageNeighbours
from mrsph.sph.particles import is_real, is_virtual
from mrsph.sph.step import Pass

from ..base import PressureSolver, TimeStepBound
from ..eos import sound_speed
from ..gradients import PairGradients
from .counts import DENSITY, DIVERGENCE, SolveCounts
from .jacobi import Sweeps
from .krylov import Krylov
from .operator import Operator
from .pairs import StoredPairs
from .tolerance import Stopping


@ti.data_oriented
class DFSPH(PressureSolver):
    name = "dfsph"
    incompressible = True

    def __init__(self, core, params, coupling, fade, state, warn):
        """params: the scene's (its [dfsph], [fluid] for the artificial viscosity's sound
        speed, [physics] for dt_max); coupling: the level coupling's hooks; fade: a split
        child's target is ρ0 + δρ (multires/fade.py); state: the step's dt (``sph.step``);
        warn: how a warning reaches the user (a solve at its maximum iterations)."""
        fluid, physics, params = params.fluid, params.physics, params.dfsph
        self.dim, self.adaptive = core.dim, core.adaptive
        self.pool, self.lev, self.nb, self.coupling = core.pool, core.lev, core.nb, coupling
        self.fade, self.state, self.params = fade, state, params
        self.dt_max = physics.dt_max
        self.rest_density = core.lev.rest_density
        self.stop = Stopping(params, self.rest_density)
        # the pressure bound dt <= pressure_cfl s_l / sqrt(p_i / rho_i) (``step_rate``), in a
        # field so that a scene's value does not compile the step again
        self.has_step_rate = params.pressure_cfl > 0.0
        self.inv_pressure_cfl = ti.field(float, shape=())
        self.inv_pressure_cfl[None] = 1.0 / params.pressure_cfl if self.has_step_rate else 0.0
        self.divergence = params.divergence_solve
        # the time over which an inherited compression is corrected (``_inherited``)
        self.correction_time = ti.field(float, shape=())
        self.correction_time[None] = params.correction_time
        self._damping_c = sound_speed(fluid.stiffness, fluid.eos)
        cap = core.pool.capacity
        self.alpha = ti.field(float, shape=cap)
        self.pairs = PairGradients(core, coupling)  # ∇W of neighbours and images, the factor sums
        self.kept = StoredPairs(core.pool, self.dim, core.nb.max_neighbours, self.pairs.grad, self.pairs.add_factor)
        self.op = Operator(core, coupling, self.pairs, self.kept)  # the rate and the push
        self.ksum = ti.field(float, shape=cap)  # the density solve's κ_i, p_i / ρ_i
        self.err = ti.field(ti.f64, shape=())  # Σ of the real particles' errors
        self.n_real = ti.field(ti.i32, shape=())
        self.speed_sum = ti.field(ti.f64, shape=())  # Σ |u_i| / s_i over the real particles
        # the factor pass's visits of each image's candidates, for Neighbours.images
        self._factor_images = ImageNeighbours(self.nb, self.kept.image_pair)
        self.counts = SolveCounts(self.stop.tolerance, self.stop.max_iterations, warn, params.max_density_error)
        # a step shortened when its density solve stops at its maximum (``_density_solve``):
        # the kicked velocities it starts again from
        self.shorten_steps = params.shorten_steps
        self.kicked = ti.Vector.field(self.dim, float, shape=cap if params.shorten_steps else 1)
        self.sweeps = Sweeps(self)  # the divergence solve
        self.krylov = Krylov(self, cap)  # the density solve

    # ------------------------------------------------------------------ interface
    def bound(self) -> TimeStepBound:
        """dt <= λ s / |u| (``dfsph.cfl``): no sound speed, the flow speed alone."""
        return TimeStepBound(
            "dfsph.cfl",
            self.params.cfl,
            0.0,
            "s",
            self.dt_max,
            "the flow speed",
            even_last_steps=True,
        )

    def damping_speed(self) -> float:
        """The artificial viscosity's c: the sound speed ``fluid.stiffness`` gives a weakly
        compressible run of the scene (not a CFL bound here), so that switching solvers keeps
        the scene's dissipation. At dfsph's step it overshoots unless capped
        (``fluid.artificial_viscosity_cap``): the quick deep tank moves at 0.020 sqrt(gH) with
        it, 0.0057 without, 0.0031 capped (docs/validation.md)."""
        return self._damping_c

    @ti.func
    def cfl_rate(self, c_sound, speed, l):
        """|u| / s_l: dt = λ s_l / |u|."""
        return speed / self.lev.s[l]

    @ti.func
    def step_rate(self, i, l):
        """sqrt(p_i / ρ_i) / (λ_p s_l), p_i the last step's pressure: dt <= λ_p s_l /
        sqrt(p_i / ρ_i) (``dfsph.pressure_cfl``). The pressure pushes a particle off its
        place in the lattice back with a stiffness of order p/s², explicitly (the solve
        is linear in the velocities and blind to that motion, which changes no density at
        first order), so a step past about 0.45 s / sqrt(p/ρ) lets the lattice ring: the
        80-deep tank at rest moved at 0.051 sqrt(gH) at 2 ms, 0.002 at 1 ms
        (docs/validation.md)."""
        p = ti.static(self.pool.p)
        return ti.sqrt(ti.max(p[i].p, 0.0) / p[i].rho) * self.inv_pressure_cfl[None] / self.lev.s[l]

    def step_rate_says(self, rate: float) -> str:
        return (
            f"dfsph's pressure bound sets it (dfsph.pressure_cfl: sqrt(p/rho)/(pressure_cfl s) = {rate:.3g} 1/s, "
            "a pressure rising without bound)"
        )

    @ti.func
    def note_step(self, dt):
        """The spacings the real particles move on average this step, mean |u_i| / s_i
        (summed by the factor pass) times dt (``RestTolerance``)."""
        self.stop.rest.note_step(self.speed_sum[None] / ti.max(self.n_real[None], 1) * dt)

    # ------------------------------------------------------------------ host
    def reset_counters(self) -> None:
        self.counts.reset()

    def take_stats(self) -> dict:
        """Mean iterations per step of each solve, the last density error, and the solves
        that stopped at their maximum, since the last call (``SolveCounts``)."""
        return self.counts.take()

    def after_density(self) -> list:
        """The factors α, then the divergence solve (with the last step's dt)."""
        passes = [Pass("dfsph_factors", "pressure", self._factors, loops=1)]
        if self.divergence:
            passes.append(Pass("divergence_solve", "divergence", self._divergence_solve))
        return passes

    def after_kick(self) -> list:
        # decides: a shortened step's dt is the one the host advances by
        return [Pass("density_solve", "pressure", self._density_solve, decides=True)]

    def solve_loops(self, stats: dict) -> float:
        """Neighbour loops a step: the Krylov solve's (``Krylov.loops``), two a divergence
        sweep (the rate, the push)."""
        return self.krylov.loops(stats["density_iterations"]) + 2.0 * stats["divergence_iterations"]

    def _divergence_solve(self, n: int) -> None:
        it, err, hit = self.sweeps.solve(n)
        self.counts.add(DIVERGENCE, it, err, hit, t=float(self.state.t[None]) if hit else None)

    def _density_solve(self, n: int):
        """The constant-density solve on the kicked velocities, then p = ρ Σ κ. A solve
        that stops at its maximum short of its tolerance is run again on a step half as
        long, from the kicked velocities of that step (u + dt' a), up to
        ``dfsph.shorten_steps`` times and not below the step's dt_min: the predicted
        compression dt' Σ m (u_i − u_j)·∇W shrinks with the step, and with it the error
        the iterations must remove. Returns the shortened dt (None: the step's own)."""
        if self.shorten_steps:
            self._keep_kicked(n)
        shortened = 0
        while True:
            it, err, hit = self.krylov.solve(n, self.stop.args(DENSITY))
            if not (hit and shortened < self.shorten_steps and self._shorten(n)):
                break
            shortened += 1
            self.counts.iterations[DENSITY] += it  # the work of the solve dropped
        # read back only for the warning: a read per step costs a device sync
        peak = float(self.stop.peak[None]) / self.rest_density if hit else None
        self.counts.add(DENSITY, it, err, hit, peak, float(self.state.t[None]) if hit else None, shortened)
        self._pressures(n)
        return float(self.state.dt[None]) if shortened else None

    # ------------------------------------------------------------------ device
    @ti.kernel
    def _factors(self, n: ti.i32):
        p = ti.static(self.pool.p)
        self.n_real[None] = 0
        self.speed_sum[None] = 0.0
        for i in range(n):
            if is_real(p[i].kind):
                l, h, ctx = self.pairs.ctx(i)
                acc = ti.Vector.zero(float, self.dim + 2)
                listed = self.nb.is_listed(i)
                xi = p[i].x
                eye = ti.Matrix.identity(float, self.dim)
                self.kept.img_n[i] = 0
                if listed:
                    self.nb.listed_candidates(i, xi, eye, xi, xi, False, False, self.kept.listed_pair, ctx, acc)
                else:
                    self.nb.grid_candidates(i, xi, eye, xi, xi, False, l, self.pairs.factor_pair, ctx, acc)
                self.nb.images(i, h, self._factor_images.visit, ctx, acc)
                den = self.pairs.denominator(acc)
                # an isolated particle has no neighbour to push: no pressure
                self.alpha[i] = p[i].rho / den if den > 1e-12 * p[i].rho * p[i].rho else 0.0
                self.n_real[None] += 1
                self.speed_sum[None] += ti.cast(p[i].v.norm() / self.lev.s[l], ti.f64)

    @ti.func
    def inherited_share(self):
        """The share of an inherited compression this step removes, dt / correction_time."""
        h_dt = ti.cast(self.state.dt[None], float)
        return ti.min(h_dt / ti.max(self.correction_time[None], 1e-30), 1.0)

    @ti.func
    def excess(self, i):
        """ρ_i − ρ0 − δρ_i: particle i's density error (δρ a split child's, ``fade``)."""
        return self.pool.p[i].rho - ti.static(self.rest_density) - self.fade.excess(i)

    @ti.kernel
    def _keep_kicked(self, n: ti.i32):
        for i in range(n):
            if is_real(self.pool.p[i].kind):
                self.kicked[i] = self.pool.p[i].v

    def _shorten(self, n: int) -> bool:
        """The step halved (``_halve``), unless that is below its dt_min; whether it was.
        Read on the host: this runs only after a solve stopped at its maximum."""
        if 0.5 * float(self.state.dt[None]) < float(self.state.dt_min[None]):
            return False
        self._halve(n)
        return True

    @ti.kernel
    def _halve(self, n: ti.i32):
        """The kick u + dt a taken back to u + dt a / 2 for every real particle, the
        virtual ones following their owners, and the spacings the fastest particle moves
        (the slow-flow tolerance's) halved. The split fade's decay already ran for the whole
        step, a share dt/τ ≪ 1 of δρ."""
        p = ti.static(self.pool.p)
        dt = self.state.dt[None]
        self.state.dt[None] = 0.5 * dt
        self.stop.rest.share[None] *= 0.5
        back = ti.cast(0.5 * dt, float)
        for i in range(n):
            if is_real(p[i].kind):
                p[i].v = self.kicked[i] - back * p[i].a
                self.kicked[i] = p[i].v
        if ti.static(self.adaptive):
            for j in range(n):
                if is_virtual(p[j].kind):
                    self.coupling.follow_owners(j, self.pool.p.v)

    @ti.kernel
    def _pressures(self, n: ti.i32):
        p = ti.static(self.pool.p)
        for i in range(n):
            if is_real(p[i].kind):
                p[i].p = self.ksum[i] * p[i].rho

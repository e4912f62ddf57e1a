"""Divergence-free SPH (Bender & Koschier, "Divergence-Free SPH for Incompressible and
Viscous Fluids", SCA 2015 / TVCG 2017): an implicit pressure solver whose time step is set
by the flow speed, not by a sound speed.

Its passes in a step (``simulation.py`` schedules them):

1. ``after_density``, ``dfsph_factors`` and ``divergence_solve``: the factor of each real particle,
   α_i = ρ_i / (|Σ_j m_j ∇W_ij|² + m_i Σ_j m_j |∇W_ij|²) (the second sum is the reaction
   of i's pressure on its neighbours; with equal masses it is the paper's Σ_j |m_j ∇W_ij|²,
   see ``gradients.py``),
   then the divergence solve (``dfsph.divergence_solve``, with the last step's dt): Jacobi iterations on the
   velocities until the density's rate of change, Dρ_i/Dt = Σ_j m_j (u_i − u_j)·∇W_ij
   (compression only), averaged over the real particles, times the step, is within
   ``dfsph.divergence_tolerance`` of ρ0: κ_i = Dρ_i/Dt α_i, u_i −= Σ_j m_j (κ_i/ρ_i +
   κ_j/ρ_j) ∇W_ij;
2. non-pressure accelerations (``forces.py`` with a zero pressure term, the integrator's
   gravity and disturbances), the time step dt = λ s_l / |u| (``dfsph.cfl``, s_l the
   particle's level spacing) with dt_max and the force and viscous bounds, and the kick
   u* = u + dt a;
3. ``after_kick``, ``density_solve``: the constant-density solve, Jacobi iterations until the average predicted
   density error, (ρ*_i − ρ0)/ρ0 with ρ*_i = ρ_i + dt Σ_j m_j (u_i − u_j)·∇W_ij (compression
   only, so that a free surface is not pulled in), is within ``dfsph.density_tolerance``
   (tightened in slow flow down to ``dfsph.rest_tolerance``) and no particle's is
   above ``dfsph.max_density_error`` (the stopping rule: ``tolerance.py``):
   κ_i = (ρ*_i − ρ0) α_i / dt², u_i −= dt Σ_j m_j (κ_i/ρ_i + κ_j/ρ_j) ∇W_ij; warm-started
   from the last step's pressure (carried by the sort in the particle's ``p``);
4. drift, collide and the virtual particles' advection (integrator).

Both solves keep m_j inside every sum (particles of one level may differ in mass after a
partial merge), visit the walls and obstacles as mirror images (x_i − x_j' = L(xq − x_j),
u_j' = L u_j, κ_j' = κ_j), as the force pass does, so the response is the same at every
level, and go through the level coupling: each level's sums include its virtual
particles, whose velocities follow their owners' after every iteration, whose κ is their
partner pressure (0 with the variational coupling), and whose reaction is handed back,
split evenly, to the real particles they stand for. The pressure a particle shows
(``p``, in dumps) is ρ_i Σ κ_i over the density solve's iterations: the p of
u −= dt Σ m_j (p_i/ρ_i² + p_j/ρ_j²) ∇W.

Iterations run ``ITERATIONS_PER_LAUNCH`` to a kernel launch, the convergence decided on
the device; the host reads it once per launch. A solve that stops at its maximum
iterations is counted (``stats``) and warned about once.
"""

import taichi as ti

from mrsph.sph.neighbours import ImageNeighbours
from mrsph.sph.particles import is_real, is_virtual
from mrsph.sph.step import Pass

from ..base import PressureSolver, TimeStepBound
from ..eos import sound_speed
from ..gradients import PairGradients
from .counts import DENSITY, DIVERGENCE, SolveCounts
from .pairs import StoredPairs
from .tolerance import DONE, RUNS, Stopping

# Jacobi iterations per kernel launch: the host reads the convergence after each launch.
# More saves a launch and a read (~15 µs, against ~1.5 ms an iteration at 10k particles)
# per iteration, but each is a copy of the iteration's code in the kernel, and Taichi's
# compile time grows faster than the code: the DFSPH kernels took ~4 minutes to compile
# on this CPU with two (the window's solver switch waited for them, and the five first
# DFSPH compiles were half of the test suite's time). ``_sweep`` also runs the warm start
# in this loop, so with more than one a launch it would warm-start more than once: take
# the warm start out of the loop first.
ITERATIONS_PER_LAUNCH = 1

WARM = 2  # what a sweep (``_sweep``) runs: a solve's iteration (DENSITY, DIVERGENCE), or the warm start


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
        self.divergence = params.divergence_solve
        self.warm_start = params.warm_start
        self.warm_share = ti.field(float, shape=())  # in a field, not compiled in
        self.warm_share[None] = self.warm_start
        # the time over which an inherited compression is corrected (``_inherited``)
        self.correction_time = ti.field(float, shape=())
        self.correction_time[None] = params.correction_time
        self._damping_c = sound_speed(fluid.stiffness, fluid.eos)
        cap = core.pool.capacity
        self.alpha = ti.field(float, shape=cap)
        self.pairs = PairGradients(core, coupling)  # ∇W of neighbours and images, the factor sums
        self.kept = StoredPairs(core.pool, self.dim, core.nb.max_neighbours, self.pairs.grad, self.pairs.add_factor)
        self.kappa = ti.field(float, shape=cap)  # this iteration's κ_i
        self.ksum = ti.field(float, shape=cap)  # Σ κ_i over the density solve
        self.err = ti.field(ti.f64, shape=())  # Σ of the real particles' errors
        self.n_real = ti.field(ti.i32, shape=())
        # the visits of each image's candidates, for Neighbours.images
        self._factor_images = ImageNeighbours(self.nb, self.kept.image_pair)
        self._rate_images = ImageNeighbours(self.nb, self._rate_pair)
        self._push_images = ImageNeighbours(self.nb, self._push_image)
        self.counts = SolveCounts(self.stop.tolerance, self.stop.max_iterations, warn, params.max_density_error)
        # a step shortened when its density solve stops at its maximum (``_density_solve``):
        # the kicked velocities it starts again from
        self.shorten_steps = params.shorten_steps
        self.kicked = ti.Vector.field(self.dim, float, shape=cap if params.shorten_steps else 1)

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
    def note_step(self, moved):
        """The spacings the step's fastest particle moves (``RestTolerance``)."""
        self.stop.rest.note_step(moved)

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
        """Two loops a Jacobi sweep (the rate, the push), the warm start's one sweep."""
        warm = 1.0 if self.warm_start > 0.0 else 0.0
        return 2.0 * (stats["density_iterations"] + stats["divergence_iterations"] + warm)

    def _divergence_solve(self, n: int) -> None:
        it, err, hit = self._solve(n, DIVERGENCE)
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
            if self.warm_start > 0.0:
                self._sweep(n, WARM, 0.0, 0, 0)
            else:
                self._cold(n)
            it, err, hit = self._solve(n, DENSITY)
            if not (hit and shortened < self.shorten_steps and self._shorten(n)):
                break
            shortened += 1
            self.counts.iterations[DENSITY] += it  # the work of the solve dropped
        # read back only for the warning: a read per step costs a device sync
        peak = float(self.stop.peak[None]) / self.rest_density if hit else None
        self.counts.add(DENSITY, it, err, hit, peak, float(self.state.t[None]) if hit else None, shortened)
        self._pressures(n)
        return float(self.state.dt[None]) if shortened else None

    def _solve(self, n: int, which: int):
        """Jacobi iterations, ``ITERATIONS_PER_LAUNCH`` a launch, each launch returning
        whether the device says done (its outcome is read once, at the end: a state read
        per launch was 13 of a demo_2d step's 43 calls); returns (iterations, average
        error, stopped at the maximum)."""
        self.stop.start()
        while not self._sweep(n, which, *self.stop.args(which)):
            pass
        iterations, error, hit_max = self.stop.outcome()
        return int(iterations), float(error), bool(hit_max)

    # ------------------------------------------------------------------ device
    @ti.kernel
    def _factors(self, n: ti.i32):
        p = ti.static(self.pool.p)
        self.n_real[None] = 0
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

    @ti.func
    def _rate(self, i):
        """Σ_j m_j (u_i − u_j')·∇W_ij over i's neighbourhood: the listed neighbours from
        ``kept``, an overflowed list or images that did not fit on the fly."""
        p = ti.static(self.pool.p)
        l, h, ctx = self.pairs.ctx(i)
        rate = 0.0
        if self.nb.is_listed(i):
            vi = p[i].v
            for q in range(self.nb.count[i]):
                rate += (vi - p[self.nb.lists[i, q]].v).dot(self.kept.gw[i, q])
        else:
            self.nb.grid_candidates(
                i, p[i].x, ti.Matrix.identity(float, self.dim), p[i].x, p[i].x, False, l, self._rate_pair, ctx, rate
            )
        if self.kept.images_kept(i):
            rate = self.kept.image_rate(i, rate)
        else:
            self.nb.images(i, h, self._rate_images.visit, ctx, rate)
        return rate

    @ti.func
    def _push_all(self, i):
        """Σ_j m_j (κ_i/ρ_i + κ'_j/ρ_j) ∇W_ij over i's neighbourhood (listed neighbours from
        ``kept``), the reactions of virtual neighbours handed on."""
        p = ti.static(self.pool.p)
        l, h, ctx = self.pairs.ctx(i)
        acc = ti.Vector.zero(float, self.dim)
        ki = self.kappa[i] / p[i].rho
        if self.nb.is_listed(i):
            mi = p[i].m
            for q in range(self.nb.count[i]):
                j = self.nb.lists[i, q]
                f = (ki + self._shown(j)) * self.kept.gw[i, q]
                acc += f
                self.coupling.hand_reaction(j, -mi * f)
        else:
            self.nb.grid_candidates(
                i, p[i].x, ti.Matrix.identity(float, self.dim), p[i].x, p[i].x, False, l, self._push_own, ctx, acc
            )
        if self.kept.images_kept(i):
            for k in range(self.kept.img_n[i]):  # the walls are external: nothing handed on
                acc += (ki + self._shown(self.kept.img_j[i, k])) * self.kept.img_g[i, k]
        else:
            self.nb.images(i, h, self._push_images.visit, ctx, acc)
        return acc

    @ti.func
    def _rate_pair(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """m_j (u_i − u_j')·∇W_ij, u_j' = L u_j."""
        ok, g = self.pairs.grad(i, j, xq, L, p0, nrm, check, ctx)
        if ok:
            p = ti.static(self.pool.p)
            acc += p[j].m * (p[i].v - L @ p[j].v).dot(g)

    @ti.func
    def _shown(self, j):
        """κ'_j/ρ_j, κ'_j the pressure j shows its neighbours (the coupling's)."""
        return self.coupling.partner_pressure(self.pool.p[j].kind, self.kappa[j]) / self.pool.p[j].rho

    @ti.func
    def _push(self, i, j, g):
        """m_j (κ_i/ρ_i + κ'_j/ρ_j) ∇W_ij."""
        p = ti.static(self.pool.p)
        return p[j].m * (self.kappa[i] / p[i].rho + self._shown(j)) * g

    @ti.func
    def _push_own(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """Own-level neighbour: its part of the velocity change, and the reaction of a
        virtual j handed to its owners (as a force, m_i times the velocity change)."""
        ok, g = self.pairs.grad(i, j, xq, L, p0, nrm, check, ctx)
        if ok:
            f = self._push(i, j, g)
            acc += f
            self.coupling.hand_reaction(j, -self.pool.p[i].m * f)

    @ti.func
    def _push_image(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """A mirror image: the wall is external, nothing is handed on."""
        ok, g = self.pairs.grad(i, j, xq, L, p0, nrm, check, ctx)
        if ok:
            acc += self._push(i, j, g)

    @ti.func
    def _update(self, n, scale):
        """u_i −= scale Σ_j m_j (κ_i/ρ_i + κ'_j/ρ_j) ∇W_ij for every real i, then the
        reactions handed to the owners of virtual neighbours, then the virtual particles'
        velocities from their owners. Three loops (adaptive) or one."""
        p = ti.static(self.pool.p)
        for i in range(n):
            if self.stop.state[RUNS] and is_real(p[i].kind):
                p[i].v -= scale * self._push_all(i)
        if ti.static(self.adaptive):
            for i in range(n):
                if self.stop.state[RUNS] and is_real(p[i].kind):
                    r = self.coupling.take_reaction(i, ti.Vector.zero(float, self.dim))
                    p[i].v += scale * r / p[i].m
            for j in range(n):
                if self.stop.state[RUNS] and is_virtual(p[j].kind):
                    self.coupling.follow_owners(j)

    @ti.kernel
    def _sweep(self, n: ti.i32, mode: ti.i32, tol: ti.f64, min_it: ti.i32, max_it: ti.i32) -> ti.i32:
        """One kernel for the three sweeps over the fluid, ``mode`` a runtime argument: a
        Jacobi iteration of the density or the divergence solve (``ITERATIONS_PER_LAUNCH``
        of them), or the density solve's warm start. Each measures the rate of the current
        velocities, sets κ from it, and updates the velocities (``_update``); an iteration
        first decides on the device whether to stop (``Stopping``: converged after at
        least ``min_it`` updates, or ``max_it`` reached). One kernel, not three, because
        every copy of the neighbour sums costs compile time (the three took 3x as long,
        docs/performance.md).

        The warm start: where the kicked velocities compress a particle (ρ*_i > ρ0), κ_i
        starts at ``dfsph.warm_start`` times the last step's p_i/ρ_i (0 for a new particle),
        elsewhere at 0. Less than the whole of the last pressure, and none where the fluid
        is not compressed, since a solve only adds pressure (its errors are compressions):
        a warm start past the solution is not taken back within the step, and the next
        step starts from it again."""
        p = ti.static(self.pool.p)
        rho0 = ti.static(self.rest_density)
        h_dt = ti.cast(self.state.dt[None], float)  # this step's (the last one's before the kick)
        state, peak = ti.static(self.stop.state, self.stop.peak)
        share = ti.min(h_dt / ti.max(self.correction_time[None], 1e-30), 1.0)  # of an inherited compression
        for _ in ti.static(range(ITERATIONS_PER_LAUNCH)):
            self.err[None] = 0.0
            peak[None] = 0.0
            state[RUNS] = 1 if mode == WARM else 1 - state[DONE]
            for i in range(n):
                if state[RUNS] and is_real(p[i].kind):
                    rate = self._rate(i)
                    if mode == DENSITY:
                        e = ti.max(self._inherited(i, share) + h_dt * rate, 0.0)  # ρ* − ρ0, compression only
                        self.kappa[i] = e * self.alpha[i] / (h_dt * h_dt)
                        self.err[None] += ti.cast(e, ti.f64)
                        if e > peak[None]:  # a float max is a compare-and-swap loop
                            ti.atomic_max(peak[None], e)
                    elif mode == DIVERGENCE:
                        e = ti.max(rate, 0.0)  # Dρ/Dt, compression only
                        self.kappa[i] = e * self.alpha[i]
                        self.err[None] += ti.cast(e * h_dt, ti.f64)
                    else:
                        k = 0.0
                        if self._inherited(i, share) + h_dt * rate > 0.0:
                            k = self.warm_share[None] * p[i].p / p[i].rho
                        self.kappa[i] = k
                        self.ksum[i] = k
                elif mode == WARM:
                    self.kappa[i] = 0.0
                    self.ksum[i] = 0.0
            if mode != WARM and state[RUNS]:
                avg = self.err[None] / ti.max(self.n_real[None], 1) / rho0
                self.stop.decide(mode, avg, tol, min_it, max_it)
            # the mode in the loop's bound, not around the loop: only a kernel's outermost
            # loops run in parallel, and inside an `if` this one ran on one thread (on a
            # GPU, 8 ms of every 9 a sweep took at 100k particles)
            for i in range(ti.select(mode == DENSITY, n, 0)):
                if state[RUNS] and is_real(p[i].kind):
                    self.ksum[i] += self.kappa[i]
            self._update(n, 1.0 if mode == DIVERGENCE else h_dt)
        return state[DONE]

    @ti.func
    def _inherited(self, i, share):
        """The part of particle i's density error, ρ_i − ρ0 − δρ_i, that this step's density
        solve removes: a compression only its ``share`` (dt / ``dfsph.correction_time``, at
        most 1), a deficit whole. Removed within one step, a compression η costs a speed
        η s/dt, and a step the CFL bound shortened, dt = λ s/|u|, makes that η |u|/λ: the
        flow's own speed fed back. In the stirred soak, fluid thrown against the ceiling,
        compressed 25 % beyond what the step predicted, went from 16 to 30 m/s in one step
        and on to 71 m/s; corrected over 2 ms, it stays within 31 m/s (docs/validation.md,
        "Stirred soak"). A deficit pushes nothing: left whole, a free surface is free as
        before."""
        c = self.pool.p[i].rho - ti.static(self.rest_density) - self.fade.excess(i)
        return ti.select(c > 0.0, share * c, c)

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
                    self.coupling.follow_owners(j)

    @ti.kernel
    def _cold(self, n: ti.i32):
        for i in range(n):
            self.ksum[i] = 0.0
            self.kappa[i] = 0.0

    @ti.kernel
    def _pressures(self, n: ti.i32):
        p = ti.static(self.pool.p)
        for i in range(n):
            if is_real(p[i].kind):
                p[i].p = self.ksum[i] * p[i].rho

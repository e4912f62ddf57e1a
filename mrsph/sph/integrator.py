"""Time integration (METHOD.md §1, Eq. 21–23): accelerations, the time step, and the
kick, drift and collide of symplectic Euler, as passes of the step's list
(``timestep``, ``kick``, ``drift``, or ``integrate`` for kick and drift in one loop where
the solver has nothing between them, and ``virtual_advect``).

- accelerate: a_i = F_i/m_i + g + disturbances (the body forces), with the reactions the
  level coupling handed to i, and i's CFL and force rates and whether it is bad;
- the time step: dt = min(dt_max, CFL bound λ L/(c + |u|), force bound λ_f sqrt(h/|a|),
  the solver's own bound 1/rate_i (dfsph's pressure bound), viscous bound, disturbance
  bound), each particle with its own level's lengths, λ, L and c the pressure solver's
  (``pressure.base.TimeStepBound``), then cut to the end of the frame;
- kick u += dt a, drift x += dt u, collide (walls and obstacles, ``boundary.py``);
- the virtual particles' advection (``multires.coupling``), after their owners moved.

Nothing moves when a particle is bad (NaN/Inf, an acceleration past ``ACCEL_OVERFLOW``, a
speed past ``physics.max_speed``) or dt is below ``physics.dt_min``: the host reports it
(``SimulationError``) with the particles as the step found them.
"""

import math

import taichi as ti

from . import refusal
from .forces import viscous_dt
from .particles import is_real, is_virtual
from .refusal import ACCEL_OVERFLOW
from .step import Pass

REDUCTION_BLOCKS = 256  # blocks of the time-step reduction (see ``accelerations``)

# How much an implicit solver's step may grow on the last one's: a pressure burst that
# shortened a step, then a step twice as long, rang the 2D adaptive deep tank's pressure
# between 0.3 and 1.4 of hydrostatic (``timestep_func``).
STEP_GROWTH = 1.25

# What ``kick_drift_collide`` does for a particle: the kick, the drift and the walls.
KICK, DRIFT, COLLIDE = 1, 2, 4


class SimulationError(RuntimeError):
    """The simulation cannot go on (NaN, a time step below dt_min, a full pool at start)."""


@ti.data_oriented
class Integrator:
    live_keys = ("physics.gravity",)

    def __init__(self, core, physics, state, coupling, disturbances, pressure, fade, viscosity):
        """physics: the scene's [physics] params; state: the step's inputs, dt and go
        (``step.StepState``); coupling: the reactions handed on and the virtual
        particles' advection; pressure: the solver's CFL rate and what it notes of the
        step; fade: a split child's offset decays with the steps (multires/fade.py);
        viscosity: () -> μ on the host, as last set (``Forces``)."""
        self.physics = physics
        self.viscosity = viscosity
        self.dim, self.adaptive = core.dim, core.adaptive
        self.pool, self.lev, self.boundary = core.pool, core.lev, core.boundary
        self.state, self.fade = state, fade
        self.coupling, self.disturbances, self.pressure = coupling, disturbances, pressure
        self.rest_density = core.lev.rest_density
        # without adaptivity the force pass takes the accelerations (``accelerate_reduce``)
        self.fused_accelerations = not self.adaptive and pressure.uses_forces
        self.gravity = ti.Vector.field(self.dim, float, shape=())
        self.gravity[None] = list(physics.gravity)
        # physics.max_speed: a real particle faster than this is reported as a blow-up
        self.speed_limit = ti.field(float, shape=())
        self.speed_limit[None] = physics.max_speed
        # reductions of the time-step phase: [max (c+|u|)/h, max |a|/h, max solver rate],
        # [bad count, first bad]
        self.red_f = ti.field(float, shape=3)
        self.red_i = ti.field(ti.i32, shape=2)
        # what the host reads when a step does not go: (dt before the cut to the frame's
        # end, force limit, bad count, first bad, the solver's rate); a field, not the
        # kernel's result, which costs more to pass back
        self.step_report = ti.field(ti.f64, shape=5)
        # the first bad particle as the time-step pass found it (x, u, a; level, kind): a
        # solver that predicts first sorts and projects after that pass, moving it
        self.bad_xua = ti.Vector.field(self.dim, ti.f64, shape=3)
        self.bad_lk = ti.field(ti.i32, shape=2)
        # the last step that went as its bounds chose it, before a cut to the frame's end
        # (the stats row's dt; read once a frame, by ``chosen_dt``)
        self.bound_dt = ti.field(ti.f64, shape=())
        self.even_last_steps = pressure.bound().even_last_steps

    def set_param(self, key: str, value) -> None:
        self.gravity[None] = list(map(float, value))

    # ------------------------------------------------------------------ passes
    def timestep_pass(self) -> Pass:
        """Accelerations (unless the force pass took them), the time step, whether the
        step goes; its kernel returns dt, or -1 when it does not."""
        return Pass("timestep", "timestep", self.timestep, self.timestep_func, decides=True)

    def motion(self, after_kick: list, after_drift: list) -> list:
        """The kick, the solver's passes on the kicked velocities, the drift and collide,
        the solver's passes on the drifted positions. Without passes after the kick, the
        kick and the drift run in one loop (``integrate``): one parallel loop fewer a
        step, each of which costs 50-100 µs of thread wake-ups on two cores."""
        if after_kick:
            return [
                Pass("kick", "integrate", self.kick, self.kick_func),
                *after_kick,
                Pass("drift", "integrate", self.drift, self.drift_func),
                *after_drift,
            ]
        return [Pass("integrate", "integrate", self.integrate, self.integrate_func), *after_drift]

    def advect_pass(self) -> Pass:
        """The virtual particles follow their owners, once the owners have moved."""
        return Pass("virtual_advect", "virtual_advect", self.advect, self.advect_func)

    # ------------------------------------------------------------------ device
    @ti.func
    def clear_reductions(self):
        self.red_f[0] = 0.0
        self.red_f[1] = 0.0
        self.red_f[2] = 0.0
        self.red_i[0] = 0
        self.red_i[1] = 2147483647

    @ti.func
    def _force(self, i):
        """F_i as the force pass left it in ``a`` (zero where the solver has no force pass)."""
        if ti.static(self.pressure.uses_forces):
            return self.pool.p[i].a
        else:
            return ti.Vector.zero(float, self.dim)

    @ti.func
    def accelerate(self, i, g, c_sound, stirred):
        """a_i = F_i/m_i + g + disturbances for real particle i, F_i with the reactions
        the coupling handed to it. Returns i's CFL rate (c + |u|)/h, its force rate
        |a|/h, the solver's own rate (``step_rate``, dt <= 1/rate), and whether it is bad:
        NaN/Inf velocity or acceleration, or a speed above ``physics.max_speed``."""
        p = ti.static(self.pool.p)
        f = self.coupling.take_reaction(i, self._force(i))
        acc = f / p[i].m + g
        if stirred:
            acc += self.disturbances.accel(p[i].x, p[i].v)
        p[i].a = acc
        l = p[i].level
        h = self.lev.h[l]
        speed = p[i].v.norm()
        an = acc.norm()
        # NaN fails both comparisons; Inf and speeds past physics.max_speed fail the first
        bad = not (speed <= self.speed_limit[None] and an < ACCEL_OVERFLOW)
        return self.pressure.cfl_rate(c_sound, speed, l), an / h, self.pressure.step_rate(i, l), bad

    @ti.func
    def accelerate_reduce(self, i, g, c_sound, stirred):
        """``accelerate`` one particle inside another pass's loop (a uniform run's force
        pass) and fold its rates into the reductions."""
        cfl, force, own, bad = self.accelerate(i, g, c_sound, stirred)
        if bad:
            ti.atomic_add(self.red_i[0], 1)
            ti.atomic_min(self.red_i[1], i)
        else:
            # test first: the maxima rarely grow, and an atomic float max is a
            # compare-and-swap loop on a line both threads share
            if cfl > self.red_f[0]:
                ti.atomic_max(self.red_f[0], cfl)
            if force > self.red_f[1]:
                ti.atomic_max(self.red_f[1], force)
            if ti.static(self.pressure.has_step_rate):
                if own > self.red_f[2]:
                    ti.atomic_max(self.red_f[2], own)

    @ti.func
    def accelerations(self, n, c_sound, stirred):
        """``accelerate`` every real particle and reduce the CFL and force limits and the
        NaN/Inf count. ``stirred``: some disturbance is active (else its per-particle
        loop over the slots is skipped)."""
        p = ti.static(self.pool.p)
        g = self.gravity[None]
        self.clear_reductions()
        # reduced per block of particles, then across blocks: float atomic max is a
        # compare-and-swap loop, ten times the cost of the loop body when taken per particle
        blocks = ti.static(REDUCTION_BLOCKS)
        for b in range(blocks):
            cfl, force, own, bad_count, first_bad = 0.0, 0.0, 0.0, 0, 2147483647
            # block b's share of the pool, in 64 bits: b * n passes 2^31 from 8.4M particles
            lo = ti.cast(ti.cast(b, ti.i64) * n // blocks, ti.i32)
            hi = ti.cast(ti.cast(b + 1, ti.i64) * n // blocks, ti.i32)
            for i in range(lo, hi):
                if is_real(p[i].kind):
                    cfl_i, force_i, own_i, bad = self.accelerate(i, g, c_sound, stirred)
                    if bad:
                        bad_count += 1
                        first_bad = ti.min(first_bad, i)
                    else:
                        cfl = ti.max(cfl, cfl_i)
                        force = ti.max(force, force_i)
                        own = ti.max(own, own_i)
            ti.atomic_max(self.red_f[0], cfl)
            ti.atomic_max(self.red_f[1], force)
            if ti.static(self.pressure.has_step_rate):
                ti.atomic_max(self.red_f[2], own)
            ti.atomic_add(self.red_i[0], bad_count)
            ti.atomic_min(self.red_i[1], first_bad)

    @ti.func
    def kick_drift_collide(self, i, parts: ti.template()):
        """Symplectic Euler for real particle i: the kick u += dt a (KICK), the drift
        x += dt u (DRIFT), then the walls and obstacles (COLLIDE)."""
        p = ti.static(self.pool.p)
        dt = ti.cast(self.state.dt[None], float)
        x, v = p[i].x, p[i].v
        if ti.static(parts & KICK):
            v += dt * p[i].a
        if ti.static(parts & DRIFT):
            x += dt * v
        if ti.static(parts & COLLIDE):
            x, v = self.boundary.collide(x, v)
        p[i].x = x
        p[i].v = v
        if ti.static(parts & KICK):
            self.fade.decay(i, dt)

    @ti.func
    def _move(self, n, parts: ti.template()):
        for i in range(n):
            if self.state.go[None] and is_real(self.pool.p[i].kind):
                self.kick_drift_collide(i, parts)

    @ti.kernel
    def timestep(self, n: ti.i32) -> ti.f64:
        self.timestep_func(n)
        return self.state.outcome()

    @ti.func
    def timestep_func(self, n):
        """Accelerations (unless the force pass took them), then dt = min(cap, λ/max rate,
        λ_f / sqrt(max |a|/h), 1/max solver rate) cut to the end of the frame, whether the
        step goes, and the solver's note of it; the reasons a step does not go in
        ``step_report``."""
        st = self.state
        if ti.static(not self.fused_accelerations):
            self.accelerations(n, st.c_sound[None], st.stirred[None])
        cfl_lim = ti.cast(self.red_f[0], ti.f64)
        force_lim = ti.cast(self.red_f[1], ti.f64)
        max_dt = st.max_dt[None]
        dt = st.cap[None]
        if cfl_lim > 0.0:
            dt = ti.min(dt, st.cfl[None] / cfl_lim)
        if force_lim > 0.0:
            dt = ti.min(dt, st.force_factor[None] / ti.sqrt(force_lim))
        own_lim = ti.cast(self.red_f[2], ti.f64)
        if own_lim > 0.0:
            dt = ti.min(dt, 1.0 / own_lim)
        if ti.static(self.even_last_steps):
            # an implicit solve's κ goes as 1/dt²: a frame's last step cut short would
            # correct its density error in less time with more pressure, and every change
            # of dt sets the pressure ringing (the resting deep tank's pressure read 1.65
            # of hydrostatic in a last step cut to 0.36 of 0.62 ms). So dt grows by at most
            # STEP_GROWTH on the last step's (not from below a few dt_min, so that a step
            # cut to a sliver does not hold the next ones down), and a frame's steps are
            # equal: what is left of it over the fewest steps the bound allows.
            dt = ti.min(dt, ti.max(STEP_GROWTH * st.dt[None], 4.0 * st.dt_min[None]))
        st.go[None] = ti.cast(self.red_i[0] == 0 and dt >= st.dt_min[None], ti.i32)
        if st.go[None]:
            self.bound_dt[None] = dt
        if ti.static(self.even_last_steps):
            if max_dt <= dt * (1.0 + 1e-6):
                dt = max_dt
            elif max_dt < 1e30:
                dt = max_dt / ti.ceil(max_dt / dt * (1.0 - 1e-6))
        st.dt[None] = ti.min(dt, max_dt)
        self.pressure.note_step(st.dt[None])
        if not st.go[None]:
            self.step_report[0] = dt
            self.step_report[1] = force_lim
            self.step_report[2] = ti.cast(self.red_i[0], ti.f64)
            self.step_report[3] = ti.cast(self.red_i[1], ti.f64)
            self.step_report[4] = own_lim
            if self.red_i[0] > 0:
                b = self.red_i[1]
                self.bad_xua[0] = ti.cast(self.pool.p[b].x, ti.f64)
                self.bad_xua[1] = ti.cast(self.pool.p[b].v, ti.f64)
                self.bad_xua[2] = ti.cast(self.pool.p[b].a, ti.f64)
                self.bad_lk[0] = self.pool.p[b].level
                self.bad_lk[1] = self.pool.p[b].kind

    @ti.kernel
    def integrate(self, n: ti.i32):
        self.integrate_func(n)

    @ti.func
    def integrate_func(self, n):
        """Kick, drift and collide in one loop."""
        self._move(n, KICK | DRIFT | COLLIDE)

    @ti.kernel
    def kick(self, n: ti.i32):
        self.kick_func(n)

    @ti.func
    def kick_func(self, n):
        self._move(n, KICK)

    @ti.kernel
    def drift(self, n: ti.i32):
        self.drift_func(n)

    @ti.func
    def drift_func(self, n):
        """Drift and collide (after the solver's passes on the kicked velocities)."""
        self._move(n, DRIFT | COLLIDE)

    @ti.kernel
    def advect(self, n: ti.i32):
        self.advect_func(n)

    @ti.func
    def advect_func(self, n):
        p = ti.static(self.pool.p)
        for j in range(n):
            if self.state.go[None] and is_virtual(p[j].kind):
                self.coupling.advect(j, ti.cast(self.state.dt[None], float))

    # ------------------------------------------------------------------ host
    def chosen_dt(self) -> float:
        """The last step's dt as its bounds chose it, before any cut to a frame's end."""
        return float(self.bound_dt[None])

    def set_chosen_dt(self, dt: float) -> None:
        """Reset or restore what ``chosen_dt`` reads."""
        self.bound_dt[None] = float(dt)

    def bounds(self):
        """(cap, viscous bound) of dt from the solver's bound, the disturbances and the
        viscosity (host side; ``forces.viscous_dt``)."""
        cap = self.pressure.bound().dt_max
        strength = self.disturbances.max_strength()
        if strength > 0:
            cap = min(cap, refusal.DISTURBANCE_DT / strength)
        viscous = viscous_dt(self.physics.viscous_factor, self.lev.h0, self.rest_density, self.viscosity())
        return min(cap, viscous), viscous

    def step_args(self, max_dt: float | None, stirred: int, t: float) -> tuple:
        """``StepState``'s inputs: (c, stirred, cfl, force factor, cap, dt_min, max_dt, t),
        ``max_dt`` None for no cut to a frame's end."""
        ph, bound = self.physics, self.pressure.bound()
        cap, _ = self.bounds()
        return (
            bound.signal_speed,
            stirred,
            bound.number,
            ph.force_factor if bound.force_limited else math.inf,
            cap,
            ph.dt_min,
            math.inf if max_dt is None else float(max_dt),
            float(t),
        )

    def refuse(self, where: str):
        """Raise the ``SimulationError`` that says why the step just tried did not go
        (the time-step pass said -1; ``where``: the step and time, for the message)."""
        ph = self.physics
        _, viscous_dt = self.bounds()
        stable_dt, force_lim, bad, first_bad, own_lim = self.step_report.to_numpy().tolist()
        if bad > 0:
            x, v, a = self.bad_xua.to_numpy()
            level, kind = self.bad_lk.to_numpy().tolist()
            raise SimulationError(
                f"{where}: {refusal.bad_particles(ph, int(first_bad), int(bad), x, v, a, level, kind)}"
            )
        if not stable_dt >= ph.dt_min:  # as the kernel decided (NaN included)
            if viscous_dt < ph.dt_min:
                raise SimulationError(
                    f"{where}: the viscous time-step bound "
                    f"{viscous_dt:.3g} s is below physics.dt_min = {ph.dt_min:g} s: "
                    f"fluid.viscosity = {self.viscosity():g} Pa s is too high for this resolution"
                )
            cause = refusal.dt_cause(
                ph, self.pressure, self.disturbances.max_strength(), self.lev, stable_dt, force_lim, own_lim
            )
            raise SimulationError(
                f"{where}: time step {stable_dt:.3g} s is below physics.dt_min = {ph.dt_min:g} s: {cause}"
            )
        raise AssertionError("a step that did not go left no reason in step_report")

"""Time integration (METHOD.md §1, Eq. 21–23): accelerations, the time step, and the
kick, drift and collide of symplectic Euler.

- accelerate: a_i = F_i/m_i + g + disturbances (the body forces), with the reactions the
  level coupling handed to i, and i's CFL and force rates and whether it is bad;
- the time step: dt = min(dt_max, CFL bound λ h/(c + |u|), force bound λ_f sqrt(h/|a|),
  viscous bound, disturbance bound), each particle with its own level's h, c the pressure
  solver's signal speed, then cut to the end of the frame;
- kick u += dt a, drift x += dt u, collide (walls and obstacles, ``boundary.py``);
- the virtual particles' advection (``multires.coupling``), after their owners moved.

Nothing moves when a particle is bad (NaN/Inf, an acceleration past ``ACCEL_OVERFLOW``, a
speed past ``physics.max_speed``) or dt is below ``physics.dt_min``: the host reports it
(``SimulationError``) with the particles as the step found them.
"""

import math

import numpy as np
import taichi as ti

from .particles import is_real, is_virtual

# An acceleration this large (m/s²) is a blow-up: a step refuses it as it refuses NaN.
# (In f32, |a| overflows already from 1.8e19 m/s², as its square passes the float range.)
ACCEL_OVERFLOW = 1e30

REDUCTION_BLOCKS = 256  # blocks of the time-step reduction (see ``accelerations``)

# Parts of ``end_step``: one launch runs them all, a profiled step one a call; an implicit
# pressure solver solves between the kick and the drift (two launches).
END_TIMESTEP, END_KICK, END_BOUNDARIES, END_ADVECT, END_DRIFT = 1, 2, 4, 8, 16
END_INTEGRATE = END_KICK | END_DRIFT


class SimulationError(RuntimeError):
    """The simulation cannot go on (NaN, a time step below dt_min, a full pool at start)."""


@ti.data_oriented
class Integrator:
    live_keys = ("physics.gravity",)

    def __init__(self, parts, pressure, viscosity):
        ph = self.physics = parts.scene["physics"]
        self.viscosity = viscosity  # () -> μ on the host, as last set (``Forces``)
        self.dim, self.adaptive = parts.dim, parts.adaptive
        self.pool, self.lev, self.boundary = parts.pool, parts.lev, parts.boundary
        self.fade = parts.fade  # a split child's density offset decays with the steps
        self.coupling, self.disturbances, self.pressure = parts.coupling, parts.disturbances, pressure
        self.rest_density = float(parts.scene["fluid"]["rest_density"])
        self.fused_accelerations = not self.adaptive  # see forces.Forces.run
        self.gravity = ti.Vector.field(self.dim, float, shape=())
        self.gravity[None] = list(map(float, ph["gravity"]))
        # physics.max_speed: a real particle faster than this is reported as a blow-up
        self.speed_limit = ti.field(float, shape=())
        self.speed_limit[None] = float(ph["max_speed"])
        # reductions of the time-step phase: [max (c+|u|)/h, max |a|/h, bad count, first bad]
        self.red_f = ti.field(float, shape=2)
        self.red_i = ti.field(ti.i32, shape=2)
        # the step's dt (f64, so that a step cut to the end of a frame ends on it), and
        # whether the step may move the particles (no NaN, dt not below dt_min)
        self.step_dt = ti.field(ti.f64, shape=())
        self.step_go = ti.field(ti.i32, shape=())
        # what the host reads when a step does not go: (dt before the cut to the frame's
        # end, force limit, bad count, first bad); a field, not the kernel's result,
        # which costs more to pass back (see ``end_step``)
        self.step_report = ti.field(ti.f64, shape=4)
        # the last step that went as its bounds chose it, before a cut to the frame's end
        # (the stats row's dt; read once a frame, by ``chosen_dt``)
        self.bound_dt = ti.field(ti.f64, shape=())
        advect = END_ADVECT if self.adaptive else 0
        if pressure.implicit:  # the pressure solve between the kick and the drift
            self.launches = (END_TIMESTEP | END_KICK, END_DRIFT | END_BOUNDARIES | advect)
        else:
            self.launches = (END_TIMESTEP | END_INTEGRATE | END_BOUNDARIES | advect,)

    def set_param(self, key: str, value) -> None:
        self.gravity[None] = list(map(float, value))

    # ------------------------------------------------------------------ device
    @ti.func
    def clear_reductions(self):
        self.red_f[0] = 0.0
        self.red_f[1] = 0.0
        self.red_i[0] = 0
        self.red_i[1] = 2147483647

    @ti.func
    def accelerate(self, i, g, c_sound, stirred):
        """a_i = F_i/m_i + g + disturbances for real particle i, F_i with the reactions
        the coupling handed to it. Returns i's CFL rate (c + |u|)/h, its force rate
        |a|/h, and whether it is bad: NaN/Inf velocity or acceleration, or a speed above
        ``physics.max_speed``."""
        p = ti.static(self.pool.p)
        f = self.coupling.take_reaction(i, p[i].a)
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
        return self.pressure.cfl_rate(c_sound, speed, l), an / h, bad

    @ti.func
    def accelerate_reduce(self, i, g, c_sound, stirred):
        """``accelerate`` one particle inside another pass's loop (a uniform run's force
        pass) and fold its rates into the reductions."""
        cfl, force, bad = self.accelerate(i, g, c_sound, stirred)
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
            cfl, force, bad_count, first_bad = 0.0, 0.0, 0, 2147483647
            # block b's share of the pool, in 64 bits: b * n passes 2^31 from 8.4M particles
            lo = ti.cast(ti.cast(b, ti.i64) * n // blocks, ti.i32)
            hi = ti.cast(ti.cast(b + 1, ti.i64) * n // blocks, ti.i32)
            for i in range(lo, hi):
                if is_real(p[i].kind):
                    cfl_i, force_i, bad = self.accelerate(i, g, c_sound, stirred)
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

    @ti.func
    def kick_drift_collide(self, i, parts: ti.template()):
        """Symplectic Euler for real particle i: the kick u += dt a (END_KICK), the drift
        x += dt u (END_DRIFT), then the walls and obstacles (END_BOUNDARIES)."""
        p = ti.static(self.pool.p)
        x, v = p[i].x, p[i].v
        if ti.static(parts & END_KICK):
            v += ti.cast(self.step_dt[None], float) * p[i].a
        if ti.static(parts & END_DRIFT):
            x += ti.cast(self.step_dt[None], float) * v
        if ti.static(parts & END_BOUNDARIES):
            x, v = self.boundary.collide(x, v)
        p[i].x = x
        p[i].v = v
        if ti.static(parts & END_KICK):
            self.fade.decay(i, ti.cast(self.step_dt[None], float))

    @ti.kernel
    def end_step(
        self,
        n: ti.i32,
        c_sound: float,
        stirred: ti.i32,
        cfl: ti.f64,
        force_factor: ti.f64,
        cap: ti.f64,
        dt_min: ti.f64,
        max_dt: ti.f64,
        parts: ti.template(),
    ) -> ti.f64:
        return self.end_step_func(n, c_sound, stirred, cfl, force_factor, cap, dt_min, max_dt, parts)

    @ti.func
    def end_step_func(self, n, c_sound, stirred, cfl, force_factor, cap, dt_min, max_dt, parts: ti.template()):
        """The phases after the forces, those in ``parts`` (END_* bits): time step (with
        the accelerations, unless the force pass took them), integrate, boundaries (in
        integrate's loop when both are asked), virtual advection. Returns the dt taken,
        or -1 when the step does not go (the reasons are in ``step_report``); 0 without
        timestep. Scalars in and one out: on the CPU, a vector argument and a vector
        result cost ~50 µs a launch between them, more than integrating a few thousand
        particles."""
        p = ti.static(self.pool.p)
        out = ti.cast(0.0, ti.f64)
        if ti.static(parts & END_TIMESTEP):
            if ti.static(not self.fused_accelerations):
                self.accelerations(n, c_sound, stirred)
            cfl_lim = ti.cast(self.red_f[0], ti.f64)
            force_lim = ti.cast(self.red_f[1], ti.f64)
            dt = cap
            if cfl_lim > 0.0:
                dt = ti.min(dt, cfl / cfl_lim)
            if force_lim > 0.0:
                dt = ti.min(dt, force_factor / ti.sqrt(force_lim))
            self.step_go[None] = ti.cast(self.red_i[0] == 0 and dt >= dt_min, ti.i32)
            if self.step_go[None]:
                self.bound_dt[None] = dt
            if ti.static(self.pressure.implicit):
                # an implicit solve's κ goes as 1/dt²: a frame's last step cut to a sliver
                # would correct the whole density error in it and leave a velocity kick
                # of order error/dt. Where a full step would leave less than half a step,
                # the last two share what is left; a leftover of round-off is absorbed.
                if max_dt <= dt * (1.0 + 1e-6):
                    dt = max_dt
                elif max_dt < 1.5 * dt:
                    dt = 0.5 * max_dt
            self.step_dt[None] = ti.min(dt, max_dt)
            if ti.static(self.pressure.implicit):
                self.pressure.note_step(cfl_lim * self.step_dt[None])  # spacings moved, at most
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
                    self.kick_drift_collide(i, parts)
        if ti.static(parts & END_ADVECT):
            for j in range(n):
                if self.step_go[None] and is_virtual(p[j].kind):
                    self.coupling.advect(j, ti.cast(self.step_dt[None], float))
        return out

    # ------------------------------------------------------------------ host
    def chosen_dt(self) -> float:
        """The last step's dt as its bounds chose it, before any cut to a frame's end."""
        return float(self.bound_dt[None])

    def set_chosen_dt(self, dt: float) -> None:
        """Reset or restore what ``chosen_dt`` reads."""
        self.bound_dt[None] = float(dt)

    def bounds(self):
        """(cap, viscous bound) of dt from the scene and the disturbances (host side).

        The viscous bound: Eq. 19 relaxes a particle's velocity towards its neighbours' at
        a rate μ/ρ Σ_j V_j ∇²W ≈ 15 μ/(ρ h²) (3D; 13.3 in 2D), and the shortest mode, a
        particle against its neighbours, twice as fast; explicit Euler on that mode needs
        dt < h²ρ/(15 μ) ≈ 0.067 h²ρ/μ, so ``viscous_factor`` 0.03 keeps half of it in
        hand (as Morris et al. 1997's 0.125 h²/ν with their h, half our support). At the
        scenes' viscosities it is far above the CFL bound; it binds when the viscosity
        is raised live, which would otherwise blow up."""
        ph = self.physics
        cap = float(ph["dt_max"])
        strength = self.disturbances.max_strength()
        if strength > 0:
            cap = min(cap, 0.5 / strength)  # the disturbance relaxation stays stable
        mu = self.viscosity()
        viscous_dt = math.inf
        if mu > 0:
            viscous_dt = float(ph["viscous_factor"]) * self.lev.h0**2 * self.rest_density / mu
            cap = min(cap, viscous_dt)
        return cap, viscous_dt

    def step_args(self, max_dt: float | None, stirred: int) -> tuple:
        """``end_step``'s arguments after n: (c, stirred, cfl, force factor, cap, dt_min,
        max_dt), ``max_dt`` None for no cut to a frame's end."""
        ph = self.physics
        cap, _ = self.bounds()
        return (
            self.pressure.signal_speed(),
            stirred,
            self.pressure.cfl_number(ph),
            float(ph["force_factor"]),
            cap,
            float(ph["dt_min"]),
            math.inf if max_dt is None else float(max_dt),
        )

    def finish(self, n: int, max_dt: float | None, stirred: int, phase, profile: bool, where) -> float:
        """Accelerations, the time step, integration, boundaries and (adaptive runs) the
        virtual particles' advection: one kernel launch, integration and boundaries in one
        loop, or when profiling one call a phase (``phase(name, fn, *args)``), each timed
        as its own. Returns dt; raises ``SimulationError`` (``where()``: the step and time,
        for the message, built only then) when the step cannot go."""
        args = (n,) + self.step_args(max_dt, stirred)
        dt = 0.0
        for k, launch in enumerate(self.launches):
            if k > 0:
                if dt < 0.0:
                    break  # the step does not go: reported below
                self.pressure.solve(n, dt, phase)
            if profile:
                # One launch a part, so that each is timed; the fixed cost of a launch (its
                # arguments, result and sync), timed on an empty one, is charged once, to
                # the time step, as the fused launch pays it once.
                fixed = phase(None, self.end_step, *args, 0)
                for name, part in (
                    ("timestep", END_TIMESTEP),
                    ("integrate", launch & END_INTEGRATE),
                    ("boundaries", END_BOUNDARIES),
                    ("virtual_advect", END_ADVECT),
                ):
                    if part and part & launch:
                        out = phase(name, self.end_step, *args, part, overhead=0.0 if part == END_TIMESTEP else fixed)
                        if part == END_TIMESTEP:
                            dt = out
            else:
                out = self.end_step(*args, launch)
                if k == 0:
                    dt = out
        if dt >= 0.0:
            return dt
        self.refuse(where())

    def refuse(self, where: str):
        """Raise the ``SimulationError`` that says why the step just tried did not go
        (``end_step`` returned -1; ``where``: the step and time, for the message)."""
        ph = self.physics
        _, viscous_dt = self.bounds()
        stable_dt, force_lim, bad, first_bad = self.step_report.to_numpy().tolist()
        if bad > 0:
            self.report_bad(int(first_bad), int(bad), where)
        mu = self.viscosity()
        if not stable_dt >= float(ph["dt_min"]):  # as the kernel decided (NaN included)
            if viscous_dt < float(ph["dt_min"]):
                raise SimulationError(
                    f"{where}: the viscous time-step bound "
                    f"{viscous_dt:.3g} s is below physics.dt_min = {ph['dt_min']:g} s: "
                    f"fluid.viscosity = {mu:g} Pa s is too high for this resolution"
                )
            raise SimulationError(
                f"{where}: time step {stable_dt:.3g} s is below "
                f"physics.dt_min = {ph['dt_min']:g} s: {self.dt_cause(stable_dt, force_lim)}"
            )
        raise AssertionError("a step that did not go left no reason in step_report")

    def dt_cause(self, dt: float, force_lim: float) -> str:
        """Which bound of ``finish`` made ``dt``: the disturbance cap, read from the
        disturbances, or one of the reduced rates: the force rate |a|/h is reported, and
        the CFL rate (c + |u|)/h is cfl / dt. Which level h belongs to is not reported,
        so a speed is given as at the finest one."""
        ph = self.physics
        c = self.pressure.signal_speed()
        strength = self.disturbances.max_strength()
        if strength > 0 and dt >= 0.999 * 0.5 / strength:
            return (
                f"the disturbance bound 0.5/strength sets it (strength {strength:.3g} 1/s, "
                "the mouse's or a stirrer's): lower that strength or physics.dt_min"
            )
        force_dt = float(ph["force_factor"]) / math.sqrt(force_lim) if force_lim > 0 else math.inf
        if dt >= 0.999 * force_dt:
            return (
                f"the force bound sets it (largest |a|/h = {force_lim:.3g} 1/s^2): the fluid "
                "is blowing up; lower the disturbance strength or physics.cfl"
            )
        rate = float(ph["cfl"]) / dt
        speed = rate * self.lev.h0 - c  # |u| if the fastest particle is at level 0
        if speed <= 0.01 * c:
            return (
                f"the sound speed sqrt(fluid.stiffness) = {c:.3g} m/s sets it (physics.cfl "
                f"h / c, h0 = {self.lev.h0:.3g} m); lower fluid.stiffness or physics.dt_min"
            )
        return (
            f"the CFL bound sets it ((c + |u|)/h = {rate:.3g} 1/s with c = {c:.3g} m/s: a "
            f"particle at about {speed:.3g} m/s if at the finest level): the fluid is "
            "blowing up; lower the disturbance strength or physics.cfl"
        )

    def report_bad(self, i: int, count: int, where: str):
        def vec(field):
            val = field[i]
            return np.asarray(val.to_numpy() if hasattr(val, "to_numpy") else val, float)

        x, v, a = vec(self.pool.p.x), vec(self.pool.p.v), vec(self.pool.p.a)
        limit = float(self.physics["max_speed"])
        speed = np.linalg.norm(v)
        if not (np.isfinite(v).all() and np.isfinite(a).all()):
            what = "NaN/Inf velocity or acceleration"
        elif speed > limit:
            what = f"speed {speed:.4g} m/s above physics.max_speed = {limit:g} m/s"
        else:  # |a| >= ACCEL_OVERFLOW, or |a|² past the float's range (f32: |a| > 1.8e19)
            what = f"acceleration {np.linalg.norm(a):.4g} m/s^2, past what the step can take"
        raise SimulationError(
            f"{where}: {count} particle(s) with NaN/Inf velocity "
            f"or acceleration, an acceleration of {ACCEL_OVERFLOW:g} m/s^2 or more, or a speed "
            f"above physics.max_speed; first: particle {i}, "
            f"level {int(self.pool.p.level[i])}, "
            f"kind {int(self.pool.p.kind[i])}, x = {np.round(x, 4).tolist()}: {what}"
        )

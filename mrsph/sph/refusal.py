"""Why a step was refused, in words: the host's side of the time-step pass's report
(``Integrator.refuse`` raises the ``SimulationError``). A refused step names the bound that
made its dt too small, or the first bad particle as the pass found it, and what to change."""

import math

import numpy as np

# An acceleration this large (m/s²) is a blow-up: a step refuses it as it refuses NaN.
# (In f32, |a| overflows already from 1.8e19 m/s², as its square passes the float range.)
ACCEL_OVERFLOW = 1e30
# A disturbance relaxes a particle's velocity at ``strength`` per second; explicit Euler
# keeps that stable with room to spare while dt <= DISTURBANCE_DT / strength.
DISTURBANCE_DT = 0.5


def bad_particles(physics, i: int, count: int, x, v, a, level: int, kind: int) -> str:
    """``count`` bad particles, the first (slot ``i``) at ``x`` with ``v``, ``a``, its level
    and kind as the time-step pass read them, and what made it bad."""
    limit = physics.max_speed
    speed = np.linalg.norm(v)
    if not (np.isfinite(v).all() and np.isfinite(a).all()):
        what = "NaN/Inf velocity or acceleration"
    elif speed > limit:
        what = f"speed {speed:.4g} m/s above physics.max_speed = {limit:g} m/s"
    else:  # |a| >= ACCEL_OVERFLOW, or |a|² past the float's range (f32: |a| > 1.8e19)
        what = f"acceleration {np.linalg.norm(a):.4g} m/s^2, past what the step can take"
    return (
        f"{count} particle(s) with NaN/Inf velocity "
        f"or acceleration, an acceleration of {ACCEL_OVERFLOW:g} m/s^2 or more, or a speed "
        f"above physics.max_speed; first: particle {i}, "
        f"level {level}, kind {kind}, x = {np.round(x, 4).tolist()}: {what}"
    )


def dt_cause(physics, pressure, strength: float, lev, dt: float, force_lim: float, own_lim: float = 0.0) -> str:
    """Which bound made ``dt``: the disturbance cap (``strength``, the strongest disturbance's),
    or one of the reduced rates: the force rate |a|/h is reported, and the CFL rate of the
    solver's bound (``TimeStepBound``, its λ, length and signal speed) is λ / dt. Which level
    the fastest particle is at is not reported, so a speed is given as at the finest one."""
    bound = pressure.bound()
    c = bound.signal_speed
    if strength > 0 and dt >= 0.999 * DISTURBANCE_DT / strength:
        return (
            f"the disturbance bound {DISTURBANCE_DT:g}/strength sets it (strength {strength:.3g} 1/s, "
            "the mouse's or a stirrer's): lower that strength or physics.dt_min"
        )
    force_dt = physics.force_factor / math.sqrt(force_lim) if force_lim > 0 else math.inf
    if dt >= 0.999 * force_dt:
        return (
            f"the force bound sets it (largest |a|/h = {force_lim:.3g} 1/s^2): the fluid "
            f"is blowing up; lower the disturbance strength or {bound.key}"
        )
    if own_lim > 0 and dt >= 0.999 / own_lim:
        return f"{pressure.step_rate_says(own_lim)}: the fluid is blowing up; lower physics.dt_min"
    if bound.number == 0.0:  # no CFL bound: the solver's own step
        return f"{bound.says} sets it; lower physics.dt_min"
    rate = bound.number / dt
    speed = bound.speed_at(dt, lev.h0, lev.s0)  # |u| if the fastest is at level 0
    if c > 0 and speed <= 0.01 * c:
        return (
            f"{bound.says} sets it ({bound.key} {bound.length} / c, h0 = {lev.h0:.3g} m); "
            "lower fluid.stiffness or physics.dt_min"
        )
    form = f"(c + |u|)/{bound.length}" if c > 0 else f"|u|/{bound.length}"
    return (
        f"the CFL bound sets it ({bound.key}: {form} = {rate:.3g} 1/s with c = {c:.3g} m/s: a "
        f"particle at about {speed:.3g} m/s if at the finest level): the fluid is blowing up; "
        f"lower the disturbance strength or {bound.key}"
    )

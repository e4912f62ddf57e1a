"""Equations of state, chosen by name (``fluid.eos``).

Both are written with one stiffness k [m²/s²] so that their sound speed at rest is
sqrt(k) and switching between them keeps the time step:

- ``linear``: p = k (ρ − ρ0)   (thesis Eq. 14, after Desbrun)
- ``tait``:   p = (ρ0 k / γ) ((ρ/ρ0)^γ − 1)   (Becker & Teschner 2007), stiffer under
  compression, hence less compressible for the same time step.

Negative pressures (ρ < ρ0, near the free surface) make particles clump; by default
they are clamped to zero (``fluid.clamp_negative_pressure``).
"""

import taichi as ti

EOS_NAMES = ("linear", "tait")


@ti.func
def pressure(rho, rho0, k, gamma, tait: ti.template(), clamp: ti.template()):
    p = 0.0
    if ti.static(tait):
        p = rho0 * k / gamma * (ti.pow(rho / rho0, gamma) - 1.0)
    else:
        p = k * (rho - rho0)
    if ti.static(clamp):
        p = ti.max(p, 0.0)
    return p


def sound_speed(k: float, eos: str) -> float:
    """Sound speed at rest, for the CFL condition; the same for both by construction."""
    if eos not in EOS_NAMES:
        raise ValueError(f"fluid.eos: expected one of {EOS_NAMES} (got {eos!r})")
    return k ** 0.5

"""Equations of state, chosen by name (``fluid.eos``).

Both are written with one stiffness k [m²/s²] so that their sound speed at rest is
sqrt(k), which is what the time step's CFL bound uses, so switching between them keeps
the time step. Under compression Tait's sound speed grows, c = sqrt(k) (ρ/ρ0)^((γ−1)/2):
16 % above sqrt(k) at ρ = 1.05 ρ0 with γ = 7, so a step taken at CFL number 0.2 is one
at 0.23 there:

- ``linear``: p = k (ρ − ρ0)   (thesis Eq. 14, after Desbrun)
- ``tait``:   p = (ρ0 k / γ) ((ρ/ρ0)^γ − 1)   (Becker & Teschner 2007), stiffer under
  compression, hence less compressible for the same time step.

Negative pressures (ρ < ρ0, near the free surface) make particles clump; by default
they are clamped to zero (``fluid.clamp_negative_pressure``).
"""

import numpy as np
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
    return k**0.5


def density_at_pressure(p: float, rho0: float, k: float, eos: str, gamma: float) -> float:
    """The density whose pressure is ``p`` >= 0: the inverse of :func:`pressure`
    (host side, for the hydrostatic initial state)."""
    if eos == "tait":
        return rho0 * (1.0 + gamma * p / (rho0 * k)) ** (1.0 / gamma)
    sound_speed(k, eos)  # rejects an unknown name
    return rho0 + p / k


def hydrostatic_heights(
    depths, height: float, g: float, rho0: float, k: float, eos: str, gamma: float, samples: int = 2048
):
    """Where a column of fluid ``height`` deep, laid out on a uniform lattice at ρ0,
    sits once it is compressed to hydrostatic equilibrium.

    A particle at lattice depth D (from the top of the column) carries the weight of the
    fluid above it, p = ρ0 g D, whatever the compression, so its density is
    ρ(D) = eos⁻¹(ρ0 g D) and its height above the column's bottom becomes
    z(D) = ∫_D^height ρ0 / ρ(D') dD'. Returns z for each of ``depths`` (trapezoid rule
    on ``samples`` intervals; the integrand is within 1 % of 1 for a weakly
    compressible fluid, so the error is far below round-off of the positions).
    """
    grid = np.linspace(0.0, height, samples + 1)
    ratio = np.array([rho0 / density_at_pressure(rho0 * g * d, rho0, k, eos, gamma) for d in grid])
    # cumulative integral from the bottom (D = height) up: z(D) = ∫_D^height ratio
    seg = 0.5 * (ratio[1:] + ratio[:-1]) * np.diff(grid)
    from_top = np.concatenate([[0.0], np.cumsum(seg)])  # ∫_0^D ratio
    z_grid = from_top[-1] - from_top
    return np.interp(np.asarray(depths, float), grid, z_grid)

"""SPH smoothing kernels (METHOD.md §1; thesis Eq. 10, 17, 20; Müller et al. 2003).

Each kernel has support radius h and is zero for r > h. The constants normalise the
kernel in its dimension (∫W dV = 1); ``tests/test_kernels.py`` checks them by quadrature.

| use                | kernel                      | 2D            | 3D               |
|--------------------|-----------------------------|---------------|------------------|
| density            | poly6  c (h² − r²)³         | 4 / (π h⁸)    | 315 / (64 π h⁹)  |
| pressure gradient  | spiky  ∇W = −3c (h − r)² r̂  | c = 10/(π h⁵) | c = 15 / (π h⁶)  |
| viscosity          | ∇²W = c′ (h − r)            | 40 / (π h⁵)   | 45 / (π h⁶)      |

The 2D viscosity constant belongs to the normalised 2D kernel whose Laplacian is
c′(h − r): W(r) = c′[h(r² − h²)/4 − (r³ − h³)/9 − (h³/6) ln(r/h)], built the same way as
Müller's 3D kernel.

The Taichi functions take precomputed per-level constants (see :func:`constants`) so that
the inner loops do no powers; the numpy twins below are the reference for the tests.
The density loops call :func:`poly6`; the pair force (``forces.Forces.pair_values``)
writes :func:`spiky_grad` and :func:`visc_lap` out inline, folding pressure, artificial
viscosity and their constants into one factor along r per pair, with the spiky constant
divided by :func:`lattice_gradient_factor`. The two functions here are the formulas as
the method states them, and ``tests/test_physics.py`` checks the pair force itself
(momentum, rest density, hydrostatic pressure).
"""

import math

import numpy as np
import taichi as ti


def constants(h: float, dim: int) -> dict[str, float]:
    """Normalisation constants of the three kernels for support ``h`` in ``dim`` D."""
    if dim == 2:
        return {"poly6": 4.0 / (math.pi * h**8), "spiky": 10.0 / (math.pi * h**5), "visc": 40.0 / (math.pi * h**5)}
    if dim == 3:
        return {
            "poly6": 315.0 / (64.0 * math.pi * h**9),
            "spiky": 15.0 / (math.pi * h**6),
            "visc": 45.0 / (math.pi * h**6),
        }
    raise ValueError(f"dim must be 2 or 3 (got {dim})")


# --- Taichi ----------------------------------------------------------------------------


@ti.func
def poly6(r2, h2, c_poly6):
    """W_poly6 from the squared distance (thesis Eq. 10); the caller ensures r2 < h2."""
    d = h2 - r2
    return c_poly6 * d * d * d


@ti.func
def spiky_grad(r, rn, h, c_spiky):
    """∇W_spiky = −3c (h − |r|)² r/|r| (thesis Eq. 17); the caller ensures 0 < rn < h."""
    d = h - rn
    return (-3.0 * c_spiky * d * d / rn) * r


@ti.func
def visc_lap(rn, h, c_visc):
    """∇²W_viscosity = c′ (h − |r|) (thesis Eq. 20)."""
    return c_visc * (h - rn)


# --- numpy twins (reference for tests and host-side set-up) ----------------------------


def poly6_np(r, h, dim):
    r = np.asarray(r, dtype=np.float64)
    c = constants(h, dim)["poly6"]
    return np.where(r < h, c * np.clip(h * h - r * r, 0, None) ** 3, 0.0)


def spiky_np(r, h, dim):
    r = np.asarray(r, dtype=np.float64)
    c = constants(h, dim)["spiky"]
    return np.where(r < h, c * np.clip(h - r, 0, None) ** 3, 0.0)


def spiky_grad_np(rvec, h, dim):
    """Gradient of :func:`spiky_np` with respect to the first particle's position."""
    rvec = np.asarray(rvec, dtype=np.float64)
    rn = np.linalg.norm(rvec, axis=-1, keepdims=True)
    c = constants(h, dim)["spiky"]
    d = np.clip(h - rn, 0, None)
    return np.where(rn < h, -3.0 * c * d * d * rvec / np.maximum(rn, 1e-300), 0.0)


def viscosity_np(r, h, dim):
    """The viscosity kernel itself, whose Laplacian is :func:`visc_lap_np`."""
    r = np.maximum(np.asarray(r, dtype=np.float64), 1e-300)
    c = constants(h, dim)["visc"]
    if dim == 2:
        w = c * (h * (r * r - h * h) / 4.0 - (r**3 - h**3) / 9.0 - (h**3 / 6.0) * np.log(r / h))
    else:
        w = (15.0 / (2.0 * math.pi * h**3)) * (-(r**3) / (2 * h**3) + r * r / (h * h) + h / (2 * r) - 1.0)
    return np.where(r < h, w, 0.0)


def visc_lap_np(r, h, dim):
    r = np.asarray(r, dtype=np.float64)
    return np.where(r < h, constants(h, dim)["visc"] * (h - r), 0.0)


def lattice_density_sum(spacing: float, h: float, dim: int) -> float:
    """Σ_k W_poly6(x_k) over an infinite square lattice of the given spacing.

    The rest mass of a particle is ρ0 divided by this sum, so that a particle inside a
    lattice block starts exactly at the rest density (no start-up jolt).
    """
    n = int(math.ceil(h / spacing)) + 1
    axes = [np.arange(-n, n + 1) * spacing] * dim
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, dim)
    return float(poly6_np(np.linalg.norm(grid, axis=1), h, dim).sum())


def lattice_gradient_factor(spacing: float, h: float, dim: int) -> float:
    """How much of a linear field's gradient the spiky gradient recovers on a lattice.

    SPH estimates ∇f at x_i by Σ_j V_j (f_j − f_i) ∇W(x_i − x_j); for f = x this should be
    the identity. With V_j = m0/ρ0 = 1 / Σ_k W_poly6(x_k) it gives c·I, c = 0.874 in 2D
    and 0.947 in 3D for h = 2s. A pressure force built on it then needs that much more
    pressure to hold a fluid's weight (a hydrostatic pool reads ~14 % high in 2D). The
    solver divides the spiky constant by c: a constant factor, so every pair force stays
    antisymmetric and momentum is still conserved exactly.
    """
    n = int(math.ceil(h / spacing)) + 1
    axes = [np.arange(-n, n + 1) * spacing] * dim
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, dim)
    volume = 1.0 / lattice_density_sum(spacing, h, dim)
    # x_j − x_i = pts, and ∇_i W(x_i − x_j) = spiky_grad_np(−pts)
    grads = spiky_grad_np(-pts, h, dim)
    return float(volume * np.einsum("kd,kd->", pts, grads) / dim)

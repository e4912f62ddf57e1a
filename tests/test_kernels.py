"""SPH smoothing kernels (METHOD.md §1): normalisation, derivatives, support, Taichi twins.

The constants are checked by integration rather than compared with a table: each kernel
must integrate to one in its own dimension, the spiky gradient must be the derivative of
the spiky kernel, and the viscosity Laplacian must be the Laplacian of a kernel that
itself integrates to one. The Taichi functions used by the solver are then checked
against the numpy twins that these tests have vouched for.
"""

import math

import numpy as np
import pytest
from scipy import integrate
from scipy.spatial import cKDTree

from mrsph.sph.kernels import (
    constants,
    lattice_density_sum,
    poly6_np,
    spiky_grad_np,
    spiky_np,
    visc_lap_np,
    viscosity_np,
)

H = 0.7  # an arbitrary support radius: nothing may silently assume h = 1
RHO0 = 1000.0


def sphere_area(r, dim):
    """Measure of the sphere of radius r in dim dimensions (circle length in 2D)."""
    return 2.0 * math.pi * r if dim == 2 else 4.0 * math.pi * r * r


def random_offsets(rng, count, dim, lo, hi, h=H):
    """Vectors in random directions with lengths uniform in [lo h, hi h]."""
    u = rng.normal(size=(count, dim))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u * (rng.uniform(lo, hi, count) * h)[:, None]


# ------------------------------------------------------------------ normalisation
@pytest.mark.parametrize("kernel", [poly6_np, spiky_np, viscosity_np], ids=["poly6", "spiky", "viscosity"])
def test_kernel_integrates_to_one(dim, kernel):
    # Adaptive quadrature of the radial integral ∫_0^h W(r) |S^{d-1}| r^{d-1} dr; the
    # viscosity kernel is singular at r = 0 (log r in 2D, 1/r in 3D) but integrable.
    total, err = integrate.quad(
        lambda r: float(kernel(r, H, dim)) * sphere_area(r, dim), 0.0, H, limit=400, epsabs=1e-12, epsrel=1e-12
    )
    assert err < 1e-8, f"quadrature did not converge (error estimate {err:.2e})"
    # the quadrature is good to ~1e-15; 1e-9 catches a constant written with pi = 3.1416
    assert abs(total - 1.0) <= 1e-9, (
        f"{kernel.__name__} in {dim}D integrates to 1 {total - 1.0:+.3e}; expected 1 within 1e-9"
    )


@pytest.mark.parametrize("kernel", [poly6_np, spiky_np], ids=["poly6", "spiky"])
def test_bounded_kernel_integrates_to_one_on_a_cartesian_grid(dim, kernel):
    # The same normalisation without the radial formula: a midpoint rule on the cube
    # [-h, h]^d (these two kernels are bounded, so the midpoint rule converges fast).
    n = 600 if dim == 2 else 120
    ax = (np.arange(n) + 0.5) / n * 2.0 * H - H
    grids = np.meshgrid(*([ax] * dim), indexing="ij", sparse=True)
    r = np.sqrt(sum(g * g for g in grids))
    total = float(kernel(r, H, dim).sum()) * (2.0 * H / n) ** dim
    assert abs(total - 1.0) <= 1e-3, (
        f"{kernel.__name__} in {dim}D sums to {total:.6f} on a {n}^{dim} grid; expected 1 within 1e-3"
    )


# ------------------------------------------------------------------ derivatives
def test_spiky_gradient_matches_finite_differences(dim):
    rng = np.random.default_rng(11 + dim)
    x = random_offsets(rng, 300, dim, 0.02, 0.98)
    eps = 1e-6 * H
    fd = np.zeros_like(x)
    for k in range(dim):
        e = np.zeros(dim)
        e[k] = eps
        fd[:, k] = (
            spiky_np(np.linalg.norm(x + e, axis=1), H, dim) - spiky_np(np.linalg.norm(x - e, axis=1), H, dim)
        ) / (2.0 * eps)
    grad = spiky_grad_np(x, H, dim)
    rel = np.linalg.norm(grad - fd, axis=1) / np.linalg.norm(fd, axis=1)
    worst = int(np.argmax(rel))
    assert rel[worst] <= 1e-4, (
        f"spiky gradient at |r| = {np.linalg.norm(x[worst]) / H:.3f} h differs from the central "
        f"difference by {rel[worst]:.2e} (relative); expected <= 1e-4"
    )
    # with respect to the first particle, the gradient points from it towards the second
    # (against r = x_i - x_j), since the spiky kernel decreases outwards
    radial = np.einsum("ij,ij->i", grad, x)
    assert (radial < 0).all(), (
        f"spiky gradient must point against r = x_i - x_j (kernel decreasing in r): "
        f"{int((radial >= 0).sum())} of {len(radial)} do not, largest grad . r = {radial.max():.3e} "
        f"at |r| = {np.linalg.norm(x[int(np.argmax(radial))]) / H:.3f} h"
    )


def test_viscosity_laplacian_matches_finite_differences(dim):
    # radial Laplacian of a radial function in d dimensions: W'' + (d - 1) W' / r
    r = np.linspace(0.05, 0.95, 181) * H
    eps = 3e-4 * r
    w = lambda s: viscosity_np(s, H, dim)  # noqa: E731
    d2 = (w(r + eps) - 2.0 * w(r) + w(r - eps)) / eps**2
    d1 = (w(r + eps) - w(r - eps)) / (2.0 * eps)
    lap_fd = d2 + (dim - 1) / r * d1
    lap = visc_lap_np(r, H, dim)
    rel = np.abs(lap_fd - lap) / np.abs(lap)
    worst = int(np.argmax(rel))
    assert rel[worst] <= 1e-4, (
        f"visc_lap_np at r = {r[worst] / H:.3f} h is {lap[worst]:.6g}, the finite-difference "
        f"Laplacian of viscosity_np is {lap_fd[worst]:.6g} (relative {rel[worst]:.2e}; expected <= 1e-4)"
    )


def test_viscosity_laplacian_on_a_cartesian_stencil(dim):
    # The same check without the radial formula: the sum of second differences along the
    # axes at random points in all directions (away from the 1/r or log r core at 0).
    rng = np.random.default_rng(5 + dim)
    x = random_offsets(rng, 200, dim, 0.3, 0.95)
    eps = 1e-4 * H
    norm = lambda y: np.linalg.norm(y, axis=1)  # noqa: E731
    lap_fd = -2.0 * dim * viscosity_np(norm(x), H, dim)
    for k in range(dim):
        e = np.zeros(dim)
        e[k] = eps
        lap_fd = lap_fd + viscosity_np(norm(x + e), H, dim) + viscosity_np(norm(x - e), H, dim)
    lap_fd /= eps * eps
    lap = visc_lap_np(norm(x), H, dim)
    rel = np.abs(lap_fd - lap) / np.abs(lap)
    assert rel.max() <= 1e-3, (
        f"Cartesian Laplacian of viscosity_np differs from visc_lap_np by {rel.max():.2e}; expected <= 1e-3"
    )


# ------------------------------------------------------------------ compact support
def test_kernels_vanish_at_and_beyond_h(dim):
    r = H * np.array([1.0, 1.0 + 1e-12, 1.01, 1.5, 3.0])
    for kernel in (poly6_np, spiky_np, viscosity_np, visc_lap_np):
        values = kernel(r, H, dim)
        assert np.all(values == 0.0), f"{kernel.__name__} at r/h = {r / H} gives {values}; expected 0"
    vec = np.zeros((len(r), dim))
    vec[:, 0] = r
    g = spiky_grad_np(vec, H, dim)
    assert np.all(g == 0.0), f"spiky_grad_np at r/h = {r / H} gives {g}; expected 0"
    # ... and approach zero continuously from inside (no jump at the support edge)
    just_inside = H * (1.0 - 1e-4)
    for kernel in (poly6_np, spiky_np, viscosity_np):
        scale = float(kernel(0.5 * H, H, dim))
        edge = float(kernel(just_inside, H, dim))
        assert abs(edge) <= 1e-6 * abs(scale), (
            f"{kernel.__name__} jumps at r = h: {edge:.3g} just inside (scale {scale:.3g})"
        )


# ------------------------------------------------------------------ Taichi functions
def _taichi_kernel_values(rvecs: np.ndarray, h: float, dim: int):
    """poly6, spiky_grad and visc_lap evaluated by the Taichi functions of mrsph.sph.kernels."""
    import taichi as ti

    from mrsph.sph.kernels import poly6, spiky_grad, visc_lap

    c = constants(h, dim)

    @ti.kernel
    def evaluate(
        r: ti.types.ndarray(),
        w: ti.types.ndarray(),
        grad: ti.types.ndarray(),
        lap: ti.types.ndarray(),
        h: float,
        c6: float,
        cs: float,
        cv: float,
    ):
        for i in range(r.shape[0]):
            rv = ti.Vector([r[i, k] for k in ti.static(range(dim))], dt=float)
            rn = rv.norm()
            w[i] = poly6(rv.norm_sqr(), h * h, c6)
            g = spiky_grad(rv, rn, h, cs)
            for k in ti.static(range(dim)):
                grad[i, k] = g[k]
            lap[i] = visc_lap(rn, h, cv)

    dtype = np.float32 if ti.lang.impl.current_cfg().default_fp == ti.f32 else np.float64
    r = rvecs.astype(dtype)
    w = np.zeros(len(r), dtype)
    grad = np.zeros((len(r), dim), dtype)
    lap = np.zeros(len(r), dtype)
    evaluate(r, w, grad, lap, h, c["poly6"], c["spiky"], c["visc"])
    return r.astype(np.float64), w, grad, lap


def test_taichi_functions_match_numpy_twins(dim, taichi_f32):
    rng = np.random.default_rng(21 + dim)
    rvecs = random_offsets(rng, 500, dim, 0.01, 0.999)
    r, w, grad, lap = _taichi_kernel_values(rvecs, H, dim)
    rn = np.linalg.norm(r, axis=1)
    # f32 arithmetic: compare against the scale of each function (its value at r -> 0),
    # with a bound of a few hundred single-precision ulps
    tol = 2e-5
    w_ref = poly6_np(rn, H, dim)
    err = np.abs(w - w_ref).max() / float(poly6_np(0.0, H, dim))
    assert err <= tol, f"Taichi poly6 differs from poly6_np by {err:.2e} of W(0); expected <= {tol}"
    g_ref = spiky_grad_np(r, H, dim)
    g_scale = 3.0 * constants(H, dim)["spiky"] * H * H
    err = np.abs(grad - g_ref).max() / g_scale
    assert err <= tol, f"Taichi spiky_grad differs from spiky_grad_np by {err:.2e} of |∇W|(0); expected <= {tol}"
    l_ref = visc_lap_np(rn, H, dim)
    err = np.abs(lap - l_ref).max() / (constants(H, dim)["visc"] * H)
    assert err <= tol, f"Taichi visc_lap differs from visc_lap_np by {err:.2e} of ∇²W(0); expected <= {tol}"


def test_taichi_functions_vanish_at_h(dim, taichi_f32):
    # the solver only calls them for r < h; at r = h they must already be zero, so that
    # the cut-off does not make forces jump
    rvecs = np.zeros((dim, dim))
    rvecs[np.arange(dim), np.arange(dim)] = H
    _r, w, grad, lap = _taichi_kernel_values(rvecs, H, dim)
    assert np.all(w == 0.0) and np.all(grad == 0.0) and np.all(lap == 0.0), (
        f"at |r| = h: poly6 {w}, spiky_grad {grad}, visc_lap {lap}; expected all 0"
    )


# ------------------------------------------------------------------ lattice rest mass
@pytest.mark.parametrize("support", [1.5, 2.0, 2.5, 3.7])
def test_lattice_density_sum_gives_rest_density(dim, support):
    spacing = 0.013
    h = support * spacing
    total = lattice_density_sum(spacing, h, dim)
    m0 = RHO0 / total
    # an independent finite block of lattice, large enough to cover the support of its
    # central particle, shifted off the origin; neighbours found by a k-d tree
    n = int(math.ceil(h / spacing)) + 3
    ax = (np.arange(-n, n + 1) + 0.5) * spacing + 0.37
    pts = np.stack(np.meshgrid(*([ax] * dim), indexing="ij"), -1).reshape(-1, dim)
    centre = np.full(dim, 0.5 * spacing + 0.37)
    near = cKDTree(pts).query_ball_point(centre, h * 1.0001)
    r = np.linalg.norm(pts[near] - centre, axis=1)
    rho = math.fsum(m0 * poly6_np(r, h, dim))
    assert abs(rho / RHO0 - 1.0) <= 1e-6, (
        f"lattice particle density {rho:.9g} with m0 = rho0 / lattice_density_sum; expected "
        f"{RHO0} within 1e-6 relative (support {support}, {len(near)} neighbours)"
    )
    # and the sum is not trivially dominated by the self term: at least the nearest shell
    self_share = float(poly6_np(0.0, h, dim)) / total
    assert self_share < 0.9, f"self term is {self_share:.2f} of the lattice sum"

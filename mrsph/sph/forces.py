"""Internal forces (METHOD.md §1, thesis Eq. 16 and 19): for every real particle, the sum
over its same-level neighbours, real or virtual, and over the mirror images of its
neighbourhood at walls and obstacles, of

- the pressure solver's pair term (``pressure/``: for WCSPH −m_i m_j (p_i/ρ_i² + p_j/ρ_j²)
  ∇W_spiky),
- the symmetrised viscosity μ m_i m_j (u_j − u_i)/(ρ_i ρ_j) ∇²W_visc (Eq. 19, times the
  volume m_i/ρ_i),
- Monaghan's artificial viscosity on approaching pairs (``fluid.artificial_viscosity``).

The level coupling (``multires.coupling``) decides which pairs meet (``interacts``) and
takes the reactions of forces from virtual particles (``hand_reaction``). Body forces and
disturbances are accelerations, added by the integrator (``integrator.py``).
"""

import math

import taichi as ti

from .particles import is_real

# Monaghan's artificial viscosity divides by r² + AV_EPS h² so that a pair at (nearly)
# the same position gets a bounded force; 0.01 is Monaghan's value (1992).
AV_EPS = 0.01


def viscous_dt(factor: float, h: float, rest_density: float, mu: float) -> float:
    """The explicit viscosity's largest step, ``factor`` h²ρ0/μ (inf for μ = 0).

    Eq. 19 relaxes a particle's velocity towards its neighbours' at a rate
    μ/ρ Σ_j V_j ∇²W ≈ 15 μ/(ρ h²) (3D; 13.3 in 2D), and the shortest mode, a particle
    against its neighbours, twice as fast; explicit Euler on that mode needs
    dt < h²ρ/(15 μ) ≈ 0.067 h²ρ/μ, so ``physics.viscous_factor`` 0.03 keeps half of it in
    hand (as Morris et al. 1997's 0.125 h²/ν with their h, half our support). At the
    scenes' viscosities it is far above the CFL bound; it binds when the viscosity is
    raised live, which would otherwise blow up."""
    return factor * h**2 * rest_density / mu if mu > 0.0 else math.inf


@ti.data_oriented
class Viscosity:
    """μ, the scene's dynamic viscosity as last set: the force pass reads the field, the
    viscous time-step bound the host's copy (``value``)."""

    live_keys = ("fluid.viscosity",)

    def __init__(self, mu: float):
        self.mu = ti.field(float, shape=())
        self.set_param("fluid.viscosity", mu)

    def set_param(self, key: str, value) -> None:
        self.host = float(value)
        self.mu[None] = self.host

    def value(self) -> float:
        return self.host


@ti.data_oriented
class Forces:
    def __init__(self, core, fluid, coupling, pressure, state, viscosity, gravity, accelerate=None):
        """fluid: the scene's [fluid] params (the artificial viscosity); coupling: which
        pairs meet and where reactions go; pressure: the solver's pair term; state: the
        step's sound speed and whether a disturbance acts (``step.StepState``);
        viscosity: μ (``Viscosity``); gravity: g (the integrator's field); accelerate:
        the integrator, whose per-particle
        accelerations and time-step rates the pass takes in its own loop (a uniform run:
        nothing else adds to a force once a particle's sum is done), or None."""
        self.dim, self.adaptive = core.dim, core.adaptive
        self.pool, self.grids, self.lev, self.nb = core.pool, core.grids, core.lev, core.nb
        self.coupling, self.pressure, self.state, self.viscosity = coupling, pressure, state, viscosity
        self.gravity, self.integrator = gravity, accelerate
        self.fused_accelerations = accelerate is not None
        # alpha c of the artificial viscosity (c the solver's damping speed, which follows k)
        self.av_alpha = fluid.artificial_viscosity
        self.av_cap = float(fluid.artificial_viscosity_cap)  # κ of α c ≤ κ h / dt, 0: none (``av_strength``)
        self.av_coef = ti.field(float, shape=())
        self.update_signal_speed()
        # 1/ρ per particle, set with the density: it takes a division out of every pair
        self.inv_rho = ti.field(float, shape=core.pool.capacity)

    def update_signal_speed(self):
        self.av_coef[None] = self.av_alpha * self.pressure.damping_speed()

    @ti.func
    def av_strength(self, h):
        """α c of the artificial viscosity at support h, capped at κ h / dt where
        ``fluid.artificial_viscosity_cap`` κ > 0: explicit Euler damps the term's fastest
        mode, a particle against its neighbours, at about 5.7 α c / h (2D; 5.3 in 3D), so
        past dt = 0.35 h / (α c) it overshoots. A weakly compressible step, tied to c,
        stays below (κ h / dt ≥ 0.75 c at κ = 0.15); dfsph's, tied to the flow speed, does
        not at rest (docs/validation.md, the deep tank). dt is the last step's, since this
        one's is chosen after the forces; on the first step the step's cap."""
        coef = self.av_coef[None]
        if ti.static(self.av_cap > 0.0):
            dt = ti.cast(self.state.dt[None], float)
            dt = ti.select(dt > 0.0, dt, ti.cast(self.state.cap[None], float))
            coef = ti.min(coef, self.av_cap * h / dt)
        return coef

    @ti.func
    def factors(self, i):
        """The per-particle factors of the pair terms: 1/ρ_i and the pressure solver's."""
        inv = 1.0 / self.pool.p[i].rho
        self.inv_rho[i] = inv
        self.pressure.pair_factor(i, inv)

    @ti.func
    def pair_values(self, i, j, vi, vj, r, rn, h, cs, cv, mu):
        """Force on i from j, times i's volume: the pressure solver's pair term, the
        viscosity (Eq. 19) and the artificial viscosity.

        The artificial viscosity is Monaghan's (1992), F_i = m_i m_j α c h (u_ij·r_ij) /
        (ρ̄_ij (r² + 0.01 h²)) ∇W_spiky for approaching pairs (u_ij·r_ij < 0), ρ̄ the mean
        density. Why: a resting pool's square lattice is not a stable packing under
        pressure (the pair pressure forces push a row sliding along its neighbours
        further), so it rearranges within a second and the energy set free rings on as
        particle-scale motion that the viscosity, μ ∇²u, damps too slowly (in the tank of
        tests/test_physics.py, 0.011–0.028 sqrt(gH) of mean speed at 1.5 s without it,
        0.0002 with α = 0.2). Like the pressure term it is antisymmetric in the pair and
        along r, so momentum is still conserved.

        Written for speed (it runs ~11 times per particle in 2D, ~33 in 3D): p/ρ² and 1/ρ
        come from ``factors``, no branch on the approach (the artificial term is scaled
        by min(u_ij·r_ij, 0)), and one division, 1/(|r| ρ̄ (r² + ε h²)), serves both the
        kernel gradient's 1/|r| and the artificial term.
        """
        p = ti.static(self.pool.p)
        mm = self.coupling.sum_mass(i) * self.coupling.sum_mass(j)
        rho_bar = 0.5 * (p[i].rho + p[j].rho)
        soft = rn * rn + AV_EPS * h * h
        inv = 1.0 / (rn * rho_bar * soft)  # = 1 / (|r| ρ̄ (r² + ε h²))
        d = h - rn
        grad = -3.0 * cs * d * d * (rho_bar * soft * inv)  # ∇W_spiky = grad · r
        approach = ti.min((vi - vj).dot(r), 0.0)
        along = self.pressure.pair_term(i, j, grad) + self.av_strength(h) * h * approach * (-3.0 * cs * d * d * inv)
        visc = mu * cv * d * self.inv_rho[i] * self.inv_rho[j]
        return mm * (along * r + visc * (vj - vi))

    @ti.func
    def pair(self, i, j, r, rn, h, cs, cv, mu):
        p = ti.static(self.pool.p)
        return self.pair_values(i, j, p[i].v, p[j].v, r, rn, h, cs, cv, mu)

    @ti.func
    def _masked(self, ok, i, j, vi, vj, r, r2, h, cs, cv, mu):
        """``pair_values`` where ``ok``, else zero. Branch-free in a uniform run: computed
        for every candidate with |r| kept in (0, h] (finite for any r2, and zero beyond h,
        where h − |r| = 0) and masked, which also drops a pair at r = 0 as the branch
        does; the listed neighbours are all within h, so little is wasted, and which wall
        images are in reach is unpredictable. With a branch in an adaptive run, where
        masking cost more than it saved (docs/performance.md)."""
        f = ti.Vector.zero(float, self.dim)
        if ti.static(self.adaptive):
            if ok:
                f = self.pair_values(i, j, vi, vj, r, ti.sqrt(r2), h, cs, cv, mu)
        else:
            rn = ti.min(ti.sqrt(ti.max(r2, 1e-30)), h)
            f = self.pair_values(i, j, vi, vj, r, rn, h, cs, cv, mu) * ti.cast(ok, float)
        return f

    @ti.func
    def _own_pair(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """Force on real particle i from same-level particle j (zero beyond h, or when the
        pair meets elsewhere, see ``coupling.interacts``); a virtual j hands the reaction
        on to its owners (variational coupling). ctx: h, cs, cv, μ, skip²."""
        p = ti.static(self.pool.p)
        h = ctx[0]
        r = xq - p[j].x
        r2 = r.norm_sqr()
        ok = 0.0 < r2 < h * h and self.coupling.interacts(j, r2, ctx[4])
        f = self._masked(ok, i, j, p[i].v, p[j].v, r, r2, h, ctx[1], ctx[2], ctx[3])
        self.coupling.hand_reaction(j, f)
        acc += f

    @ti.func
    def _image_pair(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """Force on i from the mirror image of j: xq is i's image and L the reflection's
        linear part, so x_i − x_j' = L (xq − x_j) and u_j' = L u_j."""
        p = ti.static(self.pool.p)
        h = ctx[0]
        rq = xq - p[j].x
        r2 = rq.norm_sqr()
        ok = 0.0 < r2 < h * h and self.coupling.interacts(j, r2, ctx[4])
        if ti.static(check):
            if ok:
                ok = self.nb.image_in_solid(p[j].x, p0, nrm)
        acc += self._masked(ok, i, j, p[i].v, L @ p[j].v, L @ rq, r2, h, ctx[1], ctx[2], ctx[3])

    @ti.func
    def _image_force(self, i, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """The force from one image of i's neighbourhood (its own sum): over i and i's
        list for a domain-wall image of a listed particle, else the grid around xq.
        ctx: h, cs, cv, μ, skip², level, listed."""
        listed = ctx[6] != 0.0
        if ti.static(check):
            listed = False  # an obstacle image's neighbours are not i's: the grid
        f = ti.Vector.zero(float, self.dim)
        self.nb.candidates(i, xq, L, p0, nrm, check, ti.cast(ctx[5], ti.i32), listed, True, self._image_pair, ctx, f)
        acc += f

    @ti.kernel
    def run(self, n: ti.i32):
        self.run_func(n)

    @ti.func
    def run_func(self, n):
        """Internal forces on real particles, left in ``a``. With the variational
        coupling the reactions of the virtual neighbours are handed on to their owners in
        the same pass (the symmetric coupling does it after, in its own pass).

        Without adaptivity nothing else adds to a particle's force once its own iteration
        is done, so the same loop turns it into an acceleration and takes the time-step
        limits (``Integrator.accelerate``): one parallel loop fewer a step, each of which
        costs 50-100 µs of thread wake-ups on two cores."""
        p = ti.static(self.pool.p)
        mu = self.viscosity.mu[None]
        mm = self.coupling.sum_scale() * self.coupling.sum_scale()  # m_i m_j, when every pair term left it out
        g = self.gravity[None]
        c_sound, stirred = self.state.c_sound[None], self.state.stirred[None]
        if ti.static(self.fused_accelerations):
            self.integrator.clear_reductions()
        for i in range(n):
            f = ti.Vector.zero(float, self.dim)
            if is_real(p[i].kind):
                l = p[i].level
                h = self.lev.h[l]
                xi = p[i].x
                listed = self.nb.is_listed(i)
                ctx = ti.Vector(
                    [
                        h,
                        self.lev.spiky[l],
                        self.lev.visc[l],
                        mu,
                        self.coupling.skip2(i, l),
                        ti.cast(l, float),
                        ti.cast(listed, float),
                    ]
                )
                eye = ti.Matrix.identity(float, self.dim)
                self.nb.candidates(i, xi, eye, xi, xi, False, l, listed, False, self._own_pair, ctx, f)
                self.nb.images(i, h, self._image_force, ctx, f)
            p[i].a = f * mm
            if ti.static(self.fused_accelerations):
                if is_real(p[i].kind):
                    self.integrator.accelerate_reduce(i, g, c_sound, stirred)

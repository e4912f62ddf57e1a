"""Where the children of a split go (METHOD.md §5.1–5.2): a split puts 2^d children on
the fine lattice of the parent's cell; these passes then move them, positions only (mass
and momentum are untouched), so that they do not start on top of the fine particles
already there (``adaptivity.split_relax``):

- ``fit``: the children of one split, as a block, at least half a fine spacing inside the
  walls and outside the obstacles;
- ``relax`` ("spacing", the default): Jacobi iterations spreading them to
  ``split_min_distance`` fine spacings from their real neighbours, about their group's
  centre of mass, which stays where the parent was;
- ``settle`` ("density"): Jacobi iterations moving each down its level's density
  gradient (walls and obstacles as mirror images) until it reads no more than its
  parent's density plus ``split_density_tolerance``.

The children of this pass's splits are listed in ``fresh`` (a few dozen at most a pass),
so these loops run serially over that list.
"""

import taichi as ti

from mrsph.sph.particles import DEAD, is_real

FRESH = 32  # scratch flag of a real child made by a split in this pass (one of topology's)

# The longest move of a new child in one iteration of ``_settle_fresh``, in fine spacings:
# a Newton step on a density that is not linear over a spacing overshoots. Measured on the
# first splits of the two-level dam break (docs/validation.md, "The first splits of a dam
# break"): at 0.1 the energy rose by 1.2 % in 2D and 0.25 % in 3D, at 0.25 by 0.2 % and not
# at all.
SETTLE_STEP = 0.25


@ti.data_oriented
class Placement:
    def __init__(self, core, adaptivity):
        a = adaptivity
        self.dim, self.nmax = core.dim, 2**core.dim
        self.pool, self.g, self.lev, self.nb = core.pool, core.grids, core.lev, core.nb
        self.boundary = core.boundary
        self.rest_density = core.lev.rest_density
        self.relax_iterations = a.split_relax_iterations
        self.relax_distance = a.split_min_distance
        self.settle_tolerance = a.split_density_tolerance
        self.fresh = ti.field(ti.i32, shape=self.pool.capacity)  # children split this pass
        self.n_fresh = ti.field(ti.i32, shape=())

    @ti.func
    def relax(self, c):
        """``adaptivity.split_relax = "spacing"``: ``split_relax_iterations`` Jacobi
        iterations spreading the children made by this pass's splits (listed in ``fresh`` by the split): each
        is pushed away from every real level-f particle closer than ``split_min_distance``
        fine spacings, by the whole overlap from an older particle and half of it from
        another new one (which moves too), then kept half a fine spacing inside the walls
        and outside the obstacles (as ``fit``). The displacement is kept in ``a``
        (not in use during the adaptivity pass). A few dozen children at most per pass, so
        the loops run serially over the list: cheaper than a parallel loop over the pool
        per iteration.

        Why: a split puts 2^d children on the fine lattice of the parent's cell, but coarse
        particles are often closer than their spacing (in a thin sheet the coarse density
        is below rho0 and its pressure clamped, so nothing keeps them apart), and the
        children then land on top of the fine particles of a neighbour split earlier.
        Measured in the 2D dam break of tests/test_adaptive_flow.py: fine density +20 %,
        children thrown off at 5.9 m/s in a 2.4 m/s front. Moving positions keeps mass and
        momentum (velocities are untouched).

        Each iteration takes from the children's moves their group's mean
        (``_keep_centre``), so that a group is spread about its centre of mass and not
        moved: the split particle, now the group's virtual parent, stands for it at the
        coarse level where it stood. A transient parent's children are pushed away from
        the fine particles beside it, all one way; moved as a group, the virtual parent
        followed them at the step's end (``coupling.advect``), and the coarse particles on
        that side took the mass it brought for a compression. demo_2d under a cursor
        dragged at 2 m/s: a parent moved 7 mm, a quarter of its spacing, its coarse
        neighbours went from rho0 to 1.03-1.08 rho0 in one step, and the density solve
        (dfsph) threw its four children at 2.6 m/s; the pool's kinetic energy peaked at
        45 J, 24 J with the centre kept (docs/performance.md, "A cursor dragged through
        resting water"). ``fit`` still moves a group off a wall, and the walls' margin
        may move a child after the mean is taken.

        New children of a *regular* parent are not in the grid yet (claimed past the sorted
        range), so they push only against sorted particles; a regular parent has no real
        fine particle within its support, so they rarely overlap any."""
        p = ti.static(self.pool.p)
        f = c - 1
        dmin = self.relax_distance * self.lev.s[f]
        margin = 0.5 * self.lev.s[f]
        ti.loop_config(serialize=True)
        for _ in range(self.relax_iterations):
            for q in range(self.n_fresh[None]):
                i = self.fresh[q]
                xi = p[i].x
                push = ti.Vector.zero(float, self.dim)
                base = self.g.around(xi, f)
                for o in ti.grouped(ti.ndrange(*self.g.row_axes)):
                    lo, hi = self.g.row(base, o, f)
                    for j in range(lo, hi):
                        if j != i and is_real(p[j].kind) and p[j].level == f:
                            r = xi - p[j].x
                            rn = r.norm()
                            if rn < dmin:
                                share = 0.5 if (p[j].flags & FRESH) != 0 else 1.0
                                push += share * (dmin - rn) * r / ti.max(rn, 1e-6 * dmin)
                p[i].a = push
            self._keep_centre()
            self._move_fresh(margin)

    @ti.func
    def _keep_centre(self):
        """Take from each new child's displacement (in ``a``) its group's mean, so that the
        iteration spreads the group about its centre of mass and does not move it: the
        group's virtual parent (the split particle) stays where the coarse level saw it.
        The parent's ``a`` (not in use during the adaptivity pass) holds the mean."""
        p = ti.static(self.pool.p)
        for q in range(self.n_fresh[None]):
            p[p[self.fresh[q]].parent].a = ti.Vector.zero(float, self.dim)
        for q in range(self.n_fresh[None]):
            i = self.fresh[q]
            vp = p[i].parent
            p[vp].a += p[i].a / ti.max(p[vp].nchild, 1)
        for q in range(self.n_fresh[None]):
            i = self.fresh[q]
            p[i].a -= p[p[i].parent].a

    @ti.func
    def _move_fresh(self, margin):
        """Move each new child by the displacement its relaxation left in ``a`` (not in use
        during the adaptivity pass), then keep it ``margin`` inside the walls and outside
        the obstacles (as ``fit``)."""
        p = ti.static(self.pool.p)
        b = self.boundary
        for q in range(self.n_fresh[None]):
            i = self.fresh[q]
            x = p[i].x + p[i].a
            p[i].a = ti.Vector.zero(float, self.dim)
            for k in ti.static(range(self.dim)):
                x[k] = ti.min(ti.max(x[k], b.lo[k] + margin), b.hi[k] - margin)
            phi, nrm = b.obstacle_sdf(x)
            if phi < margin:
                x += (margin - phi) * nrm
            p[i].x = x

    @ti.func
    def _fresh_density(self, xq, f, h2, c6, p0, nrm, check: ti.template()):
        """(ρ, ∇ρ) of level f at xq, Σ m_j W_poly6 over every live level-f particle, real
        or virtual: those in the grid but this pass's new children, and the new children
        from their list (children of a regular parent are not in the grid yet). ``check``:
        xq is an obstacle image, and only the particles whose own image lies inside the
        obstacle count (``Neighbours.image_in_solid``)."""
        p = ti.static(self.pool.p)
        rho = 0.0
        grad = ti.Vector.zero(float, self.dim)
        base = self.g.around(xq, f)
        for o in ti.grouped(ti.ndrange(*self.g.row_axes)):
            lo, hi = self.g.row(base, o, f)
            for j in range(lo, hi):
                if p[j].kind != DEAD and p[j].level == f and (p[j].flags & FRESH) == 0:
                    w, dw = self._poly6_and_grad(xq, j, h2, p0, nrm, check)
                    rho += w
                    grad += dw
        for q in range(self.n_fresh[None]):
            w, dw = self._poly6_and_grad(xq, self.fresh[q], h2, p0, nrm, check)
            rho += w
            grad += dw
        return rho * c6, grad * c6

    @ti.func
    def _poly6_and_grad(self, xq, j, h2, p0, nrm, check: ti.template()):
        """m_j (h² − r²)³ and its gradient with respect to xq (without the constant)."""
        p = ti.static(self.pool.p)
        r = xq - p[j].x
        r2 = r.norm_sqr()
        ok = r2 < h2
        if ti.static(check):
            if ok:
                ok = self.nb.image_in_solid(p[j].x, p0, nrm)
        w = 0.0
        dw = ti.Vector.zero(float, self.dim)
        if ok:
            d = h2 - r2
            w = p[j].m * d * d * d
            dw = (-6.0 * p[j].m * d * d) * r
        return w, dw

    @ti.func
    def settle(self, c):
        """``adaptivity.split_relax = "density"``: ``split_relax_iterations``
        Jacobi iterations moving each child made by this pass's splits down the gradient
        of its level's density, walls and obstacles counted as mirror images as in the
        density pass, until it reads no more than its parent's density (ρ0 at least): a
        Newton step ``−(ρ − ρ_t) ∇ρ / |∇ρ|²``, at most ``SETTLE_STEP`` fine spacings per
        iteration, then kept half a fine spacing inside the walls and outside the
        obstacles (as ``fit``). Velocities are untouched, so mass and momentum
        are kept; positions only move where the children would start compressed beyond
        what their parent was.

        Why: the children of a split land on the fine lattice of their parent's cell, but
        a coarse particle in a thin sheet sits closer to its neighbours than its spacing
        (its density, short of neighbours above, reaches ρ0 only when compressed, and
        below ρ0 the clamped pressure keeps nothing apart), so its children start on top
        of each other's and their neighbours' and their pressure throws them off: the
        split injected energy where METHOD.md §5 wants the flow undisturbed. Measured
        with two levels (1 and 2 cm) in the dam break of tests/test_adaptive_flow.py,
        refined within 0.1 m of the block, across the first splits (docs/validation.md,
        "The first splits of a dam break"): with ``"spacing"`` the fluid's mechanical energy rose by
        2.7 % (2D) and 4.2 % (3D) and particles left at 5.3 and 7.2 m/s from a 2.9 m/s
        sheet; with ``"density"`` by 0.2 % and not at all. The thrown fluid flattened
        the jet off the block (2D: 45-50° against the uniform runs' 70-78°; 68-74° with
        ``"density"`` at tolerance 0) and took the 3D front at 1 s to 16-24 % ahead of
        the uniform run's; with ``"density"`` +1.1..+4.7 % (seven CFL numbers).
        ``test_first_splits_add_no_energy`` holds the energy.

        Why it is not the default: with three levels (1, 2 and 4 cm, the same dam break)
        the first splits, 4 to 2 cm, raised the energy by 5.5 % in 2D and 2.3 % in 3D
        with it, against -0.2 % and +1.7 % with "spacing", and the 3D front at 1 s read
        -1.0..+48.9 % over seven CFL numbers (+2.0..+3.8 % with "spacing"). A step of
        0.1 spacings (``SETTLE_STEP``) brought those splits to +0.7 and +1.1 % but the
        two-level ones from +0.2 to +1.2 % in 2D; not explained yet.

        Why the parent's density as the target: in the bulk of the fluid, compressed by
        its own weight, ρ0 cannot be reached by moving one particle, and a gradient near
        zero would send the children across the cell; the parent's density is what the
        children of a lattice cell read there, so they stay put. Why a tolerance above it
        (``split_density_tolerance``, 1 %): with none, the children of the splits in a
        resting pool moved too (the fine sum at a lattice site is not exactly the coarse
        one), and the refined pool of tests/test_adaptive_flow.py moved at 0.0069-0.0079
        sqrt(gH) after 2 s in 2D (0.0032-0.0063 with "spacing", three viscosities); at
        1 % 0.0025-0.0070, at 2 % 0.0020-0.0043. In return the tolerance lets that much
        compression through: the 3D dam-break front above reads +1.0 % on average at 0,
        +2.6 % (up to +4.7 %) at 1 %, +6.0 % (up to +12.3 %) at 2 %."""
        p = ti.static(self.pool.p)
        b = self.boundary
        f = c - 1
        h = self.lev.h[f]
        h2 = h * h
        c6 = self.lev.poly6[f]
        s_f = self.lev.s[f]
        margin = 0.5 * s_f
        ti.loop_config(serialize=True)
        for _ in range(self.relax_iterations):
            for q in range(self.n_fresh[None]):
                i = self.fresh[q]
                xi = p[i].x
                zero = ti.Vector.zero(float, self.dim)
                rho, grad = self._fresh_density(xi, f, h2, c6, zero, zero, False)
                for mask in range(1, 2**self.dim):
                    ok, xr, sgn = b.domain_image(xi, h, mask)
                    if ok:  # d(x_image)/dx_i = diag(sgn)
                        r_img, g_img = self._fresh_density(xr, f, h2, c6, zero, zero, False)
                        rho += r_img
                        for k in ti.static(range(self.dim)):
                            grad[k] += sgn[k] * g_img[k]
                ok, xo, nrm = b.obstacle_image(xi, h)
                if ok:  # with the corner's images, as Neighbours.images visits them
                    p0 = 0.5 * (xi + xo)
                    for mask in range(2**self.dim):
                        okc, xq, sgn = b.corner_image(xi, h, mask, p0, nrm)
                        if okc:  # d(x_image)/dx_i = diag(sgn) (I − 2 n nᵀ), the two commuting
                            r_img, g_img = self._fresh_density(xq, f, h2, c6, p0, nrm, True)
                            rho += r_img
                            g_img *= sgn
                            grad += g_img - 2.0 * nrm.dot(g_img) * nrm
                target = ti.cast(ti.static(self.rest_density), float)
                vp = p[i].parent
                if vp >= 0:
                    target = ti.max(target, p[vp].rho)
                step = ti.Vector.zero(float, self.dim)
                g2 = grad.norm_sqr()
                target *= ti.static(1.0 + self.settle_tolerance)
                if rho > target and g2 > 0.0:
                    step = -(rho - target) / g2 * grad
                    most = SETTLE_STEP * s_f
                    length = step.norm()
                    if length > most:
                        step *= most / length
                p[i].a = step
            self._move_fresh(margin)

    @ti.func
    def fit(self, i, s_f):
        """Shift the children of a split, as one block, so that each lies at least half a
        child spacing inside the fluid, as a lattice seeded against a wall does.

        A coarse particle can sit closer to a wall than half a fine spacing (collisions
        put particles on the wall); its children at ±s_f/2 would then start inside the
        solid or on top of their own mirror images, and the density spike threw them off
        at 3–4 times the flow speed (measured: 9.8 m/s in a 2.8 m/s dam-break front, at
        the first splits near the obstacle). Moving the block keeps the lattice; mass and
        velocities are untouched."""
        p = ti.static(self.pool.p)
        b = self.boundary
        margin = 0.5 * s_f
        shift = ti.Vector.zero(float, self.dim)
        for k in ti.static(range(self.dim)):
            below, above = 0.0, 0.0
            for q in range(self.nmax):
                xk = p[self.pool.children[i, q]].x[k]
                below = ti.max(below, b.lo[k] + margin - xk)
                above = ti.max(above, xk - (b.hi[k] - margin))
            shift[k] = below - above
        need = 0.0
        normal = ti.Vector.zero(float, self.dim)
        for q in range(self.nmax):
            phi, nq = b.obstacle_sdf(p[self.pool.children[i, q]].x + shift)
            if margin - phi > need:
                need = margin - phi
                normal = nq
        shift += need * normal
        for q in range(self.nmax):
            p[self.pool.children[i, q]].x += shift

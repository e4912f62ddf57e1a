"""The pair gradients that the implicit solvers' sums share (``dfsph``, ``pbf``): ∇_i W of
a neighbour or of a mirror image, with a particle on the wall itself handled, and the
factor sums of a particle's response to its own multiplier.

Both solvers push a particle i with Σ_j m_j (k_i + k_j) ∇W_ij over its own level (virtual
particles included) and the mirror images of its neighbourhood at walls and obstacles,
and both need the response of i's own error to its own k_i, the denominator

    D_i = |Σ_j m_j ∇W_ij|² + m_i Σ_j m_j |∇W_ij|²,

the first term the motion of i itself, the second the reaction it hands each neighbour
(the paper's Σ_j |m_j ∇W_ij|² holds for equal masses only, and partial merges leave one
level with masses 8x apart).
"""

import taichi as ti


@ti.data_oriented
class PairGradients:
    def __init__(self, core, coupling, calibrated: bool = True):
        """calibrated: the spiky constant divided by the lattice calibration
        (``kernels.lattice_gradient_factor``), exact for a linear field on the rest
        lattice; else the kernel's own, for particles that do not stay on one."""
        self.dim, self.pool, self.lev, self.nb, self.coupling = core.dim, core.pool, core.lev, core.nb, coupling
        self.scale = 1.0 if calibrated else core.lev.grad_factor

    @ti.func
    def ctx(self, i):
        """(level, h, the visits' context: h, the level's spiky constant, i's skip²)."""
        p = ti.static(self.pool.p)
        l = p[i].level
        spiky = self.lev.spiky[l]
        if ti.static(self.scale != 1.0):
            spiky *= self.scale
        return l, self.lev.h[l], ti.Vector([self.lev.h[l], spiky, self.coupling.skip2(i, l)])

    @ti.func
    def grad(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template()):
        """(does j count, ∇_i W(x_i − x_j')) for candidate j of xq (x_i or an image of it,
        x_i − x_j' = L (xq − x_j)); ctx: h, the level's spiky constant, i's skip²."""
        p = ti.static(self.pool.p)
        h = ctx[0]
        rq = xq - p[j].x
        r2 = rq.norm_sqr()
        ok = 0.0 < r2 < h * h and self.coupling.interacts(j, r2, ctx[2])
        if ti.static(check):
            if ok:
                ok = self.nb.image_in_solid(p[j].x, p0, nrm)
        g = ti.Vector.zero(float, self.dim)
        if ok:
            rn = ti.sqrt(r2)
            d = h - rn
            g = (-3.0 * ctx[1] * d * d / rn) * (L @ rq)
        elif j == i and r2 == 0.0 and L.trace() < self.dim - 1.0:
            # i on the wall itself (the collision put it there): its mirror image sits on
            # it, and the gradient's limit, 3 c h² along the wall's normal, lets the solve
            # push it back into the fluid (left out, the solve pushed its neighbours without
            # bound: the 2D dam break blew up in a corner at 0.4 s). Images only (trace
            # L <= d - 2): an overflowed list's grid block holds i itself at L = I.
            ok = True
            g = (-3.0 * ctx[1] * h * h) * self.nb.image_normal(p[i].x, L, nrm, check)
        return ok, g

    @ti.func
    def add_factor(self, i, j, mg, g, acc: ti.template()):
        """j's part of i's factor sums (acc: Σ m_j ∇W_ij, then the reaction term)."""
        if j == i:
            # i's own mirror image moves with i (u_i' = L u_i), so it counts twice in
            # i's response, (I − L)ᵀ ∇W = 2 ∇W along the wall's normal, and is no
            # other particle to be pushed; counted once, as a neighbour, the factor
            # was half what a particle at a wall needs and it blew up on impact
            for k in ti.static(range(self.dim)):
                acc[k] += 2.0 * mg[k]
        else:
            for k in ti.static(range(self.dim)):
                acc[k] += mg[k]
            acc[self.dim] += self.reaction_term(i, mg, g)

    @ti.func
    def reaction_term(self, i, mg, g):
        """m_i m_j |∇W_ij|²: i's own multiplier acting back on its error through the reaction
        it hands neighbour j."""
        return self.pool.p[i].m * mg.dot(g)

    @ti.func
    def factor_pair(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """A visit (``Neighbours``) adding j's part of i's factor sums."""
        ok, g = self.grad(i, j, xq, L, p0, nrm, check, ctx)
        if ok:
            self.add_factor(i, j, self.pool.p[j].m * g, g, acc)

    @ti.func
    def denominator(self, acc: ti.template()):
        """D_i from the factor sums (``add_factor``)."""
        s = ti.Vector([acc[k] for k in ti.static(range(self.dim))])
        return s.norm_sqr() + acc[self.dim]

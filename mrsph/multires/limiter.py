"""The virtual-mass limiter (``adaptivity.limit_virtual_density``): each step, scale each
virtual child's mass so that no real particle's density is pushed past its target by
virtual children (METHOD.md §3: virtual masses are not part of the fluid's mass).

s_i in [0, 1], for a real particle i below the coarsest level, is the largest share of
their nominal masses that the virtual children around i may carry so that
ρ_i = R_i + s_i V_i stays at or below the target ρ_t (R_i: from the other particles of the
level, V_i: from the virtual children at nominal mass). ρ_t is the largest of (1 + τ)
times the mean density of the parents of those virtual children, weighted as in V_i
(τ = ``adaptivity.virtual_density_tolerance``); i's own density of the last step, so that
a fine particle compressed by its real neighbours keeps its virtual ones; and ρ0, below
which the pressure is clamped and no force comes of the virtual mass. With
``adaptivity.split_fade`` the densities are those the pressure reads (``SplitFade.seen``)
and ρ_t is raised by i's own offset, so that the virtual mass may bring i's pressure to
the target and no further (read raw, a coarse parent's offset went into its fine
neighbours' pressure: ``fade.py``). Each real particle
hands s_i to the virtual children it lists (a virtual child keeps the least), and a
virtual child's mass is 2^-d of its parent's times that share.

Why: virtual children sit on a fixed lattice around their parents, but coarse particles
are often closer than their spacing (in a thin sheet the coarse density is below ρ0 and
its pressure clamped to 0, so nothing keeps them apart); their lattices then overlap each
other and the real fine particles already there, and the fine particles beside them were
thrown off at twice the front's speed. A force on a virtual child still goes to its
parent, so mass and momentum are kept. Why the tolerance and the floor: with ρ_t the
parents' density alone the limiter ratchets in a resting pool (a cut virtual mass lowers
the fine pressure beside it, fine particles move in, which cuts more), and it would cut in
a sheet where the fine density is below ρ0 and no pressure comes of it anyway. The target
must not be i's own density times (1 + τ): that lets it grow by τ each step
(docs/METHOD.md §12).
"""

import taichi as ti

from mrsph.sph.kernels import poly6
from mrsph.sph.particles import VIRTUAL_CHILD, is_real


@ti.data_oriented
class VirtualMassLimiter:
    def __init__(self, core, adaptivity, fade):
        self.dim, self.levels = core.dim, core.levels
        self.pool, self.grids, self.lev, self.nb = core.pool, core.grids, core.lev, core.nb
        self.fade = fade  # densities as the pressure reads them (fade.py)
        self.rest_density = core.lev.rest_density
        self.tolerance = adaptivity.virtual_density_tolerance
        # per slot, for one step: the least share a virtual child got; 1 between calls
        self.virtual_share = ti.field(float, shape=core.pool.capacity)
        self.virtual_share.fill(1.0)

    @ti.func
    def _share_term(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """Particle j's part of (Σ m_j W over the level's particles other than virtual
        children, Σ m̂_j W over its virtual children with m̂_j = 2^-d of the parent's mass,
        Σ m̂_j W ρ_parent) at xq. ctx: h², poly6 constant."""
        p = ti.static(self.pool.p)
        h2, c6 = ctx[0], ctx[1]
        r2 = (xq - p[j].x).norm_sqr()
        if r2 < h2:
            ok = True
            if ti.static(check):
                ok = self.nb.image_in_solid(p[j].x, p0, nrm)
            if ok:
                w = poly6(r2, h2, c6)
                if p[j].kind == VIRTUAL_CHILD:
                    par = p[j].parent
                    wv = p[par].m / ti.static(2**self.dim) * w
                    acc += ti.Vector([0.0, wv, wv * self.fade.seen(par)])
                else:
                    acc += ti.Vector([p[j].m * w, 0.0, 0.0])

    @ti.func
    def _image_shares(self, i, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """One image's share sums (its own sum): i and i's list for a domain-wall image of
        a listed particle, else the grid. ctx: h², poly6 constant, level, listed."""
        listed = ctx[3] != 0.0
        if ti.static(check):
            listed = False
        sub = ti.Vector.zero(float, 3)
        self.nb.candidates(i, xq, L, p0, nrm, check, ti.cast(ctx[2], ti.i32), listed, True, self._share_term, ctx, sub)
        acc += sub

    @ti.func
    def _fine_real(self, i):
        return is_real(self.pool.p[i].kind) and self.pool.p[i].level < ti.static(self.levels - 1)

    @ti.kernel
    def limit(self, n: ti.i32):
        self.limit_func(n)

    @ti.func
    def limit_func(self, n):
        """Set this step's virtual-child masses (see the module's docstring), reading the
        neighbour lists of ``Density.list_fine`` (the grid where a list overflowed, and
        for obstacle images)."""
        p = ti.static(self.pool.p)
        # virtual_share is 1 everywhere between calls (filled at the start, put back by
        # the last loop), which saves a loop that set it
        for i in range(n):
            if self._fine_real(i):
                l = p[i].level
                h = self.lev.h[l]
                h2 = h * h
                xi = p[i].x
                listed = self.nb.is_listed(i)
                ctx = ti.Vector([h2, self.lev.poly6[l], ti.cast(l, float), ti.cast(listed, float)])
                acc = ti.Vector.zero(float, 3)
                eye = ti.Matrix.identity(float, self.dim)
                self.nb.candidates(i, xi, eye, xi, xi, False, l, listed, True, self._share_term, ctx, acc)
                self.nb.images(i, h, self._image_shares, ctx, acc)
                if acc[1] > 0.0:
                    target = self.fade.excess(i) + ti.max(
                        acc[2] / acc[1] * ti.static(1.0 + self.tolerance),
                        self.fade.seen(i),
                        ti.static(self.rest_density),
                    )
                    share = ti.min(ti.max((target - acc[0]) / acc[1], 0.0), 1.0)
                    if share < 1.0:
                        if listed:
                            for q in range(self.nb.count[i]):
                                j = self.nb.lists[i, q]
                                if p[j].kind == VIRTUAL_CHILD:
                                    ti.atomic_min(self.virtual_share[j], share)
                        else:
                            base = self.grids.around(xi, l)
                            for o in ti.grouped(ti.ndrange(*self.grids.row_axes)):
                                lo, hi = self.grids.row(base, o, l)
                                for j in range(lo, hi):
                                    if p[j].kind == VIRTUAL_CHILD and (xi - p[j].x).norm_sqr() < h2:
                                        ti.atomic_min(self.virtual_share[j], share)
        for j in range(n):
            if p[j].kind == VIRTUAL_CHILD:
                p[j].m = self.virtual_share[j] * p[p[j].parent].m / ti.static(2**self.dim)
            self.virtual_share[j] = 1.0

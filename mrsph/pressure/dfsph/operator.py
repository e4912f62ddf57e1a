"""The two halves of the system both DFSPH solves iterate on, summed over the pairs the
factor pass keeps (``pairs.py``): the density rate of a velocity field,

    Σ_j m_j (v_i − v_j')·∇W_ij,

and the velocity change per unit time of a pressure κ = p/ρ,

    −Σ_j m_j (κ_i/ρ_i + κ'_j/ρ_j) ∇W_ij,

with the walls and obstacles as mirror images (x_i − x_j' = L(xq − x_j), v_j' = L v_j,
κ_j' = κ_j) and the level coupling: each level's sums include its virtual particles,
whose κ is their partner pressure (0 with the variational coupling), whose velocities
follow their owners', and whose reaction is handed back to the real particles they
stand for (its transpose, ``coupling.hand_on``). The Jacobi sweeps (``jacobi.py``) apply the one to the
particles' velocities; the Krylov solves (``krylov.py``) also to a field of velocity
changes, hence the velocity field as an argument.
"""

import taichi as ti

from mrsph.sph.neighbours import ImageNeighbours
from mrsph.sph.particles import is_real, is_virtual


@ti.data_oriented
class RateVisit:
    """The rate's visit of a candidate or an image's candidates, m_j (v_i − L v_j)·∇W_ij,
    for a particle whose list overflowed or whose image pairs did not fit, v the field
    ``vel`` (the particles' velocities, or the Krylov solves' velocity changes)."""

    def __init__(self, nb, pairs, vel):
        self.pool, self.pairs, self.vel = nb.pool, pairs, vel
        self.images = ImageNeighbours(nb, self.pair)

    @ti.func
    def pair(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        ok, g = self.pairs.grad(i, j, xq, L, p0, nrm, check, ctx)
        if ok:
            acc += self.pool.p[j].m * (self.vel[i] - L @ self.vel[j]).dot(g)


@ti.data_oriented
class Operator:
    def __init__(self, core, coupling, pairs, kept):
        """pairs: the pair gradients (``gradients.PairGradients``); kept: what the factor
        pass keeps of each particle's pairs (``pairs.StoredPairs``)."""
        self.dim, self.adaptive = core.dim, core.adaptive
        self.pool, self.nb, self.coupling = core.pool, core.nb, coupling
        self.pairs, self.kept = pairs, kept
        self.kappa = ti.field(float, shape=core.pool.capacity)  # the κ ``update_into`` applies
        self.rate_visit = RateVisit(self.nb, pairs, core.pool.p.v)
        self._push_images = ImageNeighbours(self.nb, self._push_image)

    def visit_of(self, vel) -> RateVisit:
        """A ``RateVisit`` of another velocity field (built before the first kernel)."""
        return RateVisit(self.nb, self.pairs, vel)

    # ------------------------------------------------------------------ the rate
    @ti.func
    def rate(self, i):
        """Σ_j m_j (u_i − u_j')·∇W_ij over i's neighbourhood, u the particles' velocities."""
        return self.rate_of(i, self.rate_visit)

    @ti.func
    def rate_of(self, i, visit: ti.template()):
        """Σ_j m_j (v_i − L v_j)·∇W_ij over i's neighbourhood, v the velocity field of
        ``visit``: the listed neighbours from ``kept``, an overflowed list or images that
        did not fit on the fly."""
        p = ti.static(self.pool.p)
        vel = ti.static(visit.vel)
        l, h, ctx = self.pairs.ctx(i)
        rate = 0.0
        if self.nb.is_listed(i):
            vi = vel[i]
            for q in range(self.nb.count[i]):
                rate += (vi - vel[self.nb.lists[i, q]]).dot(self.kept.gw[i, q])
        else:
            self.nb.grid_candidates(
                i, p[i].x, ti.Matrix.identity(float, self.dim), p[i].x, p[i].x, False, l, visit.pair, ctx, rate
            )
        if self.kept.images_kept(i):
            rate = self.kept.image_rate(i, rate, vel)
        else:
            self.nb.images(i, h, visit.images.visit, ctx, rate)
        return rate

    # ------------------------------------------------------------------ the push
    @ti.func
    def _push_all(self, i):
        """Σ_j m_j (κ_i/ρ_i + κ'_j/ρ_j) ∇W_ij over i's neighbourhood (listed neighbours from
        ``kept``), the reactions of virtual neighbours handed on."""
        p = ti.static(self.pool.p)
        l, h, ctx = self.pairs.ctx(i)
        acc = ti.Vector.zero(float, self.dim)
        ki = self.kappa[i] / p[i].rho
        if self.nb.is_listed(i):
            mi = p[i].m
            for q in range(self.nb.count[i]):
                j = self.nb.lists[i, q]
                f = (ki + self._shown(j)) * self.kept.gw[i, q]
                acc += f
                self.coupling.hand_reaction(j, -mi * f)
        else:
            self.nb.grid_candidates(
                i, p[i].x, ti.Matrix.identity(float, self.dim), p[i].x, p[i].x, False, l, self._push_own, ctx, acc
            )
        if self.kept.images_kept(i):
            for k in range(self.kept.img_n[i]):  # the walls are external: nothing handed on
                acc += (ki + self._shown(self.kept.img_j[i, k])) * self.kept.img_g[i, k]
        else:
            self.nb.images(i, h, self._push_images.visit, ctx, acc)
        return acc

    @ti.func
    def _shown(self, j):
        """κ'_j/ρ_j, κ'_j the pressure j shows its neighbours (the coupling's)."""
        return self.coupling.partner_pressure(self.pool.p[j].kind, self.kappa[j]) / self.pool.p[j].rho

    @ti.func
    def _push(self, i, j, g):
        """m_j (κ_i/ρ_i + κ'_j/ρ_j) ∇W_ij."""
        p = ti.static(self.pool.p)
        return p[j].m * (self.kappa[i] / p[i].rho + self._shown(j)) * g

    @ti.func
    def _push_own(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """Own-level neighbour: its part of the velocity change, and the reaction of a
        virtual j handed to its owners (as a force, m_i times the velocity change)."""
        ok, g = self.pairs.grad(i, j, xq, L, p0, nrm, check, ctx)
        if ok:
            f = self._push(i, j, g)
            acc += f
            self.coupling.hand_reaction(j, -self.pool.p[i].m * f)

    @ti.func
    def _push_image(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """A mirror image: the wall is external, nothing is handed on."""
        ok, g = self.pairs.grad(i, j, xq, L, p0, nrm, check, ctx)
        if ok:
            acc += self._push(i, j, g)

    @ti.func
    def update_into(self, n, scale, vel: ti.template(), go):
        """vel_i −= scale Σ_j m_j (κ_i/ρ_i + κ'_j/ρ_j) ∇W_ij for every real i, then the
        reactions handed to the owners of virtual neighbours, then the virtual particles'
        ``vel`` from their owners: vel += scale × the velocity change per unit time of κ.
        Three loops (adaptive) or one; none where ``go`` is 0."""
        p = ti.static(self.pool.p)
        for i in range(n):
            if go and is_real(p[i].kind):
                vel[i] -= scale * self._push_all(i)
        if ti.static(self.adaptive):
            for i in range(n):
                if go and is_real(p[i].kind):
                    r = self.coupling.take_reaction(i, ti.Vector.zero(float, self.dim))
                    vel[i] += scale * r / p[i].m
            for j in range(n):
                if go and is_virtual(p[j].kind):
                    self.coupling.follow_owners(j, vel)

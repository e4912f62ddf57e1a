"""Density (METHOD.md §1, thesis Eq. 7): ρ_i = Σ_j m_j W_poly6(x_i − x_j, h_l) over the
particle's own level, itself and its virtual neighbours included, the domain walls and
obstacles as mirror images (``boundary.py``).

The pass also writes each particle's neighbour list (``neighbours.py``): it is the one
scan of the grid a step makes for the whole pool. Particles go ``DENSITY_CLUSTER`` at a
time through one walk of their block's rows where they share a column of cells
(``_scan_cluster``), else one by one. When the density is known the pressure solver takes
it (``density_done``) and the pair factors are set (``forces.Forces.factors``).

With a skin (``particles.skin``) the scan builds each particle's skin list instead
(everything within (1 + skin) h), and only on the steps the sort says so
(``LevelGrids.building``); every step sums the density over the skin list, writing the
step's list (within h) as it goes, so that every later pass reads the same lists as
without a skin.
"""

import taichi as ti

from .kernels import poly6
from .particles import is_real

# Density loop without a branch per candidate, in both dimensions: once the fluid flows,
# which candidates are neighbours is unpredictable and the mispredictions cost more than
# computing W for every candidate (measurements: docs/performance.md, "The levers").
BRANCH_FREE = True

# The density pass takes particles DENSITY_CLUSTER at a time: consecutive particles of a
# column of cells share their block's rows, so one walk of those rows (over the union of
# their spans) serves them all, each candidate loaded once and its distance to each of
# them computed side by side (``_scan_cluster``). The row set-up, the loop-exit
# mispredictions and the loads are shared, and the K distances vectorise. K was chosen
# by timing the pass (docs/performance.md, "The levers" and "Tried and dropped").
DENSITY_CLUSTER = {2: 8, 3: 4}


@ti.data_oriented
class Density:
    def __init__(self, core, coupling, fade, pressure, forces):
        """coupling: how a sum weighs a particle and which it skips; fade: the split
        fade's measure of a child's density (multires/fade.py); pressure: takes each
        density (``density_done``); forces: the pair factors set with it (``factors``)."""
        self.dim, self.levels = core.dim, core.levels
        self.pool, self.grids, self.lev, self.nb = core.pool, core.grids, core.lev, core.nb
        self.coupling, self.fade, self.pressure, self.forces = coupling, fade, pressure, forces
        self.limit_virtual = coupling.limit_virtual
        self.skin = core.grids.skin  # > 0: lists kept across steps (neighbours.py)

    @ti.func
    def support(self, i):
        """Particle i's level, its support h, h² and poly6 constant."""
        l = self.pool.p[i].level
        h = self.lev.h[l]
        return l, h, h * h, self.lev.poly6[l]

    @ti.func
    def grid_sum(self, xq, l, h2, c6, i, record: ti.template()):
        """Σ_j m_j W_poly6(xq − x_j) over level l's grid block (real and virtual), xq
        particle i's position or one of its wall images. ``record``: xq is particle i
        itself; list its neighbours and count them."""
        p = ti.static(self.pool.p)
        rho = 0.0
        count = 0
        last = ti.static(self.nb.max_neighbours)  # the spare slot past the list
        base = self.grids.around(xq, l)
        for o in ti.grouped(ti.ndrange(*self.grids.row_axes)):
            lo, hi = self.grids.row(base, o, l)
            for j in range(lo, hi):
                r2 = (xq - p[j].x).norm_sqr()
                if ti.static(BRANCH_FREE):
                    d = h2 - r2
                    d = ti.max(d, 0.0)
                    rho += self.coupling.sum_mass(j) * (d * d * d)
                    if ti.static(record):
                        # written every time, kept only when counted; a list that
                        # overflowed into the spare slot is not read (forces use the grid)
                        self.nb.lists[i, ti.min(count, last)] = j
                        count += ti.cast(r2 < h2 and j != i, ti.i32)
                elif r2 < h2:
                    rho += self.coupling.sum_mass(j) * poly6(r2, h2, 1.0)
                    if ti.static(record):
                        if j != i:
                            self.nb.lists[i, ti.min(count, last)] = j
                            count += 1
        if ti.static(record):
            self.nb.count[i] = count
        return rho * c6 * self.coupling.sum_scale()

    @ti.func
    def _add_image_term(self, i, j, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """m_j W(xq − x_j) where j counts for the image xq (ctx: h², the image is read
        from a list). A listed image's sum, or an obstacle image's, skips the candidates
        out of reach; a domain image scanned from the grid adds them as zeros."""
        p = ti.static(self.pool.p)
        h2 = ctx[0]
        r2 = (xq - p[j].x).norm_sqr()
        if ti.static(BRANCH_FREE and not check):
            if ctx[1] != 0.0:
                if r2 < h2:
                    acc += self.coupling.sum_mass(j) * poly6(r2, h2, 1.0)
            else:
                d = ti.max(h2 - r2, 0.0)
                acc += self.coupling.sum_mass(j) * (d * d * d)
        elif r2 < h2:
            ok = True
            if ti.static(check):
                ok = self.nb.image_in_solid(p[j].x, p0, nrm)
            if ok:
                acc += self.coupling.sum_mass(j) * poly6(r2, h2, 1.0)

    @ti.func
    def _image_density(self, i, xq, L, p0, nrm, check: ti.template(), ctx: ti.template(), acc: ti.template()):
        """One image's density: its own sum over i and i's list (domain walls, listed) or
        the grid around it, added to ``acc`` (ctx: h², listed, poly6 constant, level)."""
        listed = ctx[1] != 0.0
        if ti.static(check):
            listed = False  # an obstacle image's neighbours are not i's: the grid
        rho = 0.0
        sub = ti.Vector([ctx[0], ti.cast(listed, float)])
        self.nb.candidates(
            i, xq, L, p0, nrm, check, ti.cast(ctx[3], ti.i32), listed, True, self._add_image_term, sub, rho
        )
        acc += rho * ctx[2] * self.coupling.sum_scale()

    @ti.kernel
    def list_fine(self, n: ti.i32):
        self.list_fine_func(n)

    @ti.func
    def list_fine_func(self, n):
        """The neighbour search for the real particles below the coarsest level, done
        ahead of the density pass because the virtual-mass limiter
        (``multires.limiter``) reads the lists first: the grid scan and recording of
        ``grid_sum``, its sum not kept (the virtual masses it summed are last step's),
        taken ``DENSITY_CLUSTER`` particles at a time where they share a column of cells,
        as the density pass does. ``run`` then sums over these lists. With a skin: the
        skin lists on a build step, and each step's lists from them."""
        if ti.static(self.skin > 0.0):
            self._list_fine_skin(n)
        else:
            self._list_fine(n)

    @ti.func
    def _list_fine(self, n):
        p = ti.static(self.pool.p)
        K = ti.static(DENSITY_CLUSTER[self.dim])
        for t in range((n + K - 1) // K):
            i0 = K * t
            scanned = 0
            if i0 + K <= n:
                scanned = self._scan_cluster(i0, True, False)
            for q in range(K):  # not unrolled
                i = i0 + q
                if i < n and self.fine_real(i) and not (scanned >> q) & 1:
                    l, h, h2, c6 = self.support(i)
                    self.grid_sum(p[i].x, l, h2, c6, i, True)

    @ti.func
    def _list_fine_skin(self, n):
        K = ti.static(DENSITY_CLUSTER[self.dim])
        build = self.grids.building()
        for t in range((n + K - 1) // K):
            i0 = K * t
            scanned = 0
            if build and i0 + K <= n:
                scanned = self._scan_cluster(i0, True, True)
            for q in range(K):  # not unrolled
                i = i0 + q
                if i < n and self.fine_real(i):
                    if build and not (scanned >> q) & 1:
                        self._list_near(i)
                    self._near_density(i)

    @ti.kernel
    def run(self, n: ti.i32):
        self.run_func(n)

    @ti.func
    def run_func(self, n):
        """The density of every particle the coupling does not skip, its neighbour list,
        and what the pressure solver and the pair forces take from it.

        The pool is sorted and nothing has moved since, so [0, n) holds no DEAD slot and
        every cell lists live particles. With the virtual-mass limiter on, ``list_fine``
        has already listed the neighbours of every real particle below the coarsest level
        this step; those sum over their list instead of scanning the grid again (one
        scan, not two, for those particles: docs/performance.md)."""
        if ti.static(self.skin > 0.0):
            self._run_skin(n)
        else:
            self._run(n)

    @ti.func
    def _run(self, n):
        p = ti.static(self.pool.p)
        K = ti.static(DENSITY_CLUSTER[self.dim])
        for t in range((n + K - 1) // K):
            i0 = K * t
            scanned = 0
            if i0 + K <= n:
                scanned = self._scan_cluster(i0, False, False)
            for q in range(K):  # not unrolled: one copy of the code below
                i = i0 + q
                if i < n and not self.coupling.density_skip(i):
                    l, h, h2, c6 = self.support(i)
                    rho = 0.0
                    if (scanned >> q) & 1:
                        rho = p[i].rho  # its sum, left there by the cluster's scan
                    elif self._listed_already(i):
                        rho = self._listed_density(i, p[i].x, h2, c6)
                    else:
                        rho = self.grid_sum(p[i].x, l, h2, c6, i, True)
                    self._finish(i, rho)

    @ti.func
    def _run_skin(self, n):
        """``run`` with a skin: on a build step the skin lists are scanned (clusters as
        without a skin) and each slot's x kept; every step sums over the skin lists."""
        p = ti.static(self.pool.p)
        K = ti.static(DENSITY_CLUSTER[self.dim])
        build = self.grids.building()
        for t in range((n + K - 1) // K):
            i0 = K * t
            scanned = 0
            if build and i0 + K <= n:
                scanned = self._scan_cluster(i0, False, True)
            for q in range(K):  # not unrolled: one copy of the code below
                i = i0 + q
                if i < n:
                    if build:
                        self.grids.built(i, p[i].x)
                    if not self.coupling.density_skip(i):
                        l, h, h2, c6 = self.support(i)
                        rho = 0.0
                        if self._listed_already(i):
                            rho = self._listed_density(i, p[i].x, h2, c6)
                        else:
                            if build and not (scanned >> q) & 1:
                                self._list_near(i)
                            rho = self._near_density(i)
                        self._finish(i, rho)
        self.grids.lists_built()

    @ti.func
    def _list_near(self, i):
        """Particle i's skin list from the grid block around it: the particles of its level
        within (1 + skin) h, self excluded (written every time, kept only when counted)."""
        p = ti.static(self.pool.p)
        l = p[i].level
        xi = p[i].x
        reach = ti.static(1.0 + self.skin) * self.lev.h[l]
        reach2 = reach * reach
        last = ti.static(self.nb.max_near)  # the spare slot past the list
        count = 0
        base = self.grids.around(xi, l)
        for o in ti.grouped(ti.ndrange(*self.grids.row_axes)):
            lo, hi = self.grids.row(base, o, l)
            for j in range(lo, hi):
                r2 = (xi - p[j].x).norm_sqr()
                self.nb.near[i, ti.min(count, last)] = j
                count += ti.cast(r2 < reach2 and j != i, ti.i32)
        self.nb.near_count[i] = count

    @ti.func
    def _near_density(self, i):
        """Σ_j m_j W_poly6 over i itself and its skin list (the own-level sum of
        ``grid_sum``), and i's list of this step: the skin list's particles within h, in
        its order. A skin list that overflowed at its build is not read: the grid then
        (built this step), and the next step builds the lists again."""
        p = ti.static(self.pool.p)
        l, h, h2, c6 = self.support(i)
        xi = p[i].x
        rho = 0.0
        if self.nb.is_near_listed(i):
            last = ti.static(self.nb.max_neighbours)  # the spare slot past the list
            rho = self.coupling.sum_mass(i) * (h2 * h2 * h2)  # i itself, at r = 0
            count = 0
            for q in range(self.nb.near_count[i]):
                j = self.nb.near[i, q]
                r2 = (xi - p[j].x).norm_sqr()
                d = ti.max(h2 - r2, 0.0)
                rho += self.coupling.sum_mass(j) * (d * d * d)
                self.nb.lists[i, ti.min(count, last)] = j
                count += ti.cast(r2 < h2, ti.i32)
            self.nb.count[i] = count
            rho *= c6 * self.coupling.sum_scale()
        else:
            rho = self.grid_sum(xi, l, h2, c6, i, True)
            self.grids.overflow()
        return rho

    @ti.func
    def _listed_density(self, i, xq, h2, c6):
        rho = 0.0
        ctx = ti.Vector([h2, 1.0])
        eye = ti.Matrix.identity(float, self.dim)
        self.nb.candidates(i, xq, eye, xq, xq, False, 0, True, True, self._add_image_term, ctx, rho)
        return rho * c6 * self.coupling.sum_scale()

    @ti.func
    def _listed_already(self, i):
        """Has ``list_fine`` listed i's neighbours this step?"""
        listed = False
        if ti.static(self.limit_virtual):
            listed = self.fine_real(i) and self.nb.is_listed(i)
        return listed

    @ti.func
    def fine_real(self, i):
        """A real particle below the coarsest level: the particles the limiter bounds and
        ``list_fine`` lists, whose lists ``run`` then reads."""
        return is_real(self.pool.p[i].kind) and self.pool.p[i].level < ti.static(self.levels - 1)

    @ti.func
    def _scan_cluster(self, i0, list_only: ti.template(), skin: ti.template()):
        """One scan of the grid for the K particles i0 … i0+K−1 (``DENSITY_CLUSTER``): the
        density pass's sums and neighbour lists for those that need a scan (not skipped,
        not listed already), or, with ``list_only``, the lists of the fine real particles
        (``list_fine``). It applies if those particles share a level and a
        column of cells (the same cell on every axis but the last): their blocks of cells
        then have the same rows, and the scan walks each row once over the union of their
        spans, K distances a candidate. Returns the scanned members as bits (bit q:
        i0 + q), each with its list written and its own-level sum in ``rho`` (the density
        pass adds its wall images); 0, having done nothing, if they do not share a
        column: the caller then takes them one by one. A candidate outside a particle's
        support adds exactly zero to its sum and is not listed, so the result is the
        one-by-one sum up to rounding (the same candidates in the same order, zeros
        between). The other members ride along: their sums are dropped and their list
        writes go to the spare slot. With ``skin``: the members' skin lists (within
        (1 + skin) h) instead, and no sums."""
        p = ti.static(self.pool.p)
        K = ti.static(DENSITY_CLUSTER[self.dim])
        D = ti.static(self.dim - 1)  # the axis along the rows
        l = p[i0].level
        base = self.grids.around(p[i0].x, l)
        ok = True
        found = False
        lo_c, hi_c = 0, 0
        scans = ti.Vector.zero(ti.i32, K)
        scanned = 0
        for q in ti.static(range(K)):
            i = i0 + q
            scan = False
            if ti.static(list_only):
                scan = self.fine_real(i)
            else:
                scan = not (self.coupling.density_skip(i) or self._listed_already(i))
            if scan:
                scans[q] = 1
                b = self.grids.around(p[i].x, l)
                if not found:
                    found = True
                    base, lo_c, hi_c = b, b[D], b[D]
                ok = ok and p[i].level == l
                for a in ti.static(range(D)):
                    ok = ok and b[a] == base[a]
                lo_c = ti.min(lo_c, b[D])
                hi_c = ti.max(hi_c, b[D])
        if ok and found:
            h = self.lev.h[l]
            h2, c6 = h * h, self.lev.poly6[l]
            last = ti.static(self.nb.max_neighbours)  # the spare slot past the list
            near_last = ti.static(self.nb.max_near)
            reach2 = h2 * ti.static((1.0 + self.skin) ** 2)
            base[D] = lo_c
            span = hi_c - lo_c + ti.static(2 * self.grids.reach + 1)
            xs = ti.Matrix.rows([p[i0 + q].x for q in ti.static(range(K))])
            rho = ti.Vector.zero(float, K)
            count = ti.Vector.zero(ti.i32, K)
            for o in ti.grouped(ti.ndrange(*self.grids.row_axes)):
                lo, hi = self.grids.row_span(base, o, l, span)
                for j in range(lo, hi):
                    xj = p[j].x
                    m = self.coupling.sum_mass(j)
                    for q in ti.static(range(K)):
                        r2 = 0.0
                        for a in ti.static(range(self.dim)):
                            r2 += (xs[q, a] - xj[a]) ** 2
                        if ti.static(skin):
                            # the skin list alone: the density and the list follow from it
                            self.nb.near[i0 + q, ti.select(scans[q] != 0, ti.min(count[q], near_last), near_last)] = j
                            count[q] += ti.cast(r2 < reach2 and j != i0 + q, ti.i32)
                        else:
                            if ti.static(not list_only):
                                d = ti.max(h2 - r2, 0.0)
                                rho[q] += m * (d * d * d)
                            # written every time, kept only when counted (see ``grid_sum``)
                            self.nb.lists[i0 + q, ti.select(scans[q] != 0, ti.min(count[q], last), last)] = j
                            count[q] += ti.cast(r2 < h2 and j != i0 + q, ti.i32)
            scale = c6 * self.coupling.sum_scale()
            for q in ti.static(range(K)):
                if scans[q] != 0:
                    if ti.static(skin):
                        self.nb.near_count[i0 + q] = count[q]
                    else:
                        self.nb.count[i0 + q] = count[q]
                        if ti.static(not list_only):
                            p[i0 + q].rho = rho[q] * scale
                    scanned |= 1 << q
        return scanned

    @ti.func
    def _finish(self, i, rho_own):
        """Particle i's density from its own-level sum plus its wall images (its
        neighbour list written), then its pressure and the factors the force pass reads."""
        p = ti.static(self.pool.p)
        l, h, h2, c6 = self.support(i)
        rho = rho_own
        ctx = ti.Vector([h2, ti.cast(self.nb.is_listed(i), float), c6, ti.cast(l, float)])
        self.nb.images(i, h, self._image_density, ctx, rho)
        p[i].rho = rho
        self.fade.measured(i, rho)
        self.pressure.density_done(i)
        self.forces.factors(i)

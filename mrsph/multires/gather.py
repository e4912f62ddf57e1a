"""Gathering (METHOD.md §6, "merging is incremental"): neighbouring virtual parents of
one level whose groups fit in 2^d children pool them under one, so that a group can fill
up and merge (``topology.Multires._merge``).

Each round pairs mutual nearest neighbours only (``_propose`` then ``_accept``), so the
parallel pass has no races; ``GATHER_ROUNDS`` rounds a pass take groups of one to two,
four and eight in the best case. A pair gathers only when the union of its groups spans at
most ``adaptivity.gather_span`` of the release distance (else it would be released at the
next pass and gathered again), is within ``gather_factor`` coarse spacings, and, with
``gather_coarse_only``, where the criteria want the coarse level.
"""

import taichi as ti

from mrsph.sph.particles import DEAD, VIRTUAL_PARENT

GATHER_ROUNDS = 3  # pairings per pass: 1 → 2 → 4 → 8 children in the best case


@ti.data_oriented
class Gathering:
    """The gather rounds of one level pair. ``partner`` holds each virtual parent's last
    proposal (-1: none), which the merge reads: a partial group merges only once it can
    gather no more."""

    def __init__(self, core, adaptivity, fade, counters, event: int):
        a = adaptivity
        self.dim, self.nmax = core.dim, 2**core.dim
        self.pool, self.g, self.lev = core.pool, core.grids, core.lev
        self.fade = fade
        self.release_factor = a.release_factor
        self.gather_factor = a.gather_factor
        self.gather_span = a.gather_span
        self.gather_coarse_only = a.gather_coarse_only
        self.counters, self.event = counters, event  # the topology's event counters
        self.partner = ti.field(ti.i32, shape=self.pool.capacity)

    @ti.func
    def rounds(self, n, c):
        for _ in ti.static(range(GATHER_ROUNDS)):
            self._propose(n, c)
            self._accept(n, c)

    @ti.func
    def _union_spread(self, i, j):
        """Largest distance between two children of virtual parents i and j together."""
        p = ti.static(self.pool.p)
        spread = 0.0
        for a in range(p[i].nchild + p[j].nchild):
            ca = self._child_of_pair(i, j, a)
            for b in range(a + 1, p[i].nchild + p[j].nchild):
                cb = self._child_of_pair(i, j, b)
                spread = ti.max(spread, (p[ca].x - p[cb].x).norm())
        return spread

    @ti.func
    def _child_of_pair(self, i, j, a):
        ni = self.pool.p[i].nchild
        ch = 0
        if a < ni:
            ch = self.pool.children[i, a]
        else:
            ch = self.pool.children[j, a - ni]
        return ch

    @ti.func
    def _may_gather(self, i, c):
        """``adaptivity.gather_coarse_only``: a virtual parent gathers only where the
        criteria want level c (λ > c), the only place where its group may go on to merge.
        Elsewhere a gather does nothing but move mass at level c: two virtual parents
        become one at their centre of mass, a ~1 % jump in the coarse density next to it,
        and the group is released again when its children drift apart. Measured in the 2D
        pool of tests/test_adaptive_flow.py with the limiter off: mean speed 0.022
        sqrt(gH) with gathers everywhere, 0.013 without any."""
        return (not ti.static(self.gather_coarse_only)) or self.pool.p[i].lam > c

    @ti.func
    def _propose(self, n, c):
        """Each virtual parent of level c proposes its nearest partner (``partner``)."""
        p = ti.static(self.pool.p)
        reach = self.gather_factor * self.lev.s[c]
        # a gathered group must stay well inside the release limit, or it is released at
        # the next pass and gathered again, and every such cycle moves the virtual parents
        # (measured in a resting pool: ~3000 releases and gathers per second among ~240
        # transient particles, and an interface that never came to rest). The default 0.9
        # is the first tenth above a 3D lattice cell's diagonal, sqrt(3)/2 = 0.87 of the
        # release distance: at 0.8 no cell of eight could gather, and a 3D fluid left by
        # a stirrer kept 462 of its 2000 real particles fine (190 of 1791 at 0.9;
        # tests/test_multires.py, test_fine_fluid_a_stirrer_left_merges_back)
        keep = self.gather_span * self.release_factor * self.lev.h[c - 1]
        for i in range(n):
            self.partner[i] = -1
            if p[i].kind == VIRTUAL_PARENT and p[i].level == c and p[i].nchild < self.nmax and self._may_gather(i, c):
                ctx = ti.Vector([ti.cast(i, float), ti.cast(c, float), keep])
                self.partner[i] = self.g.nearest(p[i].x, c, reach * reach, p.x, self._may_pair, ctx)

    @ti.func
    def _may_pair(self, j, ctx):
        """Whether virtual parent i (ctx: i, c, the spread to keep) may propose j."""
        p = ti.static(self.pool.p)
        i, c = ti.cast(ctx[0], ti.i32), ti.cast(ctx[1], ti.i32)
        return (
            j != i
            and p[j].kind == VIRTUAL_PARENT
            and p[i].nchild + p[j].nchild <= self.nmax
            and self._may_gather(j, c)
            and self._union_spread(i, j) <= ctx[2]
        )

    @ti.func
    def _accept(self, n, c):
        """Mutual proposals gather: j's children join i's group; j dies."""
        p = ti.static(self.pool.p)
        for i in range(n):
            j = self.partner[i]
            if j > i and self.partner[j] == i:
                ni, nj = p[i].nchild, p[j].nchild
                for q in range(nj):
                    ch = self.pool.children[j, q]
                    self.pool.children[i, ni + q] = ch
                    self.pool.children[j, q] = -1
                    p[ch].parent = i
                mi, mj = p[i].m, p[j].m
                p[i].x = (mi * p[i].x + mj * p[j].x) / (mi + mj)
                p[i].v = (mi * p[i].v + mj * p[j].v) / (mi + mj)
                p[i].m = mi + mj
                p[i].nchild = ni + nj
                p[j].nchild = 0
                p[j].kind = DEAD
                self.fade.touch(p[i].x, c)  # the coarse level sees one heavier there
                ti.atomic_add(self.counters[self.event], 1)

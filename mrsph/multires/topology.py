"""Adaptive multiresolution: virtual particles, split and merge (METHOD.md §2–6).

Levels: level n has support h_n = 2^n h0, spacing s_n = 2^n s0 and nominal mass
m_n = 2^(d n) m0, so the density is the same at every level. Particles interact only
with particles of their own level (``density.py``, ``forces.py``); levels are coupled through virtual
particles:

- a real level-(n+1) particle within h_{n+1} of a real level-n particle is a *transient
  parent*: it carries 2^d virtual children of level n, placed at the fixed offsets
  ``(±s_n/2, ±s_n/2[, ±s_n/2])`` around it (the fine lattice inside its coarse cell);
- a real level-n particle within h_{n+1} of a real level-(n+1) particle is a *transient
  child*: it is linked to a virtual parent of level n+1 shared by at most 2^d siblings.

So the fine side of an interface sees a full fine neighbourhood (real fine particles and
the coarse particles' virtual children) and the coarse side a full coarse one. The
reaction of every real–virtual force goes back to the real particles the virtual one
stands for (``coupling.py``: in the force pass with the default variational coupling,
in a pass after it with the symmetric one), so momentum is conserved.

One adaptivity pass (every ``adaptivity.interval`` steps) walks the level pairs from the
coarsest down (§5.4), rebuilding the grids between pairs, and for the coarse level c
(fine level f = c − 1) runs, each as its own kernel:

1. ``_flags``: which real particles of level c have a real level-f particle within h_c
   (and the converse), and which have a real particle two or more levels finer (those
   must split: no regular particle may neighbour one two levels away).
2. ``_release``: groups whose children drifted apart beyond ``release_factor``·h_f, or
   of which neither the virtual parent nor any child has a real level-c particle within
   h_c any more (unless the virtual parent's position wants level c: that group is on
   its way to a merge), or one of whose children must split, are released (§5.3).
3. ``_split``: real level-c particles wanting level ≤ f split (§5.1–2). A transient
   parent's virtual children become real transient children and the parent becomes
   their virtual parent; a regular particle gets 2^d new children. §5.2's other
   trigger, a transient parent with a *regular* level-f particle in its support, is
   ``adaptivity.split_near_regular`` (off by default): here a regular fine particle next
   to a coarse one is coupled instead (step 5), so the trigger fires only for fine
   particles that came within reach since the last pass, and with it on the 3D resting
   pool of tests/test_adaptive_flow.py kept moving (0.020 sqrt(gH) after 2 s, against
   0.006 without; the dam-break fronts were unchanged). Children inherit the
   velocity; masses are divided by 2^d, which is exact in floating point.
   ``placement.py`` then spreads the new children to ``split_min_distance`` from their
   real neighbours (``adaptivity.split_relax`` = "spacing", the default), or
   moves them down their level's density gradient until none reads
   more than its parent's density ("density"): see both.
4. ``_parent_roles``: real level-c particles near real level-f ones (transient children
   included, which then hold both roles) become transient parents (virtual children
   created); transient parents with no fine neighbour left drop them.
5. ``_couple_fine``: regular level-f particles near real level-c ones become transient
   children with a virtual parent of their own (§6).

   Steps 4 and 5 read the neighbourhood flags of step 1, taken before this pass's splits
   and merges (their new particles are not in the grid until the next sort). So a coarse
   particle next to a group split in this pass gets its virtual children at the next
   pass, ``interval`` steps later, and so does a fine particle next to a group merged in
   it; until then the two levels there do not see each other. Rerunning steps 1, 4 and 5
   after each level pair made the 2D dam-break front worse and the 3D one no better:
   the 2D fluid split at the block is thrown further when its coarse neighbours take
   part at once.
6. ``gather.py`` (a few rounds): neighbouring virtual parents whose groups fit
   in 2^d children and span at most ``gather_span`` of the release distance gather
   under one (mutual nearest pairs, so the parallel pass has no races) — merging is
   incremental. By default only where the criteria want level c (``gather_coarse_only``).
7. ``_merge``: a virtual parent whose position no longer wants level f (λ > c + η) and
   whose group is full, or has at least ``merge_min_children`` children and no group
   within reach that it could take in (§6: "a group need not be full"; with
   ``merge_remnants``, any number of children where the virtual parent has a real
   level-c particle within its support, the transition layer proper), none of them
   carrying virtual children of its own, becomes a real regular level-c particle with the group's
   total mass, mass-weighted velocity and centre of mass; the children are removed.
   Virtual parents form in the transition layer (next to a real coarse particle) and
   also wherever a fine particle's position wants level c (``_couple_fine``), so that a
   region fine all through can coarsen once nothing wants it fine; so merges happen
   there too, not only in the transition layer of §6.
8. ``Absorption.run`` (``absorb.py``): a group that would merge into a particle lighter
   than ``adaptivity.absorb_below`` (half) of level c's nominal mass is given instead to
   the nearest real level-c particle of any kind within half its support, which takes
   its mass and momentum and keeps its place; with no such neighbour the group stays
   fine. So every real particle stays within [1/2, 2] of its level's nominal mass. A
   light group inside a real coarse particle (``Absorption.caged``) goes the same way
   whatever the criteria want.
9. ``SplitFade.remeasure_touched`` (``adaptivity.split_fade`` only): every real particle
   whose neighbourhood this pair changed re-measures its fade offset (``fade.py``):
   level-c ones within h_c of a merge, an absorption, a new or gathered virtual parent
   (``touch``), level-f ones within h_c of a split or of new virtual children
   (``changed``).

Choices left open by the thesis (scene keys, defaults in docs/scenes.md): spring rate of
the virtual particles' Hooke springs, the sampling pattern above, the hysteresis η, the
release distance factor, the smallest group that may merge, the gathering distance, the
relaxation of split children (``split_relax_iterations``, ``split_min_distance``), and the
lightest particle a merge may make (``absorb_below``).
"""

import itertools

import numpy as np
import taichi as ti

from mrsph.sph.particles import (
    DEAD,
    REGULAR,
    ROLE_CHILD,
    ROLE_PARENT,
    VIRTUAL_CHILD,
    VIRTUAL_PARENT,
    is_real,
    merge_mass_mean,
    split_inherited,
)

from .absorb import Absorption
from .gather import Gathering
from .placement import FRESH, Placement  # FRESH: real child made by a split in this pass

# scratch bits in ``flags`` during one level pair of a pass
NEAR_FINE = 1  # real level-c particle with a real level-f particle within h_c
NEAR_COARSE = 2  # real level-f particle with a real level-c particle within h_c
MUST_SPLIT = 4  # level-c particle with a real particle ≥ 2 levels finer within h_c: a real
# one must split, a virtual parent must not merge
VP_ANCHORED = 8  # virtual parent with a real particle of its own level within its support
RELEASED = 16  # virtual parent whose group is being released (claimed atomically)
NEAR_REGULAR = 64  # real level-c particle with a regular (uncoupled) level-f particle within h_c
_FLAGS = (
    NEAR_FINE,
    NEAR_COARSE,
    MUST_SPLIT,
    VP_ANCHORED,
    RELEASED,
    FRESH,
    NEAR_REGULAR,
)  # distinct bits (a test holds it)

# The share of the pool that splits and new parent roles leave free, for the virtual
# parents a merge starts from (``_couple_fine``). Without it, a pool filled by splits
# could never coarsen again: every gather needs a slot, and a merge is what frees them
# (seen in the stirred soak, docs/performance.md).
MERGE_RESERVE = 1.0 / 32.0

# Event counters, read by ``take_counters`` (refused splits are the pool's ``refused``).
# Mass is divided on a split and summed on a merge (``particles.ATTRIBUTES``); the kernels
# below write it by hand, as the merge's means need it, so an attribute given either rule
# must be written there too (a test holds that the mass is the only one).
COUNTERS = ("splits", "merges", "released", "gathered", "absorbed")
EV_SPLITS, EV_MERGES, EV_RELEASED, EV_GATHERED, EV_ABSORBED = range(len(COUNTERS))  # indices into them


def sampling_offsets(dim: int):
    """Offsets of the 2^d virtual children in units of the child level's spacing."""
    return [[b - 0.5 for b in bits] for bits in itertools.product((0, 1), repeat=dim)]


@ti.data_oriented
class Multires:
    """The topology of the levels: which particles are transient, split, merge, release
    and gather (the module's docstring). It owns the pool's links and flags; the coupling
    (``coupling.py``) reads them."""

    def __init__(self, core, adaptivity, criteria, disturbances, fade):
        """adaptivity: the scene's params; criteria: the wanted level λ(x); disturbances:
        the mouse and stirrers; fade: the compression of split children, faded out
        (fade.py)."""
        self.dim = core.dim
        self.pool = core.pool
        self.g = core.grids
        self.levels = core.levels
        self.lev, self.nb, self.boundary = core.lev, core.nb, core.boundary
        self.criteria, self.disturbances, self.fade = criteria, disturbances, fade
        self.rest_density = core.lev.rest_density
        self.nmax = 2**self.dim
        self.reserve = int(MERGE_RESERVE * self.pool.capacity)  # slots splits leave free
        a = adaptivity
        self.hysteresis = a.hysteresis
        self.release_factor = a.release_factor
        self.merge_min = a.merge_min_children  # 0 resolved by the config
        self.merge_remnants = a.merge_remnants
        self.split_near_regular = a.split_near_regular
        self.relax_by_density = a.split_relax == "density"
        self.offsets = ti.Vector.field(self.dim, float, shape=self.nmax)
        for k, o in enumerate(sampling_offsets(self.dim)):
            self.offsets[k] = o
        # running totals, never cleared: the host takes the difference when it collects
        # them, once an ``advance`` (a read and a clear after every pass cost ~50 µs)
        self.counters = ti.field(ti.i64, shape=len(COUNTERS))
        self._taken = np.zeros(len(COUNTERS), np.int64)
        self.place = Placement(core, adaptivity)  # where the children of this pass's splits go
        self.gather = Gathering(core, adaptivity, fade, self.counters, EV_GATHERED)
        # groups too light to merge
        self.absorb = Absorption(core, adaptivity, fade, self.counters, EV_MERGES, EV_ABSORBED)

    # ------------------------------------------------------------------ host driver
    def adapt(self, time: float) -> None:
        """One adaptivity pass over every level pair, coarsest first (criteria at ``time``)."""
        self.criteria.update(time)
        for c in range(self.levels - 1, 0, -1):
            self._pair_pass(self.g.sort(self.pool), c)

    @ti.kernel
    def _pair_pass(self, n: ti.i32, c: ti.i32):
        """The level pair (c − 1, c), §5–6, in order; one kernel, since at a few thousand
        particles the launches of separate kernels, not their loops, were the cost
        (demo_2d: ~30 launches a pass)."""
        self._wanted(n)
        self._flags(n, c)
        self._release(n, c)
        self._unlink_splitters(n, c)
        self.place.n_fresh[None] = 0
        self._split(n, c)
        if ti.static(self.relax_by_density):
            self.place.settle(c)
        else:
            self.place.relax(c)
        self._parent_roles(n, c)
        self._couple_fine(n, c)
        self.gather.rounds(n, c)
        self._merge(n, c)
        if ti.static(self.absorb.on):
            self.absorb.run(c)
        self.fade.remeasure_touched(n, c)
        self.pool.clamp_n()

    def take_counters(self) -> dict:
        """The events (``COUNTERS``) since the last call."""
        vals = self.counters.to_numpy()
        new, self._taken = vals - self._taken, vals
        return {k: int(v) for k, v in zip(COUNTERS, new)}

    # ------------------------------------------------------------------ helpers
    def _fields(self, names):
        """The pool's member fields for attribute names of the registry."""
        return [getattr(self.pool.p, n) for n in names]

    @ti.func
    def _h(self, l):
        return self.lev.h[l]

    @ti.func
    def _release_group(self, vp):
        """Turn the children of virtual parent ``vp`` back into regular particles; vp dies."""
        p = ti.static(self.pool.p)
        for k in range(p[vp].nchild):
            ch = self.pool.children[vp, k]
            p[ch].kind = p[ch].kind & ~ROLE_CHILD
            p[ch].parent = -1
            self.pool.children[vp, k] = -1
        p[vp].nchild = 0
        p[vp].kind = DEAD
        ti.atomic_add(self.counters[EV_RELEASED], 1)

    @ti.func
    def _kill_virtual_children(self, i):
        """Transient parent i drops its virtual children and the parent role."""
        self.pool.drop_children(i)
        self.pool.p[i].kind = self.pool.p[i].kind & ~ROLE_PARENT

    # ------------------------------------------------------------------ kernels
    @ti.func
    def _wanted(self, n):
        for i in range(n):
            if self.pool.p[i].kind != DEAD:
                self.pool.p[i].lam = self.criteria.wanted(self.pool.p[i].x, self.boundary, self.disturbances)

    @ti.func
    def _flags(self, n, c):
        p = ti.static(self.pool.p)
        for i in range(n):
            p[i].flags = 0
        hc = self._h(c)
        for i in range(n):
            ki = p[i].kind
            li = p[i].level
            if (is_real(ki) and li < c) or (ki == VIRTUAL_PARENT and li == c):
                xi = p[i].x
                base = self.g.around(xi, c)
                for o in ti.grouped(ti.ndrange(*self.g.row_axes)):
                    lo, hi = self.g.row(base, o, c)
                    for j in range(lo, hi):
                        d2 = (xi - p[j].x).norm_sqr()
                        if ki != VIRTUAL_PARENT and li <= c - 2 and p[j].kind == VIRTUAL_PARENT and d2 < hc * hc:
                            # merging this group would put a level-c particle next to one
                            # two levels finer: the same balance that forces splits
                            ti.atomic_or(p[j].flags, MUST_SPLIT)
                        if is_real(p[j].kind) and d2 < hc * hc:
                            if ki == VIRTUAL_PARENT:
                                ti.atomic_or(p[i].flags, VP_ANCHORED)
                            elif li == c - 1:
                                ti.atomic_or(p[i].flags, NEAR_COARSE)
                                ti.atomic_or(p[j].flags, NEAR_FINE)
                                if (ki & ROLE_CHILD) == 0:
                                    ti.atomic_or(p[j].flags, NEAR_REGULAR)
                            else:
                                ti.atomic_or(p[j].flags, MUST_SPLIT)

    @ti.func
    def _release(self, n, c):
        p = ti.static(self.pool.p)
        f = c - 1
        limit = self.release_factor * self._h(f)
        for i in range(n):
            if p[i].kind == VIRTUAL_PARENT and p[i].level == c:
                anchored = (p[i].flags & VP_ANCHORED) != 0 or p[i].lam > c + self.hysteresis
                release = False
                spread = 0.0
                for a in range(p[i].nchild):
                    ca = self.pool.children[i, a]
                    # still needed while a child is near a real coarse particle, even with the
                    # barycentre beyond the coarse support (else released and gathered again)
                    if (p[ca].flags & NEAR_COARSE) != 0:
                        anchored = True
                    if p[ca].lam < f - self.hysteresis:
                        release = True
                    for b in range(a + 1, p[i].nchild):
                        cb = self.pool.children[i, b]
                        spread = ti.max(spread, (p[ca].x - p[cb].x).norm())
                if release or not anchored or spread > limit:
                    self._release_group(i)

    @ti.func
    def _unlink_splitters(self, n, c):
        """A level-c transient child that must split first leaves its group (§5.3).

        Siblings run in parallel and the first to claim the group releases it, which
        clears the others' child bit and then their ``parent``: a sibling may read its
        kind before the one and its parent after the other, so a parent of -1 means the
        group is already being released."""
        p = ti.static(self.pool.p)
        for i in range(n):
            k = p[i].kind
            if is_real(k) and p[i].level == c and (k & ROLE_CHILD) != 0:
                if p[i].lam < c - self.hysteresis or (p[i].flags & MUST_SPLIT) != 0:
                    vp = p[i].parent
                    if vp >= 0:
                        if (ti.atomic_or(p[vp].flags, RELEASED) & RELEASED) == 0:
                            self._release_group(vp)

    @ti.func
    def _split(self, n, c):
        p = ti.static(self.pool.p)
        f = c - 1
        s_f = self.lev.s[f]
        for i in range(n):
            k = p[i].kind
            if is_real(k) and p[i].level == c and (k & ROLE_CHILD) == 0:
                near_regular = False
                if ti.static(self.split_near_regular):
                    near_regular = (
                        (k & ROLE_PARENT) != 0 and (p[i].flags & NEAR_REGULAR) != 0 and p[i].lam <= c + self.hysteresis
                    )
                if p[i].lam < c - self.hysteresis or (p[i].flags & MUST_SPLIT) != 0 or near_regular:
                    ok = True
                    if k == REGULAR:
                        base = self.pool.claim(self.nmax, ti.static(self.reserve))
                        if base < 0:
                            ok = False
                        else:
                            for q in range(self.nmax):
                                ch = base + q
                                self._spawn_child(i, ch, q, f, s_f)
                                self.pool.children[i, q] = ch
                            p[i].nchild = self.nmax
                    if ok:
                        rho_seen = self.fade.seen(i)  # what its pressure read
                        # (transient parent: its virtual children become real)
                        for q in range(self.nmax):
                            ch = self.pool.children[i, q]
                            p[ch].kind = ROLE_CHILD
                            p[ch].parent = i
                            p[ch].v = p[i].v
                            # full share: a virtual child's mass may have been scaled
                            # down (``limiter.VirtualMassLimiter``)
                            p[ch].m = p[i].m / self.nmax
                            p[ch].flags = FRESH
                            self.fade.born(ch, rho_seen)  # (ρ0 at least: see fade.py)
                            self.place.fresh[ti.atomic_add(self.place.n_fresh[None], 1)] = ch
                        self.place.fit(i, s_f)
                        self.fade.clear(i)
                        self.fade.changed(i)
                        p[i].kind = VIRTUAL_PARENT
                        ti.atomic_add(self.counters[EV_SPLITS], 1)

    @ti.func
    def _spawn_child(self, i, ch, q, f, s_f):
        """Write child slot ``ch`` of particle i at sampling offset q (kind set by caller)."""
        p = ti.static(self.pool.p)
        for fld in ti.static(self._fields(split_inherited())):
            fld[ch] = fld[i]
        p[ch].m = p[i].m / self.nmax
        p[ch].x = p[i].x + self.offsets[q] * s_f
        p[ch].a = ti.Vector.zero(float, self.dim)
        p[ch].level = f
        p[ch].slot = q
        p[ch].nchild = 0
        p[ch].flags = 0
        p[ch].parent = i
        self.fade.clear(ch)
        p[ch].kind = VIRTUAL_CHILD

    @ti.func
    def _parent_roles(self, n, c):
        p = ti.static(self.pool.p)
        f = c - 1
        s_f = self.lev.s[f]
        for i in range(n):
            k = p[i].kind
            if is_real(k) and p[i].level == c:
                near = (p[i].flags & NEAR_FINE) != 0
                if near and (k & ROLE_PARENT) == 0:
                    base = self.pool.claim(self.nmax, ti.static(self.reserve))
                    if base >= 0:
                        for q in range(self.nmax):
                            self._spawn_child(i, base + q, q, f, s_f)
                            self.pool.children[i, q] = base + q
                        p[i].nchild = self.nmax
                        p[i].kind = k | ROLE_PARENT
                        self.fade.changed(i)
                elif not near and (k & ROLE_PARENT) != 0:
                    self._kill_virtual_children(i)

    @ti.func
    def _couple_fine(self, n, c):
        p = ti.static(self.pool.p)
        for i in range(n):
            k = p[i].kind
            # §6: near a real coarse particle, or (so that a region that is fine all
            # through can coarsen once nothing wants it fine) wanting the coarse level
            if (
                is_real(k)
                and p[i].level == c - 1
                and (k & ROLE_CHILD) == 0
                and ((p[i].flags & NEAR_COARSE) != 0 or p[i].lam > c + self.hysteresis)
            ):
                vp = self.pool.claim(1)
                if vp >= 0:
                    for fld in ti.static(self._fields(split_inherited())):
                        fld[vp] = fld[i]
                    p[vp].x = p[i].x
                    p[vp].m = p[i].m
                    p[vp].a = ti.Vector.zero(float, self.dim)
                    p[vp].level = c
                    p[vp].flags = 0
                    p[vp].slot = 0
                    p[vp].parent = -1
                    p[vp].nchild = 1
                    self.fade.clear(vp)
                    self.pool.children[vp, 0] = i
                    p[vp].kind = VIRTUAL_PARENT
                    self.fade.touch(p[i].x, c)
                    p[i].parent = vp
                    p[i].kind = k | ROLE_CHILD

    @ti.func
    def _merge(self, n, c):
        p = ti.static(self.pool.p)
        for i in range(n):
            # a full group merges; a partial one of at least merge_min only once it can
            # gather no more (partner: the last gathering round). Half a group by default:
            # in a film one particle thick full groups never form (the 3D dam break: 0 merges)
            k = p[i].nchild
            least = self.merge_min
            if ti.static(self.merge_remnants) and (p[i].flags & VP_ANCHORED) != 0:
                least = 1
            go = False
            if p[i].kind == VIRTUAL_PARENT and p[i].level == c and (p[i].flags & MUST_SPLIT) == 0:
                whole = k == self.nmax or (k >= least and self.gather.partner[i] == -1)
                go = whole and p[i].lam > c + self.hysteresis
                if not go and ti.static(self.absorb.on):
                    go = self.absorb.caged(i, c)  # given away whatever the criteria want
            if go:
                ok = True
                for q in range(p[i].nchild):
                    if (p[self.pool.children[i, q]].kind & ROLE_PARENT) != 0:
                        ok = False
                if ok and ti.static(self.absorb.on):
                    if self.absorb.takes(i, c):
                        ok = False  # too light to stand alone: given to a neighbour
                if ok:
                    mass = ti.cast(self.pool.group_mass(i), float)
                    rho_seen = self.fade.group_seen(i) / mass
                    for fld in ti.static(self._fields(merge_mass_mean())):
                        acc = fld[i] * 0.0
                        for q in range(p[i].nchild):
                            ch = self.pool.children[i, q]
                            acc += p[ch].m * fld[ch]
                        fld[i] = acc / mass
                    self.pool.drop_children(i)
                    p[i].m = mass
                    p[i].parent = -1
                    p[i].kind = REGULAR
                    self.fade.born(i, rho_seen)  # what its group's pressure read (fade.py)
                    self.fade.touch(p[i].x, c)
                    ti.atomic_add(self.counters[EV_MERGES], 1)

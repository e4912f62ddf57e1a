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
   ``_relax_fresh`` then spreads the new children to ``split_min_distance`` from their
   real neighbours (``adaptivity.split_relax`` = "spacing", the default), or
   ``_settle_fresh`` moves them down their level's density gradient until none reads
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
   it; until then the two levels there do not see each other. Measured by sorting again
   and rerunning steps 1, 4 and 5 after each level pair (the dam break of
   tests/test_adaptive_flow.py, seven CFL numbers, docs/dam-front.md): the 3D front came
   within -0.6..+1.0 % at six, +28.9 % at the seventh, and the 2D front went from
   +1.8..+3.7 % to +0.6..+19.7 % (mean +13.7 %); the coarse side (step 4) makes the
   whole difference, the fine side (step 5) none. A pass every step does the same
   (``interval`` = 1 in the table there). Not in: the 2D fluid split at the block is
   thrown further when its coarse neighbours take part at once.
6. ``_propose``/``_accept`` (a few rounds): neighbouring virtual parents whose groups fit
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

Choices left open by the thesis (scene keys, defaults in docs/scenes.md): spring rate of
the virtual particles' Hooke springs, the sampling pattern above, the hysteresis η, the
release distance factor, the smallest group that may merge, the gathering distance, the
relaxation of split children (``split_relax_iterations``, ``split_min_distance``).
"""

import itertools

import numpy as np
import taichi as ti

from ..particles import (DEAD, REGULAR, ROLE_CHILD, ROLE_PARENT, VIRTUAL_CHILD,
                        VIRTUAL_PARENT, is_real, merge_mass_mean, split_inherited)

# scratch bits in ``flags`` during one level pair of a pass
NEAR_FINE = 1      # real level-c particle with a real level-f particle within h_c
NEAR_COARSE = 2    # real level-f particle with a real level-c particle within h_c
MUST_SPLIT = 4     # level-c particle with a real particle ≥ 2 levels finer within h_c: a real
                   # one must split, a virtual parent must not merge
VP_ANCHORED = 8    # virtual parent with a real particle of its own level within its support
RELEASED = 16      # virtual parent whose group is being released (claimed atomically)
FRESH = 32         # real child made by a split in this pass (spread by ``_relax_fresh``)
NEAR_REGULAR = 64  # real level-c particle with a regular (uncoupled) level-f particle within h_c
_FLAGS = (NEAR_FINE, NEAR_COARSE, MUST_SPLIT, VP_ANCHORED, RELEASED, FRESH, NEAR_REGULAR)   # distinct bits (a test holds it)

GATHER_ROUNDS = 3  # pairings per pass: 1 → 2 → 4 → 8 children in the best case
# The longest move of a new child in one iteration of ``_settle_fresh``, in fine spacings:
# a Newton step on a density that is not linear over a spacing overshoots. Measured on the
# first splits of the two-level dam break (docs/dam-front.md): at 0.1 the energy rose by
# 1.2 % in 2D and 0.25 % in 3D, at 0.25 by 0.2 % and not at all.
SETTLE_STEP = 0.25

# Event counters, read by ``take_counters`` (refused splits are the pool's ``refused``).
# Mass is divided on a split and summed on a merge (``particles.ATTRIBUTES``); the kernels
# below write it by hand, as the merge's means need it, so an attribute given either rule
# must be written there too (a test holds that the mass is the only one).
COUNTERS = ("splits", "merges", "released", "gathered")
EV_SPLITS, EV_MERGES, EV_RELEASED, EV_GATHERED = range(len(COUNTERS))   # indices into them


def sampling_offsets(dim: int):
    """Offsets of the 2^d virtual children in units of the child level's spacing."""
    return [[b - 0.5 for b in bits] for bits in itertools.product((0, 1), repeat=dim)]


@ti.data_oriented
class Multires:
    """The topology of the levels: which particles are transient, split, merge, release
    and gather (the module's docstring). It owns the pool's links and flags; the coupling
    (``coupling.py``) reads them."""

    def __init__(self, parts):
        self.dim = parts.dim
        self.pool = parts.pool
        self.g = parts.grids
        self.levels = parts.levels
        self.lev, self.nb = parts.lev, parts.neighbours
        self.criteria, self.boundary, self.disturbances = parts.criteria, parts.boundary, parts.disturbances
        self.rest_density = float(parts.scene["fluid"]["rest_density"])
        self.nmax = 2 ** self.dim
        a = parts.scene["adaptivity"]
        self.hysteresis = float(a["hysteresis"])
        self.release_factor = float(a["release_factor"])
        self.merge_min = int(a["merge_min_children"])   # 0 resolved by the config
        self.gather_factor = float(a["gather_factor"])
        self.gather_span = float(a["gather_span"])
        self.merge_remnants = bool(a["merge_remnants"])
        self.gather_coarse_only = bool(a["gather_coarse_only"])
        self.relax_iterations = int(a["split_relax_iterations"])
        self.relax_distance = float(a["split_min_distance"])
        self.split_near_regular = bool(a["split_near_regular"])
        self.relax_by_density = a["split_relax"] == "density"
        self.settle_tolerance = float(a["split_density_tolerance"])
        self.offsets = ti.Vector.field(self.dim, float, shape=self.nmax)
        for k, o in enumerate(sampling_offsets(self.dim)):
            self.offsets[k] = o
        # running totals, never cleared: the host takes the difference when it collects
        # them, once an ``advance`` (a read and a clear after every pass cost ~50 µs)
        self.counters = ti.field(ti.i64, shape=len(COUNTERS))
        self._taken = np.zeros(len(COUNTERS), np.int64)
        self.partner = ti.field(ti.i32, shape=self.pool.capacity)
        self.fresh = ti.field(ti.i32, shape=self.pool.capacity)   # children split this pass
        self.n_fresh = ti.field(ti.i32, shape=())

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
        self.n_fresh[None] = 0
        self._split(n, c)
        if ti.static(self.relax_by_density):
            self._settle_fresh(c)
        else:
            self._relax_fresh(c)
        self._parent_roles(n, c)
        self._couple_fine(n, c)
        for _ in ti.static(range(GATHER_ROUNDS)):
            self._propose(n, c)
            self._accept(n, c)
        self._merge(n, c)
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
        p = ti.static(self.pool.p)
        for k in range(p[i].nchild):
            ch = self.pool.children[i, k]
            p[ch].kind = DEAD
            p[ch].parent = -1
            self.pool.children[i, k] = -1
        p[i].nchild = 0
        p[i].kind = p[i].kind & ~ROLE_PARENT

    # ------------------------------------------------------------------ kernels
    @ti.func
    def _wanted(self, n):
        for i in range(n):
            if self.pool.p[i].kind != DEAD:
                self.pool.p[i].lam = self.criteria.wanted(
                    self.pool.p[i].x, self.boundary, self.disturbances)

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
                        if ki != VIRTUAL_PARENT and li <= c - 2 and p[j].kind == VIRTUAL_PARENT \
                                and d2 < hc * hc:
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
                    # still needed while a child is near a real coarse particle, though
                    # the barycentre may lie beyond the coarse support (else the group is
                    # released and gathered again pass after pass)
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
                    near_regular = (k & ROLE_PARENT) != 0 and (p[i].flags & NEAR_REGULAR) != 0 \
                        and p[i].lam <= c + self.hysteresis
                if p[i].lam < c - self.hysteresis or (p[i].flags & MUST_SPLIT) != 0 or near_regular:
                    ok = True
                    if k == REGULAR:
                        base = self.pool.claim(self.nmax)
                        if base < 0:
                            ok = False
                        else:
                            for q in range(self.nmax):
                                ch = base + q
                                self._spawn_child(i, ch, q, f, s_f)
                                self.pool.children[i, q] = ch
                            p[i].nchild = self.nmax
                    if ok:
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
                            self.fresh[ti.atomic_add(self.n_fresh[None], 1)] = ch
                        self._fit_children(i, s_f)
                        p[i].kind = VIRTUAL_PARENT
                        ti.atomic_add(self.counters[EV_SPLITS], 1)

    @ti.func
    def _relax_fresh(self, c):
        """``adaptivity.split_relax = "spacing"``: ``split_relax_iterations`` Jacobi
        iterations spreading the children made by this pass's splits (listed in ``fresh`` by ``_split``): each
        is pushed away from every real level-f particle closer than ``split_min_distance``
        fine spacings, by the whole overlap from an older particle and half of it from
        another new one (which moves too), then kept half a fine spacing inside the walls
        and outside the obstacles (as ``_fit_children``). The displacement is kept in ``a``
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
            self._move_fresh(margin)

    @ti.func
    def _move_fresh(self, margin):
        """Move each new child by the displacement its relaxation left in ``a`` (not in use
        during the adaptivity pass), then keep it ``margin`` inside the walls and outside
        the obstacles (as ``_fit_children``)."""
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
    def _settle_fresh(self, c):
        """``adaptivity.split_relax = "density"``: ``split_relax_iterations``
        Jacobi iterations moving each child made by this pass's splits down the gradient
        of its level's density, walls and obstacles counted as mirror images as in the
        density pass, until it reads no more than its parent's density (ρ0 at least): a
        Newton step ``−(ρ − ρ_t) ∇ρ / |∇ρ|²``, at most ``SETTLE_STEP`` fine spacings per
        iteration, then kept half a fine spacing inside the walls and outside the
        obstacles (as ``_fit_children``). Velocities are untouched, so mass and momentum
        are kept; positions only move where the children would start compressed beyond
        what their parent was.

        Why: the children of a split land on the fine lattice of their parent's cell, but
        a coarse particle in a thin sheet sits closer to its neighbours than its spacing
        (its density, short of neighbours above, reaches ρ0 only when compressed, and
        below ρ0 the clamped pressure keeps nothing apart), so its children start on top
        of each other's and their neighbours' and their pressure throws them off: the
        split injected energy where METHOD.md §5 wants the flow undisturbed. Measured
        with two levels (1 and 2 cm) in the dam break of tests/test_adaptive_flow.py,
        refined within 0.1 m of the block, across the first splits (docs/dam-front.md,
        "How it came right"): with ``"spacing"`` the fluid's mechanical energy rose by
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
        two-level ones from +0.2 to +1.2 % in 2D; not explained yet (docs/dam-front.md).

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
                for mask in range(1, 2 ** self.dim):
                    ok, xr, sgn = b.domain_image(xi, h, mask)
                    if ok:       # d(x_image)/dx_i = diag(sgn)
                        r_img, g_img = self._fresh_density(xr, f, h2, c6, zero, zero, False)
                        rho += r_img
                        for k in ti.static(range(self.dim)):
                            grad[k] += sgn[k] * g_img[k]
                ok, xo, nrm = b.obstacle_image(xi, h)
                if ok:           # d(x_image)/dx_i = I − 2 n nᵀ
                    r_img, g_img = self._fresh_density(xo, f, h2, c6, 0.5 * (xi + xo), nrm, True)
                    rho += r_img
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
    def _fit_children(self, i, s_f):
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
                    base = self.pool.claim(self.nmax)
                    if base >= 0:
                        for q in range(self.nmax):
                            self._spawn_child(i, base + q, q, f, s_f)
                            self.pool.children[i, q] = base + q
                        p[i].nchild = self.nmax
                        p[i].kind = k | ROLE_PARENT
                elif not near and (k & ROLE_PARENT) != 0:
                    self._kill_virtual_children(i)

    @ti.func
    def _couple_fine(self, n, c):
        p = ti.static(self.pool.p)
        for i in range(n):
            k = p[i].kind
            # §6: near a real coarse particle, or (so that a region that is fine all
            # through can coarsen once nothing wants it fine) wanting the coarse level
            if is_real(k) and p[i].level == c - 1 and (k & ROLE_CHILD) == 0 and \
                    ((p[i].flags & NEAR_COARSE) != 0 or p[i].lam > c + self.hysteresis):
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
                    self.pool.children[vp, 0] = i
                    p[vp].kind = VIRTUAL_PARENT
                    p[i].parent = vp
                    p[i].kind = k | ROLE_CHILD

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
        keep = self.gather_span * self.release_factor * self._h(c - 1)
        for i in range(n):
            self.partner[i] = -1
            if p[i].kind == VIRTUAL_PARENT and p[i].level == c and p[i].nchild < self.nmax \
                    and self._may_gather(i, c):
                xi = p[i].x
                best, best_d2 = -1, reach * reach
                base = self.g.around(xi, c)
                for o in ti.grouped(ti.ndrange(*self.g.row_axes)):
                    lo, hi = self.g.row(base, o, c)
                    for j in range(lo, hi):
                        if j != i and p[j].kind == VIRTUAL_PARENT and \
                                p[i].nchild + p[j].nchild <= self.nmax and self._may_gather(j, c):
                            d2 = (xi - p[j].x).norm_sqr()
                            if d2 < best_d2 or (d2 == best_d2 and j < best):
                                if self._union_spread(i, j) <= keep:
                                    best, best_d2 = j, d2
                self.partner[i] = best

    @ti.func
    def _accept(self, n, c):
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
                ti.atomic_add(self.counters[EV_GATHERED], 1)

    @ti.func
    def _merge(self, n, c):
        p = ti.static(self.pool.p)
        for i in range(n):
            # a full group merges; a partial one of at least merge_min children only once
            # it can gather no more (no group within reach that it could take in; partner
            # is from the last gathering round). Half a group by default: in a film one
            # fine particle thick (the 3D dam break past its block) the 2^d nearest
            # particles span more than the release distance, so full groups never form
            # and, with full groups only, the film stayed fine for good (0 merges)
            k = p[i].nchild
            least = self.merge_min
            if ti.static(self.merge_remnants) and (p[i].flags & VP_ANCHORED) != 0:
                least = 1
            if p[i].kind == VIRTUAL_PARENT and p[i].level == c and \
                    (k == self.nmax or (k >= least and self.partner[i] == -1)) \
                    and p[i].lam > c + self.hysteresis and (p[i].flags & MUST_SPLIT) == 0:
                ok = True
                for q in range(p[i].nchild):
                    if (p[self.pool.children[i, q]].kind & ROLE_PARENT) != 0:
                        ok = False
                if ok:
                    mass = 0.0
                    for q in range(p[i].nchild):
                        mass += p[self.pool.children[i, q]].m
                    for fld in ti.static(self._fields(merge_mass_mean())):
                        acc = fld[i] * 0.0
                        for q in range(p[i].nchild):
                            ch = self.pool.children[i, q]
                            acc += p[ch].m * fld[ch]
                        fld[i] = acc / mass
                    for q in range(p[i].nchild):
                        ch = self.pool.children[i, q]
                        p[ch].kind = DEAD
                        p[ch].parent = -1
                        self.pool.children[i, q] = -1
                    p[i].m = mass
                    p[i].nchild = 0
                    p[i].parent = -1
                    p[i].kind = REGULAR
                    ti.atomic_add(self.counters[EV_MERGES], 1)

"""The compression a split puts on its children, kept out of their pressure
(``adaptivity.split_fade``;
METHOD.md §5.1–5.2).

A split puts 2^d children on the fine lattice of their parent's cell (``placement.py``
then spreads them), but coarse particles at rest are not on a lattice: in demo_2d's
pool, settled, one coarse particle in ten has a neighbour nearer than 0.62 of its
spacing, one in a hundred nearer than 0.41, and light ones (partial merges) fill less
than their cell. Their children then land closer than their spacing to each other's, and
read up to 1.6 ρ0 where the parent read ρ0. That is an error of the sampling, not a
compression of the fluid, but the pressure took it for one: a child at 1.24 ρ0 (the
99th percentile) pushed with 29 times the hydrostatic pressure at the bottom of the pool
(demo_2d's linear equation of state, k = 400 m²/s²), and a cursor entering resting
water threw it about. demo_2d at 2.5 s, a still cursor of radius 0.128 m refining
level 2 to 0 at (0.5, 0.12) (docs/validation.md, "A cursor in resting water"), 2.5 ms later:
1,638 of 6,144 particles above 1 m/s, the fastest at 11 m/s.

So each child carries ``drho``, what it reads above a reference density ``rho_ref``
(its parent's, ρ0 at least) at its first density pass, and its pressure (the equation
of state of ``wcsph``, the density solve of ``dfsph``) reads ρ − drho: the child starts
at its parent's pressure. At every later density pass ``drho`` follows the child's
density down, never above what it still reads over ``rho_ref``: as the children spread
out (the flow, the viscosity, their neighbours' pressure) the error goes without ever
having been a pressure, while a compression by the flow raises ρ − drho as it would
the density. ``drho`` also decays as exp(−t/τ), τ = ``adaptivity.split_fade`` (the
demos: 1 s), so that children that never spread (a pair stuck together) let it in at
last, slowly. Mass and momentum are untouched (the pair forces stay antisymmetric).

Off by default (τ = 0): every variant below ran the 3D dam break's front ahead of the
uniform run's by more than without it, and the one that stayed within the test's 5 %
(+3.8 %) leaves a deep child's share of the weight out of its pressure. The scenes
whose mouse refines resting water (``disturbance`` criteria: demo_2d, demo_3d) set it.

What was measured (``python3 tools/cursor_burst.py --set adaptivity.split_fade=…`` for
the cursor; the 3D dam break refined near a block of tests/test_adaptive_flow.py, its
front at 1 s against the uniform run's 1.578 m, +1.6 % without any of this):

- the offset measured against the parent's density and only decayed, τ = 0.02 s: 17
  particles above 1 m/s 2.5 ms after the cursor came; but the dam-break front +22.8 %.
  The offset only delays the error's pressure, and in a flow the delayed push went
  downstream. τ = 0.01 s: 29 above 1 m/s; 0.05 s: 10. Against ρ0 at least (a parent
  in a thin sheet reads less than ρ0 for want of neighbours, which its children's
  smaller kernel is less short of): +7.8 % (τ = 0.02 s), +11.3 % (0.005 s). Only where
  the parent read ρ0 or more: the burst back (719 above 1 m/s) and +12.3 %;
- followed down as the child's density falls, τ = 0.02 s: +7.0 %; τ = 1 s, the
  reference ρ0: +3.8 % (2D: +0.4 %), 8 above 1 m/s; τ = 1 s, the reference the
  parent's density (ρ0 at least; what is built): +10.8 %, 25 above 1 m/s at 2.5 ms, 1
  at 10 ms, none after, the mean speed back to 0.027 m/s at 100 ms. The reference is the
  parent's density, not ρ0, so that a child deep in a pool keeps its share of the
  weight above it: against ρ0 it would carry none until the offset decayed.

A merge is the same in reverse: the merged particle sits at its group's centre of mass,
which need not be where the coarse fluid has room for it. Its reference is what its
group's pressure read: the children's mass-weighted ρ − drho (ρ0 at least), and a
split's children's is what their parent's read, ρ − drho, so that an offset is handed on
rather than dropped when a particle changes level. demo_2d, the cursor above taken away
after 100 ms (``cursor_burst.py --leave``), 2.5 ms later: 336 particles above 1 m/s, the
fastest at 6.5 m/s, with the splits' offset only; 23, and 4.0 m/s, with the merges' too
(their reference then the group's raw mean density). Held at the window's strength and
let go (``--strength 20``), the children still carried their splits' offsets, and
against their raw density the merged particles took that in full: the kinetic energy
peaked at 44-52 J within 20 ms, at four places and times; against ρ − drho at 19-44 J,
21 J on the median (docs/validation.md, "A cursor in resting water").

The particles around a change of level see it too: a merge puts the group's mass at
its centre where the coarse neighbours saw a virtual parent (whose mass the limiter may
have scaled down), an absorption makes a coarse particle heavier, a new or gathered
virtual parent adds mass to the coarse level, a split or new virtual children to the
fine one. So every real particle within h_c of such an event (``touch``, ``changed``,
``remeasure_touched``) re-measures its offset at the next density pass
against what its pressure read until then (``remeasure``): its pressure does not rise
from the pass alone. Without it the offset of a particle was measured once, at its
birth, and only followed down, so a rise after that (its neighbours merging a pass
later, the coupling arriving) went into its pressure in full: level-1 particles of
0.6-0.9 nominal mass read 1.15-1.24 ρ0 with no offset left, and the release of the held
cursor above still peaked at 19-44 J. With it: 3.7-5.8 J, the fastest particle 1.7 m/s.
In demo_2d's opening stir (0.4-4 s) the offsets kept out of the pressure average
0.01-0.14 % of ρ0 (0-0.08 % before); the mean density is unchanged (0.99-1.00 ρ0).

What the pressure reads is what the passes between two density passes read too
(``seen``): the split's reference, a merge's, and the virtual-mass limiter's target
(``limiter.py``), which bounds a fine particle's density by its coarse neighbours'. Read
raw, a coarse particle with a large offset (1.17 ρ0, 0.17 ρ0 of it offset) let its
virtual children carry their whole mass onto a fine particle between them, which read
1.20 ρ0 with no offset of its own, and the density solve pushed it at 1 MPa. demo_2d,
the cursor's refinement dragged through the resting pool along twelve paths
(docs/validation.md, "A cursor in resting water"): the kinetic energy's
peak 36 J on the median, up to 5979 J, before; 13 J, up to 40 J, with this and the
placement's kept centre of mass (``placement.py``), each of which alone left peaks of
176-267 J.

The offset is measured, not computed at the split, because the children's neighbours are
only all known at the next density pass: a split marks each child with ``born``
(``drho`` = −1, a value no measured offset takes), and the density pass's ``measured``
turns it into the excess.
"""

import taichi as ti

from mrsph.sph.particles import is_real

# ``touched`` bits during an adaptivity pass's level pair (c − 1, c)
REMEASURE = 1  # a real particle whose neighbourhood changed
FINER_CHANGED = 2  # a level-c particle that split or took virtual children: the level-f
# particles within h_c see more mass


@ti.data_oriented
class SplitFade:
    """``drho`` and ``rho_ref`` of the particle pool: set at a split, measured and
    followed at every density pass, read by the pressure, decayed by the integrator. Off
    (every function a no-op, every ``drho`` 0) without adaptivity or with ``split_fade``
    = 0."""

    ATTRIBUTES = ("drho", "rho_ref")  # the pool's attributes it alone reads

    def __init__(self, core, adaptivity):
        self.pool, self.g, self.lev = core.pool, core.grids, core.lev
        self.rest_density = core.lev.rest_density
        self.tau = adaptivity.split_fade if core.adaptive else 0.0
        self.on = self.wanted(adaptivity, core.adaptive)
        # particles whose neighbourhood an adaptivity pass changed (topology.py)
        self.touched = ti.field(ti.i32, shape=self.pool.capacity if self.on else 1)

    @staticmethod
    def wanted(adaptivity, adaptive: bool) -> bool:
        """Whether a run of ``scene`` fades its splits' compression (else its attributes
        are never read, and the sort need not move them)."""
        return adaptive and adaptivity.split_fade > 0.0

    @classmethod
    def unused(cls, adaptivity, adaptive: bool) -> tuple:
        """The pool's attributes that no pass of a run of ``scene`` reads: the fade's own
        when it is off, which a sort then leaves where they are (two floats of 17 a
        particle: ~4 % of a uniform 10k step when moved, docs/performance.md)."""
        return () if cls.wanted(adaptivity, adaptive) else cls.ATTRIBUTES

    @ti.func
    def born(self, ch, parent_rho):
        """Child ``ch`` of a split whose parent read ``parent_rho`` (or a merged particle
        whose group read that on average): its reference is that density, ρ0 at least;
        its excess is measured at its first density pass."""
        p = ti.static(self.pool.p)
        if ti.static(self.on):
            p[ch].rho_ref = ti.max(parent_rho, ti.static(self.rest_density))
            p[ch].drho = -1.0
        else:
            p[ch].drho = 0.0

    @ti.func
    def touch(self, x, c):
        """A level-c particle appeared, went or grew at x (a merge, an absorption, a new
        or gathered virtual parent): the real level-c particles within h_c are
        re-measured at the end of the pass (``remeasure_touched``)."""
        if ti.static(self.on):
            p = ti.static(self.pool.p)
            hc = self.lev.h[c]
            base = self.g.around(x, c)
            for o in ti.grouped(ti.ndrange(*self.g.row_axes)):
                lo, hi = self.g.row(base, o, c)
                for j in range(lo, hi):
                    if p[j].level == c and is_real(p[j].kind) and (x - p[j].x).norm_sqr() < hc * hc:
                        ti.atomic_or(self.touched[j], REMEASURE)

    @ti.func
    def changed(self, i):
        """Level-c particle i split or took virtual children: the real level-(c − 1)
        particles within h_c are re-measured at the end of the pass."""
        if ti.static(self.on):
            ti.atomic_or(self.touched[i], FINER_CHANGED)

    @ti.func
    def remeasure_touched(self, n, c):
        """End of the level pair (c − 1, c): every real particle touched, and every real
        level-(c − 1) one within h_c of a level-c one that ``changed``, re-measures its
        offset (``remeasure``); the marks are cleared."""
        if ti.static(self.on):
            p = ti.static(self.pool.p)
            hc = self.lev.h[c]
            for i in range(n):
                if is_real(p[i].kind) and p[i].level == c - 1 and self.touched[i] == 0:
                    xi = p[i].x
                    base = self.g.around(xi, c)
                    for o in ti.grouped(ti.ndrange(*self.g.row_axes)):
                        lo, hi = self.g.row(base, o, c)
                        for j in range(lo, hi):
                            if (self.touched[j] & FINER_CHANGED) != 0 and (xi - p[j].x).norm_sqr() < hc * hc:
                                self.touched[i] = REMEASURE
            for i in range(n):
                t = self.touched[i]
                if t != 0:
                    self.touched[i] = 0
                    if (t & REMEASURE) != 0 and is_real(p[i].kind):
                        self.remeasure(i)

    @ti.func
    def group_seen(self, i):
        """Σ m (ρ − drho) over virtual parent i's children: the density their pressure
        read, mass-weighted (the caller divides by the group's mass)."""
        p = ti.static(self.pool.p)
        acc = 0.0
        for q in range(p[i].nchild):
            ch = self.pool.children[i, q]
            acc += p[ch].m * self.seen(ch)
        return acc

    @ti.func
    def remeasure(self, i):
        """Particle i's neighbourhood changed (a split, merge or new coupling within its
        support): whatever its density does at the next pass is measured as a change of
        sampling, against what its pressure read until now (ρ0 at least). Not for one
        made in this pass (its reference is set)."""
        p = ti.static(self.pool.p)
        if ti.static(self.on):
            d = p[i].drho
            if d >= 0.0:
                p[i].rho_ref = ti.max(p[i].rho - d, ti.static(self.rest_density))
                p[i].drho = -1.0

    @ti.func
    def clear(self, i):
        """A particle made otherwise (seeded, emitted, virtual)."""
        self.pool.p[i].drho = 0.0

    @ti.func
    def measured(self, i, rho):
        """Particle i's density pass found ``rho``: a child's first sets its excess over
        its reference, every later one lowers it to what is left of that excess."""
        p = ti.static(self.pool.p)
        if ti.static(self.on):
            d = p[i].drho
            if d != 0.0:
                over = ti.max(rho - p[i].rho_ref, 0.0)
                p[i].drho = over if d < 0.0 else ti.min(d, over)

    @ti.func
    def excess(self, i):
        """What particle i's pressure does not count of its density."""
        d = 0.0
        if ti.static(self.on):
            d = ti.max(self.pool.p[i].drho, 0.0)
        return d

    @ti.func
    def seen(self, i):
        """The density particle i's pressure read at its last density pass, ρ − drho; while
        a re-measure is pending (a split's child, or a particle ``touch``ed in this
        adaptivity pass: drho = −1 until the next density pass) its reference, which is
        what its pressure will read of any rise. The adaptivity pass and the virtual-mass
        limiter, which run between density passes, read this and not ρ − ``excess``:
        a pending particle's raw density may hold an offset not yet re-measured (a
        coarse particle at 1.17 ρ0 with 0.17 ρ0 of offset let the limiter give its virtual
        children their whole mass, and a fine particle between them went to 1.20 ρ0)."""
        p = ti.static(self.pool.p)
        r = p[i].rho
        if ti.static(self.on):
            d = p[i].drho
            r = p[i].rho_ref if d < 0.0 else p[i].rho - d
        return r

    @ti.func
    def decay(self, i, dt):
        """One step of d(drho)/dt = −drho/τ (explicit, dt ≪ τ)."""
        if ti.static(self.on):
            d = self.pool.p[i].drho
            if d > 0.0:
                self.pool.p[i].drho = d * ti.max(1.0 - dt / ti.static(self.tau), 0.0)

"""Absorption, step 8 of the adaptivity pass (``topology.py``): a group that would merge
into a particle lighter than ``adaptivity.absorb_below`` (half) of its level's nominal
mass is given instead to the nearest real particle of that level within ``ABSORB_REACH``
of its support, which takes its mass and mass-weighted means (up to ``ABSORB_CAP`` times
nominal) and keeps its place; with no such neighbour the group stays fine.

Without it, partial merges made light coarse particles, their splits light children, and
those merged lighter still: under a strong stir the median particle fell to 0.21-0.50 of
its level's mass and the pool filled (docs/performance.md, the mass cascade). With it
every real particle stays within [1/2, 2] of its level's nominal mass.

The receiver may be of any real kind. The coarse particles round a remnant are transient
parents, made so by the remnant itself, so with regular receivers only, a lone fine
particle stayed fine for good: demo_2d after a drag, where its level's density read above
ρ0 at the centre of a coarse particle's virtual children and the DFSPH density solve
pumped it to megapascals (docs/METHOD.md §15).

A light group caged inside a real coarse particle (``caged``) is given away whatever the
criteria want: a fine particle at the centre of a coarse particle's virtual children is
held there by them (their pushes cancel at the centre and come back to their owner, which
moves with it), its density reads above ρ0 and no pressure can lower it. In the stirred
demo under dfsph its pressure rose to 0.5 GPa, held at the criteria's hysteresis band, and
the pressure's time-step bound took the step from 0.2 ms to 2 µs (docs/validation.md,
"Stirred soak")."""

import taichi as ti

from mrsph.sph.particles import DEAD, ROLE_CHILD, is_real, merge_mass_mean

# A particle that takes a light group stays within this multiple of its level's nominal
# mass, so that absorption cannot make arbitrarily heavy particles.
ABSORB_CAP = 2.0
# ... and is within this share of its support (half: one coarse spacing) of the group's
# virtual parent. The group's mass and momentum jump to the receiver: from as far as a
# whole support, a film's light groups fed the coarse particles at its tip, which ran
# ahead as a carpet of single particles. The 3D dam-break front at 1 s over seven CFL
# numbers (tools/dam_front.py): +8.6 % on average, up to +19.9 %, at a whole support;
# +0.2 %, -0.4 .. +0.8 % at half (docs/METHOD.md §15).
ABSORB_REACH = 0.5
# A light group's virtual parent within this many fine spacings of a real coarse particle
# is caged in it: that particle's virtual children stand sqrt(d)/2 fine spacings from it.
CAGE_REACH = 0.5


@ti.data_oriented
class Absorption:
    """The light groups of one level pair's merge (``takes``), then given away (``run``)."""

    def __init__(self, core, adaptivity, fade, counters, merged: int, absorbed: int):
        """counters: the topology's event counters, ``merged`` and ``absorbed`` the two
        this counts in (an absorption is a merge too)."""
        self.pool, self.g, self.lev, self.fade = core.pool, core.grids, core.lev, fade
        self.below = adaptivity.absorb_below
        self.on = self.below > 0.0  # 0: light groups merge like any other
        # the receiver takes the group's mass-weighted means but keeps its place (moved,
        # receivers at a 3D dam-break front were pulled onto the remnants ahead of them:
        # the front ran 11 % ahead of the uniform run's, 1.6 % when they stay)
        self.means = [a for a in merge_mass_mean() if a != "x"]
        self.queue = ti.field(ti.i32, shape=self.pool.capacity)
        self.queued = ti.field(ti.i32, shape=())
        self.counters, self.merged, self.absorbed = counters, merged, absorbed

    @ti.func
    def takes(self, i, c):
        """Whether virtual parent i's group (level c − 1) is too light to merge on its
        own; if so it is queued for ``run``."""
        light = self._light(i, c)
        if light:
            self.queue[ti.atomic_add(self.queued[None], 1)] = i
        return light

    @ti.func
    def _light(self, i, c):
        return self.pool.group_mass(i) < ti.static(self.below) * self.lev.m[c]

    @ti.func
    def caged(self, i, c):
        """Whether virtual parent i's group (level c − 1) is light and sits inside a real
        level-c particle, within ``CAGE_REACH`` fine spacings of it: to be given away
        whatever the criteria want (module docstring)."""
        out = False
        if self._light(i, c):
            r = ti.static(CAGE_REACH) * self.lev.s[c - 1]
            ctx = ti.Vector([ti.cast(c, ti.f64)], ti.f64)
            out = self.g.nearest(self.pool.p[i].x, c, r * r, self.pool.p.x, self._is_real_at, ctx) >= 0
        return out

    @ti.func
    def _is_real_at(self, j, ctx):
        return is_real(self.pool.p[j].kind) and self.pool.p[j].level == ti.cast(ctx[0], ti.i32)

    @ti.func
    def _may_receive(self, j, ctx):
        """Whether j may take a light group (ctx: level c, the group's mass, the cap)."""
        p = ti.static(self.pool.p)
        return (
            is_real(p[j].kind) and p[j].level == ti.cast(ctx[0], ti.i32) and ti.cast(p[j].m, ti.f64) + ctx[1] <= ctx[2]
        )

    @ti.func
    def run(self, c):
        """Each queued group goes to its nearest real level-c particle within reach. One
        thread, in the order queued, so that two groups never fill one receiver past
        ``ABSORB_CAP``."""
        p = ti.static(self.pool.p)
        h = ti.static(ABSORB_REACH) * self.lev.h[c]
        cap = ti.static(ABSORB_CAP) * self.lev.m[c]
        ti.loop_config(serialize=True)
        for q in range(self.queued[None]):
            i = self.queue[q]
            group = self.pool.group_mass(i)
            ctx = ti.Vector([ti.cast(c, ti.f64), group, cap], ti.f64)
            best = self.g.nearest(p[i].x, c, h * h, p.x, self._may_receive, ctx)
            if best >= 0:
                total64 = ti.cast(p[best].m, ti.f64) + group
                total = ti.cast(total64, float)
                for fld in ti.static([getattr(p, name) for name in self.means]):
                    acc = p[best].m * fld[best]
                    for k in range(p[i].nchild):
                        ch = self.pool.children[i, k]
                        acc += p[ch].m * fld[ch]
                    fld[best] = acc / total
                p[best].m = total
                if (p[best].kind & ROLE_CHILD) != 0:  # its virtual parent weighs its group
                    vp = p[best].parent
                    p[vp].m = ti.cast(self.pool.group_mass(vp), float)
                self.fade.touch(p[best].x, c)
                self.pool.drop_children(i)
                p[i].kind = DEAD
                p[i].parent = -1
                ti.atomic_add(self.counters[self.merged], 1)
                ti.atomic_add(self.counters[self.absorbed], 1)
        self.queued[None] = 0

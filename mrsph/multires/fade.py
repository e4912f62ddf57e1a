"""The compression a split puts on its children, faded out (``adaptivity.split_fade``;
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
level 2 to 0 at (0.5, 0.12) (docs/performance.md, "Found in session 32"), 2.5 ms later:
1,638 of 6,144 particles above 1 m/s, the fastest at 11 m/s; with τ = 0.02 s, 17 and
1.65 m/s.

So each child carries ``drho``, the density it reads above its parent's at its first
density pass, and the pressure (the equation of state of ``wcsph``, the density solve of
``dfsph``) reads ρ − drho: the child starts at its parent's pressure, and ``drho`` decays
as exp(−t/τ), τ = ``adaptivity.split_fade``, so the fluid takes the sampling error out
over τ, through its own pressure, instead of in one step. Mass and momentum are
untouched (the pair forces stay antisymmetric); only the pressure's density is offset,
and only by an excess: a child that reads less than its parent keeps 0.

Why τ = 0.02 s: the same cursor (``python3 tools/cursor_burst.py --set
adaptivity.split_fade=τ``), the particles above 1 m/s and the mean speed 2.5, 20 and 100
ms later:
τ = 0.01 s: 29, 0 and 0 above 1 m/s, mean 0.116, 0.060, 0.028 m/s; 0.02 s: 17, 0, 0 and
0.080, 0.090, 0.056; 0.05 s: 10, 2, 0 and 0.058, 0.117, 0.038. Under dfsph, whose burst
comes later (0 above 1 m/s at 2.5 ms, 111 at 10 ms without the fade), 0.01 s left the
pool stirred at 50 ms (1,963 particles above 0.3 m/s) and 0.02 s did not (78). A longer
τ leaves a child softer for longer in a flow that compresses it; 0.02 s is some 25
steps of demo_2d.

The offset is measured, not computed at the split, because the children's neighbours are
only all known at the next density pass: a split marks each child with ``born`` (−ρ of
its parent, a negative value no measured offset takes), and the density pass's
``measured`` turns it into the excess.
"""

import taichi as ti


@ti.data_oriented
class SplitFade:
    """``drho`` of the particle pool: set at a split, measured at the next density pass,
    read by the pressure, decayed by the integrator. Off (every function a no-op, every
    ``drho`` 0) without adaptivity or with ``split_fade`` = 0."""

    def __init__(self, parts):
        a = parts.scene["adaptivity"]
        self.pool = parts.pool
        self.tau = float(a["split_fade"]) if parts.adaptive else 0.0
        self.on = self.tau > 0.0

    @ti.func
    def born(self, ch, parent_rho):
        """Child ``ch`` of a split whose parent read ``parent_rho``."""
        self.pool.p[ch].drho = -parent_rho if ti.static(self.on) else 0.0

    @ti.func
    def clear(self, i):
        """A particle made otherwise (seeded, emitted, merged, virtual)."""
        self.pool.p[i].drho = 0.0

    @ti.func
    def measured(self, i, rho):
        """Particle i's density pass found ``rho``: a child's first, its excess over its
        parent's."""
        if ti.static(self.on):
            d = self.pool.p[i].drho
            if d < 0.0:
                self.pool.p[i].drho = ti.max(rho + d, 0.0)

    @ti.func
    def excess(self, i):
        """What particle i's pressure does not count of its density."""
        d = 0.0
        if ti.static(self.on):
            d = ti.max(self.pool.p[i].drho, 0.0)
        return d

    @ti.func
    def decay(self, i, dt):
        """One step of d(drho)/dt = −drho/τ (explicit, dt ≪ τ)."""
        if ti.static(self.on):
            d = self.pool.p[i].drho
            if d > 0.0:
                self.pool.p[i].drho = d * ti.max(1.0 - dt / ti.static(self.tau), 0.0)

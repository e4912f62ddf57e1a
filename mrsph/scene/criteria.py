"""Refinement criteria (METHOD.md §7): where the fluid should be fine.

Each criterion maps a position to a *wanted level* λ, a real number: ``level`` inside its
zone, growing by one per ``adaptivity.band`` metres away from it, so that the wanted
resolution is graded and never jumps by two levels across a support radius. Criteria are
combined by taking the finest (the minimum). Far from every criterion λ is
``background_level + ½``: there particles of the background level neither split
(λ < ℓ − η) nor merge (λ > ℓ + 1 + η), groups of the level below merge into it
(λ > ℓ + η), and coarser particles split down to it, for any hysteresis η < ½. (Capping λ
at the background level itself would forbid every merge into it.)

A particle of level ℓ splits when λ < ℓ − η and a group may merge into level ℓ + 1 when
λ > ℓ + 1 + η, with η = ``adaptivity.hysteresis``: between the two thresholds nothing
happens, so particles do not flicker between levels.

Named criteria (``[[criteria]] type = ...``):
- ``region``: a box or sphere, optionally moving along a path of waypoints;
- ``obstacles``: within ``distance`` of any obstacle;
- ``disturbance``: inside any active disturbance (the mouse, a stirrer).
"""

import numpy as np
import taichi as ti

from mrsph.limits import MAX_CRITERIA

TYPES = {"region": 0, "obstacles": 1, "disturbance": 2}


@ti.data_oriented
class Criteria:
    def __init__(self, dim: int, specs: list, band: float, background: float, paths=None, first_path: int = 0):
        """``paths`` (``interaction.Paths``) holds, from ``first_path`` on, the path of
        each region that has one, in the order of ``specs``."""
        assert len(specs) <= MAX_CRITERIA, "too many criteria (the scene check refuses them)"
        self.dim = dim
        self.specs = specs
        self.count = len(specs)
        n = max(1, self.count)
        self.type = ti.field(ti.i32, shape=n)
        self.level = ti.field(float, shape=n)
        self.sphere = ti.field(ti.i32, shape=n)
        self.center = ti.Vector.field(dim, float, shape=n)
        self.half = ti.Vector.field(dim, float, shape=n)
        self.radius = ti.field(float, shape=n)
        self.distance = ti.field(float, shape=n)
        self.band = ti.field(float, shape=())
        self.background = ti.field(float, shape=())
        self.band[None] = band
        self.background[None] = background
        self.paths, self.first_path = paths, first_path
        moving = [i for i, s in enumerate(specs) if s.type == "region" and s.path]
        self.moving = len(moving)
        shape = max(self.moving, 1)
        # a moving region's centre is (its centre as written + the path's position) −
        # the path's first waypoint, summed in that order in f64 as the scene reads
        self.moving_index = ti.field(ti.i32, shape=shape)
        self.moving_base = ti.Vector.field(dim, ti.f64, shape=shape)
        self.moving_first = ti.Vector.field(dim, ti.f64, shape=shape)
        for r, i in enumerate(moving):
            self.moving_index[r] = i
            self.moving_first[r] = [float(v) for v in specs[i].path[0][1:]]
        for i, s in enumerate(specs):
            self.type[i] = TYPES[s.type]
            self.level[i] = float(s.level)
            if s.type == "region":
                if s.shape == "sphere":
                    c = np.asarray(s.center, float)
                    self.sphere[i] = 1
                    self.radius[i] = s.radius
                else:
                    lo, hi = np.asarray(s.min, float), np.asarray(s.max, float)
                    c = (lo + hi) / 2
                    self.half[i] = ((hi - lo) / 2).tolist()
                self.center[i] = c.tolist()
                if i in moving:
                    self.moving_base[moving.index(i)] = c.tolist()
            elif s.type == "obstacles":
                self.distance[i] = s.distance

    def update(self, t: float) -> None:
        """Move regions that follow a path to their place at time t (one launch)."""
        if self.moving:
            self._follow(self.paths, self.first_path, t)

    @ti.kernel
    def _follow(self, paths: ti.template(), first: ti.i32, t: ti.f64):
        for r in range(self.moving):
            pos, _vel = paths.sample(first + r, t)
            self.center[self.moving_index[r]] = ti.cast(self.moving_base[r] + pos - self.moving_first[r], float)

    @ti.func
    def wanted(self, x, boundary: ti.template(), disturbances: ti.template()):
        """λ(x): the finest level wanted at x by any criterion (graded by distance)."""
        band = self.band[None]
        lam = self.background[None] + 0.5
        for c in range(self.count):
            d = 1e30
            t = self.type[c]
            if t == 0:
                rel = x - self.center[c]
                if self.sphere[c]:
                    d = ti.max(rel.norm() - self.radius[c], 0.0)
                else:
                    d = ti.max(ti.abs(rel) - self.half[c], 0.0).norm()
            elif t == 1:
                phi, _n = boundary.obstacle_sdf(x)
                d = ti.max(phi - self.distance[c], 0.0)
            else:
                d = disturbances.distance(x)
            lam = ti.min(lam, self.level[c] + d / band)
        return ti.max(lam, 0.0)

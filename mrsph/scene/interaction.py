"""Disturbances: the mouse and scripted stirrers, as data plus the kernel that applies them.

A :class:`Disturbance` is what the window (or a scene's ``[[stirrers]]``) hands to the
solver: a centre, a radius, a strength (a rate, 1/s) and a mode. Inside the radius, with
weight w = (1 − (r/R)²)², it adds the acceleration

- push: a = strength · w · (u_d − u), driving the fluid toward the disturbance's own
  velocity u_d (the mouse's drag velocity), so a drag pushes the fluid along the drag;
- pull: a = strength · w · (strength · (c − x) − u), driving the fluid toward the centre.

Both are relaxations toward a target velocity, stable for strength · dt < 1, which the
solver's time step respects. The ``disturbance`` refinement criterion refines inside the
radius of every active disturbance.
"""

import math
from dataclasses import dataclass, field

import numpy as np
import taichi as ti

from mrsph.limits import MAX_STIRRERS

MAX_DISTURBANCES = 1 + MAX_STIRRERS  # slot 0 is the mouse's, the others the scene's stirrers
MOUSE_SLOT = 0
MODES = ("push", "pull")


@dataclass
class Disturbance:
    center: tuple
    radius: float
    strength: float
    mode: str = "push"
    velocity: tuple = field(default=())

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"Disturbance.mode: expected push or pull (got {self.mode!r})")
        if not all(math.isfinite(c) for c in self.center):
            raise ValueError(f"Disturbance.center: expected finite numbers (got {self.center})")
        if not (math.isfinite(self.radius) and self.radius > 0):
            raise ValueError(f"Disturbance.radius: expected a finite number > 0 (got {self.radius})")
        if not (math.isfinite(self.strength) and self.strength >= 0):
            raise ValueError(f"Disturbance.strength: expected a finite number >= 0 (got {self.strength})")
        if len(self.velocity) not in (0, len(self.center)) or not all(math.isfinite(c) for c in self.velocity):
            raise ValueError(
                f"Disturbance.velocity: expected () or {len(self.center)} finite "
                f"numbers, as many as the centre has (got {self.velocity})"
            )


def path_sample(path, t: float, loop: bool):
    """Position and velocity at time t along waypoints [[t, x, y(, z)], ...] (linear)."""
    pts = np.asarray(path, dtype=np.float64)
    times, xs = pts[:, 0], pts[:, 1:]
    if loop and times[-1] > times[0]:
        t = times[0] + (t - times[0]) % (times[-1] - times[0])
    if t <= times[0]:
        return xs[0], np.zeros(xs.shape[1])
    if t >= times[-1]:
        return xs[-1], np.zeros(xs.shape[1])
    k = int(np.searchsorted(times, t, side="right")) - 1
    a = (t - times[k]) / (times[k + 1] - times[k])
    vel = (xs[k + 1] - xs[k]) / (times[k + 1] - times[k])
    return xs[k] + a * (xs[k + 1] - xs[k]), vel


@ti.data_oriented
class Paths:
    """Waypoint paths on the device, sampled as :func:`path_sample` samples them (in
    f64), so that stirrers and moving regions follow theirs with one launch and no field
    written from Python. ``paths``: (waypoints [[t, x, y(, z)], ...], loop) pairs."""

    def __init__(self, dim: int, paths: list):
        self.dim = dim
        self.count = len(paths)
        width = max([len(w) for w, _ in paths] + [1])
        shape = (max(self.count, 1), width)
        self.times = ti.field(ti.f64, shape=shape)
        self.points = ti.Vector.field(dim, ti.f64, shape=shape)
        self.length = ti.field(ti.i32, shape=shape[0])
        self.loop = ti.field(ti.i32, shape=shape[0])
        times, points = np.zeros(shape), np.zeros(shape + (dim,))
        length, loop = np.ones(shape[0], np.int32), np.zeros(shape[0], np.int32)
        for k, (waypoints, looped) in enumerate(paths):
            w = np.asarray(waypoints, np.float64)
            times[k, : len(w)], points[k, : len(w)] = w[:, 0], w[:, 1:]
            length[k], loop[k] = len(w), int(looped)
        self.times.from_numpy(times)
        self.points.from_numpy(points)
        self.length.from_numpy(length)
        self.loop.from_numpy(loop)

    @ti.func
    def sample(self, k, t):
        """Position and velocity of path k at time t (f64): linear between waypoints,
        at rest before the first and after the last, repeated if it loops."""
        n = self.length[k]
        t0, t1 = self.times[k, 0], self.times[k, n - 1]
        s = t
        if self.loop[k] and t1 > t0:
            s = t0 + (s - t0) % (t1 - t0)  # floored, as Python's
        pos = self.points[k, 0]
        vel = ti.Vector.zero(ti.f64, self.dim)
        if s >= t1:
            pos = self.points[k, n - 1]
        elif s > t0:
            j = 0
            for q in range(n - 1):  # the last waypoint at or before s
                if self.times[k, q] <= s:
                    j = q
            span = self.times[k, j + 1] - self.times[k, j]
            step = self.points[k, j + 1] - self.points[k, j]
            vel = step / span
            pos = self.points[k, j] + (s - self.times[k, j]) / span * step
        return pos, vel


@ti.data_oriented
class Disturbances:
    """Device-side table of active disturbances."""

    def __init__(self, dim: int):
        self.dim = dim
        self.active = ti.field(ti.i32, shape=MAX_DISTURBANCES)
        self.center = ti.Vector.field(dim, float, shape=MAX_DISTURBANCES)
        self.velocity = ti.Vector.field(dim, float, shape=MAX_DISTURBANCES)
        self.radius = ti.field(float, shape=MAX_DISTURBANCES)
        self.strength = ti.field(float, shape=MAX_DISTURBANCES)
        self.pull = ti.field(ti.i32, shape=MAX_DISTURBANCES)
        self._host: list = [None] * MAX_DISTURBANCES

    def set(self, slot: int, d: Disturbance | None) -> None:
        """Write slot ``slot``; only what changed goes to the device."""
        if d == self._host[slot]:
            return
        self._host[slot] = None if d is None else Disturbance(**d.__dict__)
        if d is None:
            self.active[slot] = 0
            return
        if len(d.center) != self.dim:
            raise ValueError(f"Disturbance.center: expected {self.dim} numbers (got {d.center})")
        vel = d.velocity or (0.0,) * self.dim  # __post_init__: () or as long as the centre
        self.center[slot] = list(map(float, d.center))
        self.velocity[slot] = list(map(float, vel))
        self.radius[slot] = float(d.radius)
        self.strength[slot] = float(d.strength)
        self.pull[slot] = int(d.mode == "pull")
        self.active[slot] = 1

    def get(self, slot: int) -> Disturbance | None:
        return self._host[slot]

    @ti.kernel
    def follow(self, paths: ti.template(), first: ti.i32, count: ti.i32, t: ti.f64):
        self.follow_func(paths, first, count, t)

    @ti.func
    def follow_func(self, paths: ti.template(), first, count, t):
        """Move slots first … first + count − 1 to paths 0 … count − 1 at time t (their
        radius, strength and mode were ``set`` once; the host's copy keeps the centre
        it was set with)."""
        for k in range(count):
            pos, vel = paths.sample(k, t)
            self.center[first + k] = ti.cast(pos, float)
            self.velocity[first + k] = ti.cast(vel, float)

    def max_strength(self) -> float:
        return max((d.strength for d in self._host if d is not None), default=0.0)

    def any_active(self) -> bool:
        return any(d is not None for d in self._host)

    @ti.func
    def accel(self, x, v):
        a = ti.Vector.zero(float, self.dim)
        for s in range(MAX_DISTURBANCES):
            if self.active[s]:
                d = x - self.center[s]
                R = self.radius[s]
                q2 = d.norm_sqr() / (R * R)
                if q2 < 1.0:
                    w = (1.0 - q2) * (1.0 - q2)
                    k = self.strength[s]
                    target = self.velocity[s]
                    if self.pull[s]:
                        target = -k * d
                    a += k * w * (target - v)
        return a

    @ti.func
    def distance(self, x):
        """Distance from x to the nearest active disturbance's disc (0 inside), or 1e30."""
        best = 1e30
        for s in range(MAX_DISTURBANCES):
            if self.active[s]:
                best = ti.min(best, ti.max((x - self.center[s]).norm() - self.radius[s], 0.0))
        return best


@ti.data_oriented
class StirrerPaths:
    """The step's ``stirrers`` pass: the stirrers' disturbances to where their paths are at
    the end of the step (none when the step did not go)."""

    def __init__(self, disturbances: Disturbances, paths: Paths, count: int, state):
        """count: the stirrers (disturbance slots 1 … count, paths 0 … count − 1);
        state: the step's time, dt and outcome (``sph.step.StepState``)."""
        self.disturbances, self.paths, self.count, self.state = disturbances, paths, count, state

    @ti.kernel
    def run(self, n: ti.i32):
        self.run_func(n)

    @ti.func
    def run_func(self, n):
        # the count in the loop's bound, not an ``if`` around it, which would run the loop
        # on one thread
        st = self.state
        self.disturbances.follow_func(self.paths, 1, self.count * st.go[None], st.t[None] + st.dt[None])

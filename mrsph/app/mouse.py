"""Mouse -> ``Disturbance``: the state machine behind stirring the fluid, as pure logic.

The window feeds :meth:`MouseDisturbance.update` once per frame with the cursor in
world coordinates and the held buttons; it answers the disturbance to hand to
``sim.set_disturbance`` (None when nothing is held). No Taichi, no window: testable
with plain numbers.

Gestures
--------
* left drag: push; the disturbance moves with the cursor and drives the fluid toward
  the cursor's velocity (smoothed, so mouse jitter does not shake the fluid);
* right drag, or shift + left drag: pull toward the cursor;
* wheel: radius up / down by a constant factor, clamped.

Time and the speed cap
----------------------
``dt`` is *wall-clock* time: the drag velocity is the hand's velocity in metres per
wall second. (Per simulated second, a one-second swipe in 10x slow motion became a blow
ten times faster than the hand.) Both gestures are capped to ``max_speed``, by default
:func:`safe_speed`: a tenth of the fluid's sound speed c0 = sqrt(fluid.stiffness)
(``mrsph.eos.sound_speed``). Weakly compressible SPH holds density to ~1 % only while
the flow stays below Mach 0.1 (Monaghan 1994, "Simulating free surface flows with
SPH"); a faster push compresses the fluid and it splashes apart instead of moving along.
The push's target velocity is clipped to the cap; the pull's target, strength × distance
to the centre, is at most strength × radius, so the pull's strength is lowered until
that is within the cap.
"""

from __future__ import annotations

import math

import numpy as np

LEFT, RIGHT, MIDDLE, SHIFT = "left", "right", "middle", "shift"
# Taichi GGUI key names -> ours, so the window can pass what it reads directly.
_ALIASES = {"lmb": LEFT, "rmb": RIGHT, "mmb": MIDDLE, "shift": SHIFT, "left": LEFT, "right": RIGHT, "middle": MIDDLE}

#: Time constant of the exponential smoothing of the cursor velocity. 50 ms removes
#: per-frame jitter at 60 fps while a flick still reaches full speed within ~3 frames.
SMOOTHING_S = 0.05
#: Radius change per wheel notch (multiplicative, so it feels the same at any size).
WHEEL_FACTOR = 1.15
#: Default radius, clamps and speed limit relative to the largest domain side.
RADIUS_FRACTION = 0.08
RADIUS_MIN_FRACTION = 0.01
RADIUS_MAX_FRACTION = 0.5
#: A cursor that jumps (window re-entered, a dropped frame) would otherwise hand the
#: solver an absurd target velocity; clamp to this many domain sizes per second (where
#: no sound speed is known; see :func:`safe_speed`).
MAX_SPEED_DOMAINS_PER_S = 8.0
#: The mouse's speed cap as a fraction of the sound speed (Mach number): the weakly
#: compressible limit, density within ~1 % (module docstring).
SAFE_MACH = 0.1
DEFAULT_STRENGTH = 20.0  # 1/s; relaxes the fluid to the drag velocity in ~50 ms
STRENGTH_MAX = 100.0  # 1/s; the HUD slider's top, the soak's strongest setting


def safe_speed(stiffness: float | None, domain_min, domain_max) -> float:
    """The documented cap on the mouse's target speed, m/s: SAFE_MACH × sqrt(stiffness)
    (c0 of ``mrsph.eos.sound_speed``), and never above MAX_SPEED_DOMAINS_PER_S domain
    sizes per second; the latter alone when ``stiffness`` is None."""
    size = float(np.max(np.asarray(domain_max, float) - np.asarray(domain_min, float)))
    cap = MAX_SPEED_DOMAINS_PER_S * size
    if stiffness is not None and stiffness > 0:
        cap = min(cap, SAFE_MACH * math.sqrt(float(stiffness)))
    return cap


def _default_factory(**kwargs):
    # Imported lazily: mrsph.scene.interaction imports Taichi, this module must stay light.
    from mrsph.scene.interaction import Disturbance

    return Disturbance(**kwargs)


class MouseDisturbance:
    """Turns per-frame mouse state into a push / pull :class:`Disturbance`.

    ``radius`` (m) and ``strength`` (1/s) are plain attributes the HUD sliders write;
    ``radius`` is clamped to [radius_min, radius_max] on every update.
    ``max_speed`` (m/s) caps the push's target velocity and the pull's (see the module
    docstring); ``dt`` of :meth:`update` is wall-clock time.
    ``factory`` builds the disturbance (default: ``mrsph.scene.interaction.Disturbance``).
    """

    def __init__(
        self,
        dim: int,
        radius: float = 0.1,
        strength: float = DEFAULT_STRENGTH,
        radius_min: float = 0.01,
        radius_max: float = 1.0,
        max_speed: float = 10.0,
        smoothing: float = SMOOTHING_S,
        factory=None,
    ):
        if not 0 < radius_min <= radius_max:
            raise ValueError(f"radius clamps: expected 0 < radius_min <= radius_max (got {radius_min}, {radius_max})")
        self.dim = int(dim)
        self.radius_min, self.radius_max = float(radius_min), float(radius_max)
        self.radius = float(np.clip(radius, radius_min, radius_max))
        self.strength = float(strength)
        self.max_speed = float(max_speed)
        self.smoothing = float(smoothing)
        self.factory = factory or _default_factory
        self.reset()

    @classmethod
    def for_domain(cls, domain_min, domain_max, stiffness: float | None = None, **kwargs) -> MouseDisturbance:
        """Defaults scaled to the domain: radius 8 % of its largest side, clamps 1-50 %;
        speed cap :func:`safe_speed` of the fluid's stiffness (the window's settings)."""
        lo, hi = np.asarray(domain_min, float), np.asarray(domain_max, float)
        size = float(np.max(hi - lo))
        kwargs.setdefault("radius", RADIUS_FRACTION * size)
        kwargs.setdefault("radius_min", RADIUS_MIN_FRACTION * size)
        kwargs.setdefault("radius_max", RADIUS_MAX_FRACTION * size)
        kwargs.setdefault("max_speed", safe_speed(stiffness, lo, hi))
        return cls(len(lo), **kwargs)

    def reset(self) -> None:
        """Forget the drag in progress (button released, scene switched)."""
        self._prev = None
        self._velocity = np.zeros(self.dim)
        self._mode = None
        self.current = None

    @property
    def active(self) -> bool:
        return self.current is not None

    @staticmethod
    def mode_for(buttons) -> str | None:
        """ "push", "pull" or None for a set of held buttons / modifiers."""
        held = {_ALIASES.get(str(b).lower(), str(b).lower()) for b in buttons}
        if RIGHT in held or (LEFT in held and SHIFT in held):
            return "pull"
        if LEFT in held:
            return "push"
        return None

    def scroll(self, wheel: float) -> None:
        """Wheel notches (positive = up = larger radius)."""
        if wheel:
            self.radius = self.radius * WHEEL_FACTOR ** float(wheel)
        self.radius = float(np.clip(self.radius, self.radius_min, self.radius_max))

    def update(self, cursor_world_pos, buttons, dt: float, wheel: float = 0):
        """One frame: cursor position in world units (None = outside the view), held
        buttons (``{"left"}``, ``{"right"}``, ``{"left", "shift"}``, Taichi's "LMB",
        "RMB", "Shift" also accepted), wall-clock time since the last update dt (s),
        wheel notches.
        Returns the disturbance to apply, or None."""
        self.scroll(wheel)
        mode = self.mode_for(buttons)
        if mode is None or cursor_world_pos is None:
            self.reset()
            return None
        pos = np.asarray(cursor_world_pos, dtype=np.float64).reshape(-1)[: self.dim]
        if mode != self._mode:
            # A new drag (or a switch between push and pull) starts at rest: the cursor's
            # history belongs to the other gesture.
            self._prev, self._velocity = None, np.zeros(self.dim)
        if mode == "push" and self._prev is not None and dt > 0:
            raw = (pos - self._prev) / dt
            speed = float(np.linalg.norm(raw))
            if speed > self.max_speed:
                raw *= self.max_speed / speed
            alpha = 1.0 - math.exp(-dt / self.smoothing) if self.smoothing > 0 else 1.0
            self._velocity = self._velocity + alpha * (raw - self._velocity)
        self._prev, self._mode = pos, mode
        velocity = self._velocity if mode == "push" else np.zeros(self.dim)
        strength = float(self.strength)
        if mode == "pull" and strength * self.radius > self.max_speed:
            strength = self.max_speed / self.radius  # target speed at the rim = the cap
        self.current = self.factory(
            center=tuple(float(c) for c in pos),
            radius=float(self.radius),
            strength=strength,
            mode=mode,
            velocity=tuple(float(c) for c in velocity),
        )
        return self.current


# ----------------------------------------------------------------------------- 3D picking
def ray_plane(ray_origin, ray_dir, plane_point, plane_normal):
    """Intersection of a ray with a plane, or None when parallel or behind the origin."""
    o, d = np.asarray(ray_origin, float), np.asarray(ray_dir, float)
    p, n = np.asarray(plane_point, float), np.asarray(plane_normal, float)
    denom = float(d @ n)
    if abs(denom) < 1e-12:
        return None
    t = float((p - o) @ n) / denom
    return o + t * d if t >= 0 else None


def ray_box(ray_origin, ray_dir, box_min, box_max):
    """(t_near, t_far) of a ray against an axis-aligned box (slab method), or None."""
    o, d = np.asarray(ray_origin, float), np.asarray(ray_dir, float)
    lo, hi = np.asarray(box_min, float), np.asarray(box_max, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1, t2 = (lo - o) * inv, (hi - o) * inv
    # A zero direction component: the slab is hit everywhere or nowhere.
    parallel = d == 0
    inside = (o >= lo) & (o <= hi)
    t1 = np.where(parallel, np.where(inside, -np.inf, np.inf), t1)
    t2 = np.where(parallel, np.inf, t2)
    t_near = float(np.max(np.minimum(t1, t2)))
    t_far = float(np.min(np.maximum(t1, t2)))
    if t_near > t_far or t_far < 0:
        return None
    return t_near, t_far


def pick_point(ray_origin, ray_dir, box_min, box_max, fallback_plane_point, plane_normal=None):
    """The 3D point under the mouse: where the ray enters the fluid's bounding box, else
    where it crosses the plane through ``fallback_plane_point`` facing the camera
    (normal ``plane_normal``, default the ray direction). Never None: when even the
    plane is missed (ray parallel or pointing away) the plane point itself is returned.
    """
    o, d = np.asarray(ray_origin, float), np.asarray(ray_dir, float)
    hit = ray_box(o, d, box_min, box_max)
    if hit is not None and hit[0] >= 0:
        return o + hit[0] * d
    n = d if plane_normal is None else np.asarray(plane_normal, float)
    p = ray_plane(o, d, fallback_plane_point, n)
    return p if p is not None else np.asarray(fallback_plane_point, float).copy()

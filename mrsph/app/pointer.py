"""The window's cursor and buttons -> camera motion (3D) or the mouse's disturbance.

A press decides once who owns the drag until every button is up: the HUD (the press was
over a panel, ImGui's), the camera (3D, right button: orbit), the pan (3D, middle
button), or the fluid (push; pull with the right button in 2D or shift). The fluid's
drags go through :class:`~mrsph.app.mouse.MouseDisturbance`, which turns the cursor's
world positions into a disturbance; in 3D the cursor moves in the plane facing the
camera through the point the drag grabbed, so the drag velocity is the cursor's.
"""

from __future__ import annotations

import math

import numpy as np

from . import palette
from .mouse import LEFT, RIGHT, SHIFT, pick_point, ray_plane

#: A drag over the whole window orbits by half a turn horizontally (a quarter vertically).
ORBIT_DRAG_GAIN = math.pi


class Pointer:
    """Drag state of one window: who owns the drag, the cursor of the last frame, and
    (3D) the plane a push drag moves in."""

    def __init__(self):
        self.prev = None  # cursor (u, v) of the last frame
        self.owner = None  # "fluid" / "camera" / "pan" / "hud" while a button is held
        self.plane = None  # 3D: (point, normal) of the plane the push drag moves in

    def reset(self) -> None:
        """Forget the drag (a new scene)."""
        self.owner, self.plane = None, None

    def update(
        self, cursor, lmb: bool, rmb: bool, mmb: bool, shift: bool, snap, renderer, mouse, over_hud: bool, dt: float
    ):
        """One frame: move the camera or feed ``mouse``; returns the disturbance (None
        when the fluid is not being dragged). ``cursor``: (u, v), canvas coordinates;
        ``over_hud``: the cursor is over a HUD panel; ``dt``: wall seconds."""
        u, v = cursor
        prev, self.prev = self.prev, (u, v)
        if not (lmb or rmb or mmb):
            self.reset()
            return mouse.update(None, set(), dt)
        if self.owner is None:  # a press: decide once who owns this drag
            if over_hud:
                self.owner = "hud"
            elif snap.dim == 3 and rmb:
                self.owner = "camera"
            elif snap.dim == 3 and mmb:
                self.owner = "pan"
            else:
                self.owner = "fluid"
        if self.owner in ("camera", "pan"):
            if prev is not None:
                du, dv = u - prev[0], v - prev[1]
                cam = renderer.ensure_camera(snap)
                if self.owner == "camera":
                    cam.orbit(-du * ORBIT_DRAG_GAIN, -dv * ORBIT_DRAG_GAIN * 0.5)
                else:
                    width, height = renderer.size
                    cam.pan(du * width / height, dv)
            return mouse.update(None, set(), dt)
        if self.owner != "fluid":
            return mouse.update(None, set(), dt)
        buttons = {b for b, held in ((LEFT, lmb), (RIGHT, rmb and snap.dim == 2), (SHIFT, shift)) if held}
        return mouse.update(self._world(u, v, snap, renderer), buttons, dt)

    def _world(self, u: float, v: float, snap, renderer):
        """The cursor in world coordinates: in 2D through the view; in 3D on the drag's
        plane."""
        if snap.dim == 2:
            return renderer.view2d(snap).canvas_to_world((u, v))
        cam = renderer.ensure_camera(snap)
        width, height = renderer.size
        origin, direction = cam.ray(u, v, width / height)
        forward = cam.basis()[0]
        if self.plane is None:
            # Start of a drag: grab the fluid where the ray enters its bounding box (or
            # the plane through the domain centre), then move in the plane through that
            # point facing the camera.
            real = ~palette.is_virtual(snap.kind)
            x = np.asarray(snap.x)[real] if real.any() else np.asarray(snap.x)
            centre = (np.asarray(snap.domain_min) + np.asarray(snap.domain_max)) / 2.0
            lo, hi = (x.min(axis=0), x.max(axis=0)) if len(x) else (snap.domain_min, snap.domain_max)
            p = pick_point(origin, direction, lo, hi, centre, forward)
            self.plane = (p, forward)
            return p
        p = ray_plane(origin, direction, self.plane[0], self.plane[1])
        return p if p is not None else self.plane[0]

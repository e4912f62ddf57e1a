"""What the window draws over the water to show what acts on it: the scene's stirrers
where they are now, and the mouse's reach (numpy only; the renderers draw the
:class:`~mrsph.app.geometry.Mark` circles).

The mouse's circle follows the cursor while it is over the fluid and no drag belongs to
the camera or the HUD: in 2D where the cursor is (inside the domain), in 3D where the
cursor's ray enters the real particles' bounding box, the point a push drag would grab.
"""

from __future__ import annotations

import numpy as np

from . import palette
from .geometry import Mark, stirrer_marks
from .mouse import ray_box


def frame_marks(scene, snap, mouse, cursor, renderer, hovering: bool) -> list[Mark]:
    """The marks of one frame. ``mouse``: the window's ``MouseDisturbance`` (its
    current disturbance wins over the cursor); ``cursor``: (u, v) in canvas coordinates,
    y up; ``renderer``: the frame's renderer (its 2D view or camera maps the cursor);
    ``hovering``: the cursor may show the reach (no drag owned elsewhere, not over the
    HUD)."""
    marks = stirrer_marks(scene, float(snap.time), snap)
    d = mouse.current
    if d is not None:
        marks.append(Mark(np.asarray(d.center, float), float(d.radius), "mouse"))
        return marks
    u, v = cursor
    if not hovering or not (0 <= u <= 1 and 0 <= v <= 1):
        return marks
    reach = _cursor_point(snap, (u, v), renderer)
    if reach is not None:
        marks.append(Mark(reach, float(mouse.radius), "mouse"))
    return marks


def _cursor_point(snap, cursor, renderer):
    """Where the cursor points into the fluid, or None (outside the domain in 2D, the
    ray missing the fluid's bounding box in 3D)."""
    if snap.dim == 2:
        p = renderer.view2d(snap).canvas_to_world(cursor)
        inside = np.all(p >= snap.domain_min) and np.all(p <= snap.domain_max)
        return p if inside else None
    real = ~palette.is_virtual(snap.kind)
    if not real.any():
        return None
    x = np.asarray(snap.x)[real]
    width, height = renderer.size
    origin, direction = renderer.ensure_camera(snap).ray(cursor[0], cursor[1], width / height)
    hit = ray_box(origin, direction, x.min(axis=0), x.max(axis=0))
    return origin + hit[0] * direction if hit is not None and hit[0] >= 0 else None

"""Drawable geometry of the scene furniture (domain box, obstacles), shared by the
GGUI renderer and the software rasteriser. Numpy only.

Obstacles come from ``Snapshot.obstacles`` (docs/ARCHITECTURE.md):
``{"shape": "box", "min": .., "max": ..}`` or ``{"shape": "sphere", "center": .., "radius": r}``
(a "sphere" in 2D is a circle).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .view import box_edges, circle_loop, scene_setting

#: Segments of a circle outline: smooth at 1080p for a circle half the window high.
CIRCLE_SEGMENTS = 72
#: 3D obstacle shells are sampled with about this many points along the obstacle's
#: smallest dimension: dense enough to read as a surface, cheap enough to draw.
SHELL_POINTS_ACROSS = 18


def domain_segments(domain_min, domain_max) -> np.ndarray:
    """Domain outline as segment end points (2*k, dim)."""
    return box_edges(domain_min, domain_max)


def obstacle_segments(obstacle: dict, dim: int) -> np.ndarray:
    """Outline of one obstacle as segment end points (2*k, dim).

    2D: rectangle edges or a circle. 3D: box wireframe, or three great circles for a
    sphere (the shell from :func:`obstacle_shell` gives it its body).
    """
    shape = obstacle.get("shape")
    if shape == "box":
        return box_edges(obstacle["min"], obstacle["max"])
    if shape == "sphere":
        c, r = np.asarray(obstacle["center"], dtype=np.float64), float(obstacle["radius"])
        if dim == 2:
            return circle_loop(c, r, CIRCLE_SEGMENTS)
        return np.concatenate([circle_loop(c, r, CIRCLE_SEGMENTS, axes) for axes in ((0, 1), (0, 2), (1, 2))])
    return np.zeros((0, dim))


def obstacle_triangles(obstacle: dict) -> np.ndarray:
    """Filled 2D obstacle as triangle vertices (3*k, 2): two for a box, a fan for a
    circle."""
    shape = obstacle.get("shape")
    if shape == "box":
        (x0, y0), (x1, y1) = np.asarray(obstacle["min"])[:2], np.asarray(obstacle["max"])[:2]
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y0], [x1, y1], [x0, y1]], dtype=np.float64)
    if shape == "sphere":
        c, r = np.asarray(obstacle["center"], dtype=np.float64)[:2], float(obstacle["radius"])
        t = np.linspace(0.0, 2.0 * math.pi, CIRCLE_SEGMENTS + 1)
        rim = c + r * np.stack([np.cos(t), np.sin(t)], axis=1)
        tri = np.empty((CIRCLE_SEGMENTS, 3, 2))
        tri[:, 0], tri[:, 1], tri[:, 2] = c, rim[:-1], rim[1:]
        return tri.reshape(-1, 2)
    return np.zeros((0, 2))


def obstacle_shell(obstacle: dict):
    """3D obstacle surface sampled by points: (points (K, 3), point radius).

    Drawn as small spheres, the points read as a solid surface in GGUI and in the
    rasteriser alike, without needing a mesh pipeline in the rasteriser.
    """
    shape = obstacle.get("shape")
    if shape == "sphere":
        c, r = np.asarray(obstacle["center"], dtype=np.float64), float(obstacle["radius"])
        spacing = 2.0 * r / SHELL_POINTS_ACROSS
        n = max(int(math.ceil(4.0 * math.pi * r * r / spacing**2)), 12)
        # Fibonacci sphere: near-uniform points without clustering at the poles.
        i = np.arange(n) + 0.5
        y = 1.0 - 2.0 * i / n
        rho = np.sqrt(1.0 - y * y)
        phi = i * math.pi * (3.0 - math.sqrt(5.0))
        pts = c + r * np.stack([rho * np.cos(phi), y, rho * np.sin(phi)], axis=1)
        return pts, 0.75 * spacing
    if shape == "box":
        lo, hi = np.asarray(obstacle["min"], dtype=np.float64), np.asarray(obstacle["max"], dtype=np.float64)
        spacing = float(np.min(hi - lo)) / SHELL_POINTS_ACROSS
        spacing = max(spacing, float(np.max(hi - lo)) / 120.0)  # bound the count of thin slabs
        faces = []
        for k in range(3):
            a, b = [j for j in range(3) if j != k]
            ua = np.linspace(lo[a], hi[a], max(int(round((hi[a] - lo[a]) / spacing)) + 1, 2))
            ub = np.linspace(lo[b], hi[b], max(int(round((hi[b] - lo[b]) / spacing)) + 1, 2))
            ga, gb = np.meshgrid(ua, ub, indexing="ij")
            for side in (lo[k], hi[k]):
                p = np.empty((ga.size, 3))
                p[:, a], p[:, b], p[:, k] = ga.ravel(), gb.ravel(), side
                faces.append(p)
        return np.concatenate(faces), 0.75 * spacing
    return np.zeros((0, 3)), 0.0


# ----------------------------------------------------------------------------- marks
class Mark(NamedTuple):
    """Something that acts on the water, drawn as a circle: the mouse's reach or a
    scene's stirrer. ``kind`` is "mouse" or "stirrer" (palette.MARK_COLOURS)."""

    center: np.ndarray
    radius: float
    kind: str


def stirrer_marks(scene, t: float) -> list[Mark]:
    """The scene's stirrers at simulated time ``t``: where the solver puts them, from
    the same scene data and the same ``mrsph.scene.interaction.path_sample``."""
    stirrers = scene_setting(scene, "stirrers", None) or []
    if not stirrers:
        return []
    from mrsph.scene.interaction import path_sample  # imports Taichi (not initialised): lazily

    out = []
    for st in stirrers:
        pos, _vel = path_sample(st["path"], t, bool(st.get("loop", True)))
        out.append(Mark(np.asarray(pos, float), float(st["radius"]), "stirrer"))
    return out


def mark_segments(mark: Mark, dim: int, facing=None) -> np.ndarray:
    """A mark's outline as segment end points (2k, dim): a circle in 2D; in 3D a ring
    in the plane facing the camera (``facing``: the view direction), moved toward the
    camera by the radius, plus a smaller ring at half the radius, so it reads as a
    sphere's outline with its centre."""
    c, r = np.asarray(mark.center, float)[:dim], float(mark.radius)
    if dim == 2:
        return circle_loop(c, r, CIRCLE_SEGMENTS)
    f = np.asarray(facing if facing is not None else (0.0, 0.0, -1.0), float)
    f = f / max(np.linalg.norm(f), 1e-12)
    a = np.cross(f, (0.0, 1.0, 0.0) if abs(f[1]) < 0.9 else (1.0, 0.0, 0.0))
    a /= np.linalg.norm(a)
    b = np.cross(f, a)
    c = c - r * f  # on the near side of the reach, so the surface it acts on hides none of it
    t = np.linspace(0.0, 2.0 * math.pi, CIRCLE_SEGMENTS + 1)
    rings = []
    for rr in (r, 0.5 * r):
        pts = c + rr * (np.cos(t)[:, None] * a + np.sin(t)[:, None] * b)
        rings.append(np.stack([pts[:-1], pts[1:]], axis=1).reshape(-1, 3))
    return np.concatenate(rings)


def water(snapshot, rgb):
    """The water view's surface of a snapshot (``mrsph.io.surface.surface``), coloured by
    the particles' colours ``rgb`` (N, 3) mixed into the water's (palette.WATER_TINT)."""
    from mrsph.io.surface import surface

    from . import palette

    tint = (1.0 - palette.WATER_TINT) * np.asarray(palette.WATER_COLOUR) + palette.WATER_TINT * np.asarray(rgb)
    return surface(snapshot.x, snapshot.m, snapshot.rho, snapshot.level, snapshot.kind, snapshot.dim, tint)

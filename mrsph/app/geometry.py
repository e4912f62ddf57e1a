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

from . import palette
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


def outside_domain_triangles(view, domain_min, domain_max) -> np.ndarray:
    """Four rectangles round the 2D domain out to the window's edges, in canvas
    coordinates: triangles (24, 2)."""
    (x0, y0), (x1, y1) = view.world_to_canvas(np.array([domain_min[:2], domain_max[:2]], np.float64))
    far = 4.0  # beyond the canvas' [0, 1]
    rects = ((-far, -far, x0, far), (x1, -far, far, far), (x0, -far, x1, y0), (x0, y1, x1, far))
    tri = []
    for a0, b0, a1, b1 in rects:
        tri += [(a0, b0), (a1, b0), (a1, b1), (a0, b0), (a1, b1), (a0, b1)]
    return np.asarray(tri, np.float64)


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


def stirrer_marks(scene, t: float, snap=None) -> list[Mark]:
    """The scene's stirrers at simulated time ``t``: where the solver puts them, from
    the same scene data and the same ``mrsph.scene.interaction.path_sample``. Given the
    frame's ``snap``, a stirrer whose path has ended with no real particle within its
    radius is left out: parked out of the water (demo_2d's, lifted above the post), it
    acts on nothing."""
    stirrers = scene_setting(scene, "stirrers", None) or []
    if not stirrers:
        return []
    from mrsph.scene.interaction import path_sample  # imports Taichi (not initialised): lazily

    real = None if snap is None else np.asarray(snap.x)[~palette.is_virtual(snap.kind)]
    out = []
    for st in stirrers:
        loop = bool(st.get("loop", True))
        pos, _vel = path_sample(st["path"], t, loop)
        centre, radius = np.asarray(pos, float), float(st["radius"])
        ended = not loop and t >= float(st["path"][-1][0])
        if ended and real is not None and not (np.linalg.norm(real - centre[: real.shape[1]], axis=1) < radius).any():
            continue
        out.append(Mark(centre, radius, "stirrer"))
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


class Water2D(NamedTuple):
    """The 2D water view of a snapshot (world coordinates): the body as triangles with a
    colour per vertex, its lit free surface as segments, and the drops that left it."""

    triangles: np.ndarray  # (3T, 2)
    colours: np.ndarray  # (3T, 3)
    surface: np.ndarray  # (2S, 2): segments of the free surface (facing up)
    drops: np.ndarray  # (D, 2) centres
    drop_radius: np.ndarray  # (D,) world radii
    drop_colours: np.ndarray  # (D, 3)
    grid: object  # the mrsph.io.surface.Grid, its rgb the nodes' colours (the rasteriser's)


#: The 2D water body darkens with the depth under its free surface: half way from the
#: shallow colour to the deep one at DEPTH_FRACTION of the domain's height (a scene's
#: depths are some tenths of its height), and lightens within a few cells of the
#: surface (the lit surface: RIM_CELLS cells, by RIM_LIGHT of the way to the edge colour).
DEPTH_FRACTION = 0.25
RIM_CELLS = 1.8
RIM_LIGHT = 0.55
#: A tinted body keeps its colour at the surface and darkens to this share of it deep down.
TINT_DEEP = 0.5
#: The free surface's lit line: segments whose outward normal points this much up.
SURFACE_FACING_UP = 0.3
#: A drop (a particle outside the body) is drawn this many times its particle's radius.
DROP_SCALE = 1.15


def water_colours(depth, scale: float, cell: float, base=None, across=None) -> np.ndarray:
    """Colours of the body's nodes from their depth under the free surface: the shallow
    water's colour to the deep's (or the tint ``base`` to TINT_DEEP of it), and lighter
    just under the surface. ``across``: each node's distance to the air beside it; the
    darkening follows the nearer of the two, so that a wave's face or a sheet climbing a
    wall stays light."""
    from . import palette

    dark = np.asarray(depth) if across is None else np.minimum(depth, across)
    t = (1.0 - np.exp(-dark * (np.log(2.0) / max(scale, 1e-9))))[..., None]
    if base is None:
        col = (1.0 - t) * np.asarray(palette.WATER_SHALLOW) + t * np.asarray(palette.WATER_DEEP)
    else:
        col = np.asarray(base) * (1.0 - (1.0 - TINT_DEEP) * t)
    rim = np.exp(-np.asarray(depth) / (RIM_CELLS * cell))[..., None] * RIM_LIGHT
    return np.clip(col + rim * (np.asarray(palette.WATER_EDGE) - col), 0.0, 1.0)


def water_2d(snapshot, rgb=None, dim_factor: float = 1.0) -> Water2D | None:
    """The 2D water view: the body (mrsph.io.surface: the volume fraction with the
    particles mirrored at the walls, filled by marching squares) shaded by depth, its
    free surface and its drops. ``rgb`` (N, 3): the tint (per particle), or None."""
    from mrsph.io import surface as sf

    from . import palette

    walls = (snapshot.domain_min, snapshot.domain_max, snapshot.obstacles)
    grid = sf.volume_fraction(snapshot.x, snapshot.m, snapshot.rho, snapshot.level, snapshot.kind, rgb, walls)
    if grid is None:
        return None
    solid = sf.inside_obstacles(grid, snapshot.obstacles)
    depth = sf.depth_below_surface(grid, solid)
    height = float(np.asarray(snapshot.domain_max)[1] - np.asarray(snapshot.domain_min)[1])
    base = grid.rgb if grid.rgb is not None else grid.colour
    across = sf.distance_to_air_across(grid, solid)
    grid.rgb = water_colours(depth, DEPTH_FRACTION * height, grid.cell, base, across) * dim_factor
    grid.colour = None
    tri, tri_rgb, seg = sf.marching_squares(grid)
    # the lit line: the contour inside the domain where it faces up (the free surface)
    if len(seg):
        mid = 0.5 * (seg[0::2] + seg[1::2])
        gy = np.gradient(grid.phi, axis=1)
        node = np.clip(np.rint((mid - grid.origin) / grid.cell).astype(np.int64), 0, np.array(grid.phi.shape) - 1)
        gx = np.gradient(grid.phi, axis=0)[tuple(node.T)]
        up = -gy[tuple(node.T)] / np.maximum(np.hypot(gx, gy[tuple(node.T)]), 1e-12)
        lo, hi = np.asarray(snapshot.domain_min)[:2], np.asarray(snapshot.domain_max)[:2]
        keep = (up > SURFACE_FACING_UP) & np.all((mid > lo) & (mid < hi), axis=1) & ~solid[tuple(node.T)]
        seg = seg.reshape(-1, 2, 2)[keep].reshape(-1, 2)
    # drops: real particles outside the body
    real = ~palette.is_virtual(snapshot.kind)
    x = np.asarray(snapshot.x, np.float64)[real, :2]
    out = sf.phi_at(grid, x) < sf.ISO
    level = np.asarray(snapshot.level)[real][out]
    if rgb is None:
        drop_rgb = np.tile(np.asarray(palette.WATER_SPRAY, np.float32), (int(out.sum()), 1))
    else:
        drop_rgb = np.asarray(rgb, np.float32)[real][out]
    radius = np.asarray(snapshot.radius, np.float64)[level] * DROP_SCALE
    return Water2D(tri, tri_rgb, seg, x[out], radius, drop_rgb * dim_factor, grid)


def water(snapshot, rgb, tint: bool = False, dim_factor: float = 1.0):
    """The water view of a snapshot: 2D a :class:`Water2D` (the body, its surface, the
    drops), 3D ``("mesh", vertices, normals, colours)``. Untinted, the 2D body is the
    water's colours by depth and the 3D mesh palette.WATER_COLOUR; tinted, both take the
    particles' colours ``rgb`` (N, 3), the legend's."""
    from mrsph.io.surface import surface

    from . import palette

    if snapshot.dim == 2:
        return water_2d(snapshot, np.asarray(rgb) if tint else None, dim_factor)
    colour = np.asarray(rgb) if tint else np.broadcast_to(np.asarray(palette.WATER_COLOUR), (len(snapshot.x), 3))
    return surface(snapshot.x, snapshot.m, snapshot.rho, snapshot.level, snapshot.kind, 3, colour * dim_factor)

"""The water view: the fluid's surface from its particles. Numpy only, no Taichi.

Used by the renderers (the window's and the recordings' ``w`` / ``render.surface``) and
by ``--dump-format obj``; it reads particles and never changes the simulation.

1. Volume fraction on a grid. Each real particle's volume V_j = m_j / ρ_j is deposited
   on the grid nodes around it (cloud-in-cell, the 2^d nearest nodes) and the deposit
   of each level is smoothed by a separable Gaussian of width σ_l = SIGMA_SPACINGS · s_l,
   with s_l = V^(1/d) that level's spacing, so that the particles' volumes add up to

       φ(x) = Σ_j V_j G_σ(x − x_j) / cell^d  ≈ 1 inside the fluid, 0 outside,

   whatever the level (a coarse particle spreads its larger volume wider). The fluid's
   edge is the level set φ = ISO = 1/2: where a half-space of particles ends, half of
   the smoothed volume is left (Zhu & Bridson 2005, "Animating sand as a fluid", splat
   a smooth field and contour it, with a simpler field). The grid's cell is the finest
   spacing present (1.5 of it in 3D), grown where the grid would hold more than MAX_NODES nodes.
2. 2D: marching squares, filled. Each cell's corners inside (φ ≥ ISO) pick one of 16
   polygons over its corners and its edge crossings (linear interpolation of φ along
   the edge); the polygons are fanned into triangles, and their edges that lie on the
   contour make the outline. The two saddle cases take the mean of the corners. Cells
   wholly inside are drawn as row strips where their colour does not change along the row.
3. 3D: surface nets (Gibson 1998). One vertex in each cube the level set crosses, at
   the mean of the crossings on the cube's edges; each crossed grid edge gives a quad
   joining the four cubes around it (two triangles), so the mesh is closed. Normals are
   −∇φ (central differences) averaged like the vertices; each quad turns so that it
   faces outward (the OBJ volume check relies on it). Marching tetrahedra, used first,
   gave the same surface to within a cell with ~4x the triangles, too slow for the
   window's every frame (pool_3d: 25 200 triangles in 67 ms; surface nets 6 650 in 8 ms).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Level set of the smoothed volume fraction taken as the surface (see the docstring).
ISO = 0.5
#: Gaussian width per particle spacing: 0.6 s smooths a lattice to within ~1 % of φ = 1
#: inside (0.5 s leaves 4 % ripples, visible as dimples in 3D) and rounds the corners of
#: the fluid by less than a spacing.
SIGMA_SPACINGS = 0.6
#: The Gaussian is cut at this many σ (its weight beyond is 1 %).
TRUNCATE_SIGMAS = 2.5
#: Grid cell per finest spacing: 3D surfaces are smooth at 1.5 (and cost 3.4x less
#: than at 1); 2D cells are cheap.
CELL_SPACINGS = {2: 1.0, 3: 1.5}
#: Largest grid, in nodes; a larger one is coarsened (cost grows with the node count).
MAX_NODES = {2: 400_000, 3: 400_000}
#: Colour step, out of 255, within which the cells of a row are drawn as one strip.
MERGE_STEP = 4
#: Kind codes of real particles: virtual = kind >= 4 (``sph.particles.VIRTUAL_CHILD``, kept
#: apart so that this module needs no Taichi).
_VIRTUAL_KIND = 4


@dataclass
class Grid:
    """A scalar field on a regular grid: ``phi[i, j(, k)]`` at ``origin + (i, j, k) * cell``;
    ``rgb`` (same shape + (3,)) the volume-weighted mean colour, or None; ``colour`` (3,)
    the one colour of every particle when they all have the same (then ``rgb`` is None)."""

    origin: np.ndarray
    cell: float
    phi: np.ndarray
    rgb: np.ndarray | None = None
    colour: np.ndarray | None = None


def _spacing(volume: np.ndarray, dim: int) -> float:
    return float(np.median(volume)) ** (1.0 / dim)


def volume_fraction(x, m, rho, level, kind=None, rgb=None, walls=None) -> Grid | None:
    """The smoothed volume fraction φ of the real particles (kind < 4) on a grid that
    covers them with room for the smoothing; None when there are none. ``rgb`` (N, 3):
    a colour per particle, averaged into ``Grid.rgb`` with the same weights. ``walls``:
    (domain_min, domain_max, obstacles): the particles near a wall or an obstacle are
    mirrored across it (``mirrored``), so that φ stays at 1 up to the wall instead of
    falling to 1/2 there, and the body drawn reaches the wall.

    Each level is deposited and smoothed on the part of the grid its particles reach
    only (a few fine particles near an obstacle do not cost a pass over the whole
    grid), and the colour channels ride along with φ in one array, so that a frame costs
    few numpy passes (the window computes this every frame)."""
    x = np.asarray(x, np.float64)
    n, dim = x.shape if x.ndim == 2 else (0, 2)
    real = np.ones(n, bool) if kind is None else np.asarray(kind) < _VIRTUAL_KIND
    rho = np.asarray(rho, np.float64)
    real &= rho > 0
    if not real.any():
        return None
    x = x[real]
    vol = np.asarray(m, np.float64)[real] / rho[real]
    level = np.asarray(level)[real]
    col = uniform = None
    if rgb is not None:
        col = np.asarray(rgb, np.float64)[real]
        if np.all(col == col[0]):  # one colour (one level, or a flat colour mode)
            col, uniform = None, col[0].copy()
    levels = np.unique(level)
    by_level = [level == l for l in levels] if len(levels) > 1 else [slice(None)]
    spacing = [_spacing(vol[sel], dim) for sel in by_level]
    if walls is not None:
        s_of = np.zeros(int(levels.max()) + 1)
        s_of[levels] = spacing
        src, ghosts = mirrored(x, TRUNCATE_SIGMAS * SIGMA_SPACINGS * s_of[level] + max(spacing), *walls)
        if len(src):
            x, vol = np.concatenate([x, ghosts]), np.concatenate([vol, vol[src]])
            level = np.concatenate([level, level[src]])
            if col is not None:
                col = np.concatenate([col, col[src]])
            by_level = [level == l for l in levels] if len(levels) > 1 else [slice(None)]
    cell = CELL_SPACINGS[dim] * min(spacing)
    reach = TRUNCATE_SIGMAS * SIGMA_SPACINGS * max(spacing) + 2.0 * cell
    lo, hi = x.min(axis=0) - reach, x.max(axis=0) + reach
    while np.prod(np.ceil((hi - lo) / cell) + 1) > MAX_NODES[dim]:
        cell *= 1.25
    shape = tuple(int(c) for c in np.ceil((hi - lo) / cell) + 1)
    channels = 1 if col is None else 4  # volume, then volume x colour
    acc = np.zeros(shape + (channels,))
    for sel, s_l in zip(by_level, spacing):
        w = vol[sel, None] / cell**dim
        if col is not None:
            w = np.concatenate([w, w * col[sel]], axis=1)
        sigma = SIGMA_SPACINGS * s_l / cell
        r = _blur_radius(sigma)
        u = (x[sel] - lo) / cell
        # the box of nodes this level's particles reach, after smoothing
        b0 = np.maximum(np.floor(u.min(axis=0)).astype(np.int64) - r, 0)
        b1 = np.minimum(np.floor(u.max(axis=0)).astype(np.int64) + 2 + r, shape)
        box = tuple(slice(a, b) for a, b in zip(b0, b1))
        sub = tuple(int(c) for c in b1 - b0)
        acc[box] += _blur(_deposit(u - b0, w, sub), sigma)
    phi = np.ascontiguousarray(acc[..., 0])
    grid_rgb = None
    if col is not None:
        grid_rgb = acc[..., 1:] / np.maximum(phi, 1e-6)[..., None]
    return Grid(lo, cell, phi, grid_rgb, uniform)


def mirrored(x, reach, domain_min, domain_max, obstacles=()):
    """Mirror images of the particles near the domain's walls and the obstacles' faces:
    (the indices of the particles mirrored, the images' positions). ``reach`` (N,): how
    near a particle must be (its smoothing's reach). A particle within reach of a wall
    is mirrored across it; of a box's face (beside the face), across the face; of a
    sphere (a circle in 2D), radially, as deep inside as it is outside."""
    x = np.asarray(x, np.float64)
    reach = np.broadcast_to(np.asarray(reach, np.float64), (len(x),))
    lo, hi = np.asarray(domain_min, np.float64), np.asarray(domain_max, np.float64)
    dim = x.shape[1]
    src, out = [], []
    for a in range(dim):
        for wall, sign in ((lo[a], 1.0), (hi[a], -1.0)):
            d = (x[:, a] - wall) * sign
            near = np.nonzero((d >= 0.0) & (d < reach))[0]
            g = x[near].copy()
            g[:, a] = 2.0 * wall - g[:, a]
            src.append(near)
            out.append(g)
    for o in obstacles or ():
        if o.get("shape") == "box":
            b0, b1 = np.asarray(o["min"], np.float64)[:dim], np.asarray(o["max"], np.float64)[:dim]
            for a in range(dim):
                others = [k for k in range(dim) if k != a]
                beside = np.all([(x[:, k] >= b0[k] - reach) & (x[:, k] <= b1[k] + reach) for k in others], axis=0)
                for face, sign in ((b0[a], -1.0), (b1[a], 1.0)):
                    d = (x[:, a] - face) * sign
                    near = np.nonzero(beside & (d >= 0.0) & (d < reach))[0]
                    g = x[near].copy()
                    g[:, a] = 2.0 * face - g[:, a]
                    src.append(near)
                    out.append(g)
        elif o.get("shape") == "sphere":
            c, r = np.asarray(o["center"], np.float64)[:dim], float(o["radius"])
            rel = x - c
            dist = np.linalg.norm(rel, axis=1)
            d = dist - r
            near = np.nonzero((d >= 0.0) & (d < np.minimum(reach, r)))[0]
            n = rel[near] / np.maximum(dist[near], 1e-12)[:, None]
            src.append(near)
            out.append(c + (r - d[near])[:, None] * n)
    if not src:
        return np.zeros(0, np.int64), np.zeros((0, dim))
    return np.concatenate(src), np.concatenate(out)


def inside_obstacles(grid: Grid, obstacles) -> np.ndarray:
    """Nodes of ``grid`` inside any obstacle (bool, the grid's shape)."""
    shape = grid.phi.shape
    dim = len(shape)
    axes = [grid.origin[a] + grid.cell * np.arange(shape[a]) for a in range(dim)]
    solid = np.zeros(shape, bool)
    for o in obstacles or ():
        if o.get("shape") == "box":
            b0, b1 = np.asarray(o["min"], np.float64)[:dim], np.asarray(o["max"], np.float64)[:dim]
            box = tuple(slice(*np.searchsorted(axes[a], (b0[a], b1[a]), side="left")) for a in range(dim))
            solid[box] = True
        elif o.get("shape") == "sphere":
            c, r = np.asarray(o["center"], np.float64)[:dim], float(o["radius"])
            box = tuple(slice(*np.searchsorted(axes[a], (c[a] - r, c[a] + r), side="left")) for a in range(dim))
            sub = np.meshgrid(*[axes[a][box[a]] for a in range(dim)], indexing="ij")
            solid[box] |= sum((sub[a] - c[a]) ** 2 for a in range(dim)) <= r * r
    return solid


def depth_below_surface(grid: Grid, solid=None, iso: float = ISO) -> np.ndarray:
    """Per node of a 2D or 3D grid: how far it is below the free surface above it (along
    +y, axis 1): the crossing of φ = iso between the first node above that is outside
    the fluid (φ < iso and not ``solid``) and the node under that one, interpolated, so
    that the depth varies smoothly along the surface (whole cells drew stripes); 0 at and
    above the surface. An obstacle counts as fluid, so the water under a floating body
    is as deep as it is beside it."""
    phi = grid.phi
    outside = phi < iso
    if solid is not None:
        outside &= ~solid
    ny = outside.shape[1]
    j = np.arange(ny).reshape((1, ny) + (1,) * (outside.ndim - 2))
    first_out = np.where(outside, j, ny)
    # the first outside node at or above each node: a minimum from the top down
    above = np.minimum.accumulate(first_out[:, ::-1], axis=1)[:, ::-1]
    top = np.clip(above, 1, ny - 1)
    p_out = np.take_along_axis(phi, top, axis=1)
    p_in = np.take_along_axis(phi, top - 1, axis=1)
    # where φ crosses iso between them, as a fraction of the cell below the outside node
    t = np.clip((p_in - iso) / np.maximum(p_in - p_out, 1e-9), 0.0, 1.0)
    depth = (above - 1 - j) + np.where(above < ny, t, 1.0)
    return np.maximum(depth, 0.0) * grid.cell * (above > j)


def distance_to_air_across(grid: Grid, solid=None, iso: float = ISO) -> np.ndarray:
    """Per node of a 2D grid: how far it is, along x (axis 0) either way, from the
    nearest node outside the fluid (φ < iso and not ``solid``), in whole cells: the
    water by a steep face or in a thin sheet is near the air whatever its depth."""
    outside = grid.phi < iso
    if solid is not None:
        outside &= ~solid
    nx = outside.shape[0]
    i = np.arange(nx).reshape((nx,) + (1,) * (outside.ndim - 1))
    far = 4 * nx
    right = np.minimum.accumulate(np.where(outside, i, far)[::-1], axis=0)[::-1] - i
    left = i - np.maximum.accumulate(np.where(outside, i, -far), axis=0)
    return np.minimum(left, right).astype(np.float64) * grid.cell


def phi_at(grid: Grid, p) -> np.ndarray:
    """φ at points p (N, d), bilinear (trilinear) between the nodes; 0 off the grid."""
    u = (np.asarray(p, np.float64) - grid.origin) / grid.cell
    shape = np.array(grid.phi.shape)
    i0 = np.floor(u).astype(np.int64)
    ok = np.all((i0 >= 0) & (i0 < shape - 1), axis=1)
    f = u - i0
    out = np.zeros(len(u))
    i0, f = i0[ok], f[ok]
    dim = u.shape[1]
    acc = np.zeros(len(i0))
    for corner in range(2**dim):
        w = np.ones(len(i0))
        idx = []
        for a in range(dim):
            bit = (corner >> a) & 1
            w *= f[:, a] if bit else 1.0 - f[:, a]
            idx.append(i0[:, a] + bit)
        acc += w * grid.phi[tuple(idx)]
    out[ok] = acc
    return out


def _deposit(u, w, shape) -> np.ndarray:
    """Cloud-in-cell: each particle's weights w (N, k), at u (N, d) in cells from the
    grid's first node, shared among its 2^d nearest nodes, linearly: (*shape, k)."""
    dim, k = len(shape), w.shape[1]
    i0 = np.floor(u).astype(np.int64)
    f = u - i0
    strides = np.array([int(np.prod(shape[a + 1 :])) for a in range(dim)])
    base = np.clip(i0, 0, np.array(shape) - 2) @ strides
    corners = 2**dim
    idx = np.empty((corners, len(u)), np.int64)
    frac = np.empty((corners, len(u)))
    for corner in range(corners):
        fr = np.ones(len(u))
        off = 0
        for a in range(dim):
            bit = (corner >> a) & 1
            fr *= f[:, a] if bit else 1.0 - f[:, a]
            off += bit * strides[a]
        idx[corner] = base + off
        frac[corner] = fr
    idx, size = idx.ravel(), int(np.prod(shape))
    out = np.empty((size, k))
    for j in range(k):
        out[:, j] = np.bincount(idx, weights=(frac * w[:, j]).ravel(), minlength=size)
    return out.reshape(shape + (k,))


def _blur_radius(sigma: float) -> int:
    return max(int(np.ceil(TRUNCATE_SIGMAS * sigma)), 1)


def _blur(a: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian smoothing over the grid axes of ``a`` (*grid, k) (normalised
    taps, zero outside the grid)."""
    r = _blur_radius(sigma)
    t = np.arange(-r, r + 1, dtype=np.float64)
    taps = np.exp(-0.5 * (t / max(sigma, 1e-9)) ** 2)
    taps /= taps.sum()
    for axis in range(a.ndim - 1):
        out = a * taps[r]
        n = a.shape[axis]
        for k in range(1, min(r, n - 1) + 1):
            lo = [slice(None)] * a.ndim
            hi = [slice(None)] * a.ndim
            lo[axis], hi[axis] = slice(0, n - k), slice(k, n)
            lo, hi = tuple(lo), tuple(hi)
            out[hi] += taps[r + k] * a[lo]  # taps are symmetric
            out[lo] += taps[r + k] * a[hi]
        a = out
    return a


# ----------------------------------------------------------------------------- 2D
#: Marching squares with fill. Corners 0..3 = (0,0), (1,0), (1,1), (0,1) (counter-
#: clockwise); points 4..7 = crossings on the edges 0-1, 1-2, 3-2, 0-3. Case bit k is
#: corner k inside. Each case: its filled polygons, counter-clockwise; the saddles
#: 5 and 10 have a "separate" and a "joined" variant (index 16, 17).
_SQUARE_POLYS = {
    1: [[0, 4, 7]],
    2: [[4, 1, 5]],
    3: [[0, 1, 5, 7]],
    4: [[5, 2, 6]],
    5: [[0, 4, 7], [5, 2, 6]],
    6: [[4, 1, 2, 6]],
    7: [[0, 1, 2, 6, 7]],
    8: [[7, 6, 3]],
    9: [[0, 4, 6, 3]],
    10: [[4, 1, 5], [7, 6, 3]],
    11: [[0, 1, 5, 6, 3]],
    12: [[7, 5, 2, 3]],
    13: [[0, 4, 5, 2, 3]],
    14: [[4, 1, 2, 3, 7]],
    15: [[0, 1, 2, 3]],
    16: [[0, 4, 5, 2, 6, 7]],
    17: [[4, 1, 5, 6, 3, 7]],
}


def marching_squares(grid: Grid, iso: float = ISO):
    """Filled contour of ``grid.phi >= iso``: (triangles (3T, 2), colours (3T, 3) or None,
    outline segments (2S, 2)) in world coordinates."""
    phi = grid.phi
    c = np.stack([phi[:-1, :-1], phi[1:, :-1], phi[1:, 1:], phi[:-1, 1:]], axis=-1)  # corners 0..3
    inside = c >= iso
    case = inside[..., 0] | (inside[..., 1] << 1) | (inside[..., 2] << 2) | (inside[..., 3] << 3)
    case = case.astype(np.int8)
    # cells the contour crosses: one pass finds them all, grouped by case below
    mixed = np.flatnonzero((case != 0) & (case != 15))
    ij = np.stack(np.unravel_index(mixed, case.shape), axis=1)
    code = case.ravel()[mixed]
    cm = c.reshape(-1, 4)[mixed]
    saddle = ((code == 5) | (code == 10)) & (cm.mean(axis=1) >= iso)
    code = np.where(saddle, code + np.where(code == 5, 11, 7), code)  # 5 -> 16, 10 -> 17
    pts = _square_points(grid, cm, ij, iso)  # (n, 8, 2)
    order = np.argsort(code, kind="stable")
    bounds = np.searchsorted(code[order], np.arange(19))
    tris, segs = [], []
    for k, polys in _SQUARE_POLYS.items():
        if k == 15:
            continue
        rows = order[bounds[k] : bounds[k + 1]]
        if len(rows) == 0:
            continue
        p = pts[rows]
        for poly in polys:
            fan = [(poly[0], poly[t], poly[t + 1]) for t in range(1, len(poly) - 1)]
            tris.append(p[:, fan].reshape(-1, 2))
            edges = [(a, b) for a, b in zip(poly, poly[1:] + poly[:1]) if a >= 4 and b >= 4]
            if edges:
                segs.append(p[:, edges].reshape(-1, 2))
    tris.extend(_inside_quads(grid, case == 15))
    if not tris:
        return np.zeros((0, 2)), None, np.zeros((0, 2))
    tri = np.concatenate(tris)
    seg = np.concatenate(segs) if segs else np.zeros((0, 2))
    return tri, sample_colour(grid, tri), seg


def _inside_quads(grid: Grid, inside) -> list[np.ndarray]:
    """Triangles (2 a quad) covering the cells wholly inside: consecutive cells of a row
    whose colours stay within one step of MERGE_STEP / 255 as one strip, the others one
    quad each. Most of a pool is one colour, or one colour a depth, so this draws a few
    thousand triangles where a quad per cell drew tens of thousands (the colours, sampled
    at the strips' ends and blended between, are off by MERGE_STEP / 255 at most: the
    water view's depth shading at 1/255 merged nothing, 22 600 triangles and 15 ms for
    demo_2d's body)."""
    if grid.rgb is not None:
        q = np.floor(np.clip(grid.rgb, 0.0, 1.0) * (255.0 / MERGE_STEP)).astype(np.int16)
        along = np.all(q[:-1] == q[1:], axis=-1)  # node i, i+1 of a row alike
        flat = along[:, :-1] & along[:, 1:]  # both rows of the cell
    else:
        flat = np.ones_like(inside)
    strip = inside & flat
    padded = np.zeros((strip.shape[1], strip.shape[0] + 2), np.int8)  # rows (y), cells (x)
    padded[:, 1:-1] = strip.T
    step = np.diff(padded, axis=1)
    j0, i0 = np.nonzero(step == 1)  # first cell of each run
    _, i1 = np.nonzero(step == -1)  # one past its last cell (row-major: paired)
    single = np.stack(np.nonzero(inside & ~flat), axis=1)
    lo = np.concatenate([np.stack([i0, j0], axis=1), single]).astype(np.float64)
    width = np.concatenate([i1 - i0, np.ones(len(single))])
    if len(lo) == 0:
        return []
    x0, y0 = grid.origin + lo * grid.cell, grid.origin[1] + (lo[:, 1] + 1) * grid.cell
    x1 = x0[:, 0] + width * grid.cell
    a, b = x0, np.stack([x1, x0[:, 1]], axis=1)
    c, d = np.stack([x1, y0], axis=1), np.stack([x0[:, 0], y0], axis=1)
    return [np.stack([a, b, c, a, c, d], axis=1).reshape(-1, 2)]


def _square_points(grid: Grid, c, ij, iso):
    """The 8 points of marching squares for cells ij with corner values c (n, 4)."""
    base = grid.origin + ij * grid.cell
    corner = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float) * grid.cell
    pts = np.empty((len(ij), 8, 2))
    pts[:, :4] = base[:, None, :] + corner[None]
    a = np.array([0, 1, 3, 0])
    b = np.array([1, 2, 2, 3])
    d = c[:, b] - c[:, a]
    t = np.clip((iso - c[:, a]) / np.where(np.abs(d) > 1e-12, d, 1.0), 0.0, 1.0)
    t = np.where(np.abs(d) > 1e-12, t, 0.5)
    pts[:, 4:] = pts[:, a] + t[..., None] * (pts[:, b] - pts[:, a])
    return pts


def sample_colour(grid: Grid, p) -> np.ndarray | None:
    """The grid's colour at points p (nearest node), or None without colours."""
    if grid.rgb is None:
        return None if grid.colour is None else np.broadcast_to(grid.colour, (len(p), 3)).copy()
    idx = np.rint((np.asarray(p) - grid.origin) / grid.cell).astype(np.int64)
    idx = np.clip(idx, 0, np.array(grid.phi.shape) - 1)
    return grid.rgb[tuple(idx.T)]


# ----------------------------------------------------------------------------- 3D
#: For each axis a, the two other axes (b, c) in right-handed order (b × c = a): a quad
#: around an edge along a, its cubes taken in this order, turns counter-clockwise seen
#: from +a.
_AROUND = ((1, 2), (2, 0), (0, 1))


def surface_nets(grid: Grid, iso: float = ISO):
    """The surface ``grid.phi = iso`` as triangles, by surface nets (Gibson 1998,
    "Constrained elastic surface nets", without the relaxation): one vertex in each cube
    the level set crosses, at the mean of the crossings on its edges, and for each grid
    edge it crosses a quad joining the four cubes around that edge. Same vertices'
    places as marching tetrahedra to within a cell, about four times fewer triangles
    (two per crossed edge instead of ~7.6 per crossed cube), so the window draws it
    every frame. Returns (vertices (3T, 3), normals (3T, 3), colours (3T, 3) or None),
    wound counter-clockwise seen from outside; normals −∇φ averaged like the vertices."""
    phi = grid.phi
    shape = np.array(phi.shape)
    cubes = shape - 1
    inside = phi >= iso
    n_cubes = int(np.prod(cubes))
    acc = np.zeros((n_cubes, 7))  # position (3), −∇φ (3), crossings (1)
    quads = []
    for a in range(3):
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[a], hi[a] = slice(0, -1), slice(1, None)
        crossed = inside[tuple(lo)] != inside[tuple(hi)]
        e = np.stack(np.nonzero(crossed), axis=1)  # edge starts
        if len(e) == 0:
            continue
        f = e.copy()
        f[:, a] += 1
        v0, v1 = phi[tuple(e.T)], phi[tuple(f.T)]
        t = (iso - v0) / (v1 - v0)  # crossed: v1 != v0
        p = grid.origin + (e + 0.0) * grid.cell
        p[:, a] += t * grid.cell
        g0, g1 = _grad_at(phi, e, grid.cell), _grad_at(phi, f, grid.cell)
        g = -(g0 + t[:, None] * (g1 - g0))
        b, c = _AROUND[a]
        # the four cubes around the edge, in turning order; edges on the grid's faces
        # have fewer (never crossed: the grid has room around the fluid)
        ring = []
        for db, dc in ((1, 1), (0, 1), (0, 0), (1, 0)):
            cube = e.copy()
            cube[:, b] -= db
            cube[:, c] -= dc
            ring.append(cube)
        ok = np.all([np.all((q >= 0) & (q < cubes), axis=1) for q in ring], axis=0)
        ids = np.stack([np.ravel_multi_index(tuple(q[ok].T), tuple(cubes)) for q in ring], axis=1)
        w = np.concatenate([p, g, np.ones((len(p), 1))], axis=1)[ok]
        for k in range(4):
            for col in range(7):
                acc[:, col] += np.bincount(ids[:, k], weights=w[:, col], minlength=n_cubes)
        # counter-clockwise seen from +a: outward when the inside is at the edge's start
        flip = ~inside[tuple(e[ok].T)]
        ids[flip] = ids[flip][:, ::-1]
        quads.append(ids)
    if not quads:
        return np.zeros((0, 3)), np.zeros((0, 3)), None
    quads = np.concatenate(quads)
    used = acc[:, 6] > 0
    vert = np.zeros((n_cubes, 3))
    nrm = np.zeros((n_cubes, 3))
    vert[used] = acc[used, :3] / acc[used, 6:7]
    nrm[used] = acc[used, 3:6]
    nrm[used] /= np.maximum(np.linalg.norm(nrm[used], axis=1, keepdims=True), 1e-12)
    tri = quads[:, [0, 1, 2, 0, 2, 3]].reshape(-1)
    verts = vert[tri]
    return verts, nrm[tri], sample_colour(grid, verts)


def _grad_at(phi, idx, cell):
    """∇φ at nodes idx (n, 3): central differences, one-sided on the grid's faces."""
    shape = np.array(phi.shape)
    out = np.empty(idx.shape)
    for a in range(3):
        up, down = idx.copy(), idx.copy()
        up[:, a] = np.minimum(up[:, a] + 1, shape[a] - 1)
        down[:, a] = np.maximum(down[:, a] - 1, 0)
        out[:, a] = (phi[tuple(up.T)] - phi[tuple(down.T)]) / ((up[:, a] - down[:, a]) * cell)
    return out


def mesh_volume(vertices) -> float:
    """Signed volume enclosed by triangles (3T, 3) wound outward (divergence theorem)."""
    p = np.asarray(vertices, np.float64).reshape(-1, 3, 3)
    return float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0)


def polygon_area(triangles) -> float:
    """Signed area of triangles (3T, 2), counter-clockwise positive."""
    p = np.asarray(triangles, np.float64).reshape(-1, 3, 2)
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    return float((e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum() / 2.0)


def surface(x, m, rho, level, kind, dim: int, rgb=None, walls=None):
    """The fluid's surface from particle arrays: 2D ``("area", triangles, colours,
    outline)``, 3D ``("mesh", vertices, normals, colours)``; None without fluid.
    ``walls``: as ``volume_fraction``'s, the body then reaching the walls."""
    grid = volume_fraction(x, m, rho, level, kind, rgb, walls)
    if grid is None:
        return None
    if dim == 2:
        return ("area",) + marching_squares(grid)
    return ("mesh",) + surface_nets(grid)

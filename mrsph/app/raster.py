"""Pure-numpy software rasteriser: the fallback renderer when GGUI / Vulkan is missing.

It draws the same picture as :mod:`mrsph.app.render` from the same inputs (palette,
letterboxed :class:`~mrsph.app.view.View2D`, :class:`~mrsph.app.view.OrbitCamera`):

* 2D: flat discs, painter's order (coarse under fine, virtual ones smaller on top, as
  GGUI draws them), filled obstacles, domain and obstacle outlines on top.
* 3D: sphere splats with headlight shading resolved by a z-buffer; obstacle shells
  and wireframes go through the same z-buffer so depth is right everywhere.

Everything is vectorised per group of equal-sized stamps: a group of n particles
whose discs cover k pixels each becomes one (n, k) index array. No Python loop runs
per particle, so 30k particles take tens of milliseconds at 960x540.
"""

from __future__ import annotations

import functools

import numpy as np

from . import geometry, palette
from .legend import MARGIN_PX as LEGEND_MARGIN_PX
from .legend import box_px as legend_box
from .legend import lines as legend_lines
from .palette import Style
from .view import OrbitCamera, View2D, fitted_view, framed_camera

#: Lighting shared with the GGUI renderer (render.py sets the same ambient and
#: light colour): colour * (AMBIENT + DIFFUSE * max(n.l, 0)).
AMBIENT = 0.38
DIFFUSE = 0.72
#: Light direction in view space (x right, y up, z toward the viewer): a headlight
#: slightly above and left of the camera, so spheres read as spheres.
LIGHT_DIR_VIEW = np.array([-0.25, 0.45, 0.86]) / np.linalg.norm([-0.25, 0.45, 0.86])
#: Radii are rounded to this many pixels so that particles share stamps.
RADIUS_QUANTUM_PX = 0.25
#: Smallest drawn radius: a particle always covers at least its centre pixel.
MIN_RADIUS_PX = 0.5
#: Line width of domain and obstacle outlines, as a fraction of the image height
#: (render.py uses the same fraction for GGUI's canvas.lines).
LINE_WIDTH_FRACTION = 0.0028


@functools.lru_cache(maxsize=256)
def _disc(r_q: int):
    """Pixel offsets covered by a disc of radius r_q * RADIUS_QUANTUM_PX around a pixel
    centre: (dx, dy, nx, ny) with (nx, ny) the offset divided by the radius (for the
    sphere normal). Cached: there are only a few distinct radii per frame."""
    r = max(r_q * RADIUS_QUANTUM_PX, MIN_RADIUS_PX)
    k = int(np.ceil(r))
    dy, dx = np.mgrid[-k : k + 1, -k : k + 1]
    inside = dx * dx + dy * dy <= r * r
    if not inside.any():
        inside[k, k] = True
    dx, dy = dx[inside].astype(np.int64), dy[inside].astype(np.int64)
    return dx, dy, dx / r, dy / r


def _quantise(r_px: np.ndarray) -> np.ndarray:
    return np.maximum(np.rint(np.asarray(r_px) / RADIUS_QUANTUM_PX), 0).astype(np.int64)


# 3x5 bitmap glyphs for the legend (drawn by hand; '#' = ink).
_GLYPHS = {
    "0": ("###", "#.#", "#.#", "#.#", "###"),
    "1": (".#.", "##.", ".#.", ".#.", "###"),
    "2": ("###", "..#", "###", "#..", "###"),
    "3": ("###", "..#", ".##", "..#", "###"),
    "4": ("#.#", "#.#", "###", "..#", "..#"),
    "5": ("###", "#..", "###", "..#", "###"),
    "6": ("###", "#..", "###", "#.#", "###"),
    "7": ("###", "..#", ".#.", ".#.", ".#."),
    "8": ("###", "#.#", "###", "#.#", "###"),
    "9": ("###", "#.#", "###", "..#", "###"),
    ".": ("...", "...", "...", "...", ".#."),
    "=": ("...", "###", "...", "###", "..."),
    "-": ("...", "...", "###", "...", "..."),
    " ": ("...", "...", "...", "...", "..."),
    "L": ("#..", "#..", "#..", "#..", "###"),
    "t": (".#.", "###", ".#.", ".#.", ".##"),
    "s": ("...", ".##", "##.", "..#", "##."),
    "V": ("#.#", "#.#", "#.#", "#.#", ".#."),
}


class Rasterizer:
    """Software renderer for snapshots into (H, W, 3) uint8 images."""

    def __init__(self, width: int, height: int):
        self.width, self.height = int(width), int(height)

    # -- public ------------------------------------------------------------------------
    def render(
        self,
        snapshot,
        color_mode: str = "level",
        show_virtual: bool = False,
        camera: OrbitCamera | None = None,
        legend: bool = True,
        style: Style | None = None,
        rest_density: float | None = None,
        marks=(),
        surface: bool = False,
        tint: bool = False,
    ) -> np.ndarray:
        """Draw one frame. ``camera`` is used in 3D (default: framed on the domain).
        ``marks``, ``surface`` and ``tint`` as for :meth:`mrsph.app.render.Renderer.draw`."""
        self.marks, self.surface, self.tint = list(marks or ()), bool(surface), bool(tint)
        self.legend = bool(legend)
        w, h = self.width, self.height
        self.style = style or Style()
        self._img = np.empty((h * w, 3), dtype=np.float32)
        self._img[:] = self.style.background
        rgb = palette.colours(snapshot, color_mode, rest_density=rest_density)
        keep = np.ones(len(rgb), dtype=bool) if show_virtual else ~palette.is_virtual(snapshot.kind)
        self.avoid = None
        if legend:  # the GGUI legend's place, so that both renderers frame alike
            rows = len(legend_lines(snapshot, color_mode, self.surface, self.tint))
            lx, ly, lw, lh = legend_box((w, h), rows)
            self.avoid = (lx, h - ly - lh - LEGEND_MARGIN_PX, lx + lw + LEGEND_MARGIN_PX, h)
        if snapshot.dim == 2:
            self._render_flat(snapshot, rgb, keep)
        else:
            if camera is None:
                camera = framed_camera(None, snapshot.domain_min, snapshot.domain_max, (w, h), avoid=self.avoid)
            self._render_perspective(snapshot, rgb, keep, camera)
        if legend:
            self._legend(snapshot, color_mode)
        out = np.clip(self._img * 255.0 + 0.5, 0, 255).astype(np.uint8).reshape(h, w, 3)
        return np.ascontiguousarray(out[::-1])  # pixel rows are y-up; images are top-down

    # -- 2D ----------------------------------------------------------------------------
    def view2d(self, snap) -> View2D:
        """The frame's 2D view: the domain fitted clear of the legend, as the GGUI
        renderer fits it (mrsph.app.render.Renderer.view2d), so both frame it alike."""
        return fitted_view(snap.domain_min, snap.domain_max, self.width, self.height, avoid=self.avoid)

    def _render_flat(self, snap, rgb, keep):
        view = self.view2d(snap)
        level = np.asarray(snap.level)
        virt = palette.is_virtual(snap.kind)
        edge = None
        if self.surface:
            water = self._fill_water(snap, rgb, view)
            edge = water.surface if water is not None else None
            keep = keep & virt
        px = view.world_to_px(np.asarray(snap.x)[:, :2])
        scale = palette.DISC_SCALE * self.style.point_scale
        radius_px = view.radius_px(np.asarray(snap.radius, dtype=np.float64)) * scale
        # Painter's order: coarse below fine (fine detail on top), virtual ones last, smaller.
        for want_virtual in (False, True):
            share = palette.VIRTUAL_SCALE if want_virtual else 1.0
            for lvl in range(int(snap.levels) - 1, -1, -1):
                sel = keep & (level == lvl) & (virt == want_virtual)
                if sel.any():
                    self._stamp_flat(px[sel], _quantise(share * radius_px[lvl]), rgb[sel])
        # outside the domain is background (the discs and the body stop at the walls),
        # and the obstacles cover what reached into them
        (x0, y0), (x1, y1) = view.world_to_px(np.array([snap.domain_min[:2], snap.domain_max[:2]], np.float64))
        img = self._img.reshape(self.height, self.width, 3)
        cols, rows = np.arange(self.width) + 0.5, np.arange(self.height) + 0.5
        img[:, (cols < x0) | (cols > x1)] = self.style.background
        img[(rows < y0) | (rows > y1), :] = self.style.background
        for obs in snap.obstacles:
            self._fill_triangles(view.world_to_px(geometry.obstacle_triangles(obs)), palette.OBSTACLE_FILL)
        lw = max(LINE_WIDTH_FRACTION * self.height, 1.0)
        for obs in snap.obstacles:
            self._lines_flat(view.world_to_px(geometry.obstacle_segments(obs, 2)), palette.OBSTACLE_EDGE, lw)
        self._lines_flat(
            view.world_to_px(geometry.domain_segments(snap.domain_min, snap.domain_max)), palette.DOMAIN_COLOUR, lw
        )
        if edge is not None and len(edge):
            self._lines_flat(view.world_to_px(edge), palette.WATER_EDGE, lw)
        for mark in self.marks:
            self._lines_flat(view.world_to_px(geometry.mark_segments(mark, 2)), palette.MARK_COLOURS[mark.kind], lw)

    def _fill_water(self, snap, rgb, view):
        """2D water view: pixels whose φ (bilinear on the body's grid) reaches the level
        set take the colour of the nearest node; the drops are stamped as discs. Returns
        the body (its lit surface is drawn with the lines)."""
        from mrsph.io.surface import ISO

        water = geometry.water(snap, rgb, self.tint)
        if water is None:
            return None
        grid = water.grid
        ys, xs = np.mgrid[0 : self.height, 0 : self.width]
        world = view.px_to_world(np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], axis=1))
        u = (world - grid.origin) / grid.cell
        nx, ny = grid.phi.shape
        ok = (u[:, 0] >= 0) & (u[:, 0] < nx - 1) & (u[:, 1] >= 0) & (u[:, 1] < ny - 1)
        i0 = np.floor(u[ok]).astype(np.int64)
        f = u[ok] - i0
        p = grid.phi
        phi = (
            (1 - f[:, 0]) * (1 - f[:, 1]) * p[i0[:, 0], i0[:, 1]]
            + f[:, 0] * (1 - f[:, 1]) * p[i0[:, 0] + 1, i0[:, 1]]
            + (1 - f[:, 0]) * f[:, 1] * p[i0[:, 0], i0[:, 1] + 1]
            + f[:, 0] * f[:, 1] * p[i0[:, 0] + 1, i0[:, 1] + 1]
        )
        inside = np.nonzero(ok)[0][phi >= ISO]
        near = np.rint(u[inside]).astype(np.int64)
        self._img[inside] = grid.rgb[near[:, 0], near[:, 1]]
        if len(water.drops):
            r_q = _quantise(view.radius_px(water.drop_radius))
            px = view.world_to_px(water.drops)
            for q in np.unique(r_q):
                sel = r_q == q
                self._stamp_flat(px[sel], q, water.drop_colours[sel])
        return water

    def _indices(self, px: np.ndarray, dx: np.ndarray, dy: np.ndarray):
        """Flat pixel indices (n, k) of stamps at pixel positions px, and a validity mask."""
        cx = np.floor(px[:, 0]).astype(np.int64)[:, None] + dx[None, :]
        cy = np.floor(px[:, 1]).astype(np.int64)[:, None] + dy[None, :]
        ok = (cx >= 0) & (cx < self.width) & (cy >= 0) & (cy < self.height)
        return cy * self.width + cx, ok

    def _stamp_flat(self, px, r_q, rgb):
        dx, dy, _, _ = _disc(int(r_q))
        idx, ok = self._indices(px, dx, dy)
        col = np.broadcast_to(rgb[:, None, :], idx.shape + (3,))
        self._img[idx[ok]] = col[ok]

    def _fill_triangles(self, tri_px: np.ndarray, colour):
        """Fill triangles (3k, 2) given in pixel coordinates (y up); pixel centres inside
        by the edge-function test."""
        for a, b, c in tri_px.reshape(-1, 3, 2):
            lo = np.maximum(np.floor(np.minimum(np.minimum(a, b), c)).astype(int), 0)
            hi = np.minimum(np.ceil(np.maximum(np.maximum(a, b), c)).astype(int), [self.width - 1, self.height - 1])
            if np.any(hi < lo):
                continue
            ys, xs = np.mgrid[lo[1] : hi[1] + 1, lo[0] : hi[0] + 1]
            p = np.stack([xs + 0.5, ys + 0.5], axis=-1)

            def edge(u, v, p=p):
                return (v[0] - u[0]) * (p[..., 1] - u[1]) - (v[1] - u[1]) * (p[..., 0] - u[0])

            e0, e1, e2 = edge(a, b), edge(b, c), edge(c, a)
            inside = ((e0 >= 0) & (e1 >= 0) & (e2 >= 0)) | ((e0 <= 0) & (e1 <= 0) & (e2 <= 0))
            self._img[(ys[inside] * self.width + xs[inside])] = colour

    def _sample_segments(self, seg_px: np.ndarray):
        """Points every half pixel along segments (2k, 2) -> (M, 2) and the segment
        parameter t of each point (for interpolating depth)."""
        a, b = seg_px[0::2], seg_px[1::2]
        length = np.linalg.norm(b - a, axis=1)
        counts = np.clip(np.ceil(length * 2.0).astype(np.int64) + 1, 2, 20000)
        seg = np.repeat(np.arange(len(a)), counts)
        start = np.repeat(np.cumsum(counts) - counts, counts)
        t = (np.arange(counts.sum()) - start) / np.repeat(counts - 1, counts)
        return a[seg] + (b[seg] - a[seg]) * t[:, None], seg, t

    def _lines_flat(self, seg_px, colour, width_px):
        if len(seg_px) == 0:
            return
        pts, _, _ = self._sample_segments(seg_px)
        dx, dy, _, _ = _disc(int(_quantise(width_px / 2.0)))
        idx, ok = self._indices(pts, dx, dy)
        self._img[idx[ok]] = colour

    # -- 3D ----------------------------------------------------------------------------
    def _render_perspective(self, snap, rgb, keep, cam: OrbitCamera):
        w, h = self.width, self.height
        f = cam.focal_px(h)
        self._zbuf = np.full(w * h, np.inf, dtype=np.float64)
        frags = []  # (idx, depth, colour) of every fragment, resolved by the z-buffer
        radius = np.asarray(snap.radius, dtype=np.float64)[np.asarray(snap.level)] * self.style.point_scale
        radius = np.where(palette.is_virtual(snap.kind), palette.VIRTUAL_SCALE * radius, radius)
        if self.surface:
            frags += self._mesh_splats(cam, snap, rgb, f)
            keep = keep & palette.is_virtual(snap.kind)
        frags += self._spheres(cam, np.asarray(snap.x)[keep], radius[keep], rgb[keep], f)
        for obs in snap.obstacles:
            pts, r = geometry.obstacle_shell(obs)
            if len(pts):
                col = np.broadcast_to(np.asarray(palette.OBSTACLE_FILL, np.float32) * 1.5, (len(pts), 3))
                frags += self._spheres(cam, pts, np.full(len(pts), r), col, f)
        lw = max(LINE_WIDTH_FRACTION * h, 1.0)
        frags += self._lines_zbuffered(
            cam, geometry.domain_segments(snap.domain_min, snap.domain_max), palette.DOMAIN_COLOUR, lw
        )
        for obs in snap.obstacles:
            if obs.get("shape") == "box":
                frags += self._lines_zbuffered(cam, geometry.obstacle_segments(obs, 3), palette.OBSTACLE_EDGE, lw)
        for mark in self.marks:
            frags += self._lines_zbuffered(
                cam, geometry.mark_segments(mark, 3, cam.basis()[0]), palette.MARK_COLOURS[mark.kind], lw
            )
        if not frags:
            return
        idx = np.concatenate([fr[0] for fr in frags])
        depth = np.concatenate([fr[1] for fr in frags])
        col = np.concatenate([fr[2] for fr in frags])
        np.minimum.at(self._zbuf, idx, depth)
        win = depth <= self._zbuf[idx]
        self._img[idx[win]] = col[win]

    def _spheres(self, cam, x, r_world, rgb, focal):
        """Fragments of shaded sphere splats."""
        if len(x) == 0:
            return []
        px, z = cam.project(x, self.width, self.height)
        front = z > cam.z_near
        px, z, r_world, rgb = px[front], z[front], r_world[front], np.asarray(rgb)[front]
        r_q = _quantise(r_world * focal / z)
        out = []
        for q in np.unique(r_q):
            sel = r_q == q
            dx, dy, nx, ny = _disc(int(q))
            nz = np.sqrt(np.clip(1.0 - nx * nx - ny * ny, 0.0, 1.0))
            shade = AMBIENT + DIFFUSE * np.maximum(
                nx * LIGHT_DIR_VIEW[0] + ny * LIGHT_DIR_VIEW[1] + nz * LIGHT_DIR_VIEW[2], 0.0
            )
            idx, ok = self._indices(px[sel], dx, dy)
            depth = z[sel][:, None] - r_world[sel][:, None] * nz[None, :]
            col = rgb[sel][:, None, :] * shade[None, :, None].astype(np.float32)
            out.append((idx[ok], depth[ok], np.minimum(col, 1.0)[ok]))
        return out

    def _mesh_splats(self, cam, snap, rgb, focal):
        """3D water view without GPU: each triangle of the surface mesh as a flat disc
        of its size at its centroid, lit by its normal (the triangles are a few pixels)."""
        water = geometry.water(snap, rgb)
        if water is None or len(water[1]) == 0:
            return []
        tri = water[1].reshape(-1, 3, 3)
        c = tri.mean(axis=1)
        nrm = water[2].reshape(-1, 3, 3).mean(axis=1)
        col = water[3].reshape(-1, 3, 3).mean(axis=1)
        forward, right, up = cam.basis()
        n_view = np.stack([nrm @ right, nrm @ up, -(nrm @ forward)], axis=1)
        shade = AMBIENT + DIFFUSE * np.abs(n_view @ LIGHT_DIR_VIEW)  # two-sided, as GGUI draws it
        size = np.sqrt(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1))
        px, z = cam.project(c, self.width, self.height)
        front = z > cam.z_near
        out = []
        r_q = _quantise(0.75 * size[front] * focal / z[front])
        px, z, col, shade = px[front], z[front], col[front], shade[front]
        for q in np.unique(r_q):
            sel = r_q == q
            dx, dy, _, _ = _disc(int(q))
            idx, ok = self._indices(px[sel], dx, dy)
            depth = np.broadcast_to(z[sel][:, None], idx.shape)
            colour = np.broadcast_to(np.minimum(col[sel] * shade[sel, None], 1.0)[:, None, :], idx.shape + (3,))
            out.append((idx[ok], depth[ok], colour[ok].astype(np.float32)))
        return out

    def _lines_zbuffered(self, cam, seg_world, colour, width_px):
        if len(seg_world) == 0:
            return []
        pts_px, z = cam.project(seg_world, self.width, self.height)
        a_ok = z[0::2] > cam.z_near
        b_ok = z[1::2] > cam.z_near
        both = np.repeat(a_ok & b_ok, 2)  # segments crossing the near plane are dropped
        if not both.any():
            return []
        pts, seg, t = self._sample_segments(pts_px[both])
        za, zb = z[both][0::2], z[both][1::2]
        # Perspective-correct depth along the segment: 1/z is linear in screen space.
        depth = 1.0 / ((1.0 - t) / za[seg] + t / zb[seg])
        dx, dy, _, _ = _disc(int(_quantise(width_px / 2.0)))
        idx, ok = self._indices(pts, dx, dy)
        # Small bias so a line lying on a surface is not hidden by that surface.
        d = np.broadcast_to((depth * 0.995)[:, None], idx.shape)
        col = np.broadcast_to(np.asarray(colour, np.float32), idx.shape + (3,))
        return [(idx[ok], d[ok], col[ok])]

    # -- legend ------------------------------------------------------------------------
    def _text(self, s: str, x: int, y_top: int, scale: int, colour):
        """Bitmap text; (x, y_top) in pixels, y up, at the top-left of the first glyph."""
        for ch in s:
            g = _GLYPHS.get(ch, _GLYPHS[" "])
            for row, line in enumerate(g):
                for col, c in enumerate(line):
                    if c == "#":
                        x0, y0 = x + col * scale, y_top - (row + 1) * scale
                        self._rect(x0, y0, scale, scale, colour)
            x += 4 * scale

    def _rect(self, x0, y0, w, h, colour):
        xs = slice(max(x0, 0), min(x0 + w, self.width))
        ys = slice(max(y0, 0), min(y0 + h, self.height))
        img = self._img.reshape(self.height, self.width, 3)
        img[ys, xs] = colour

    def _legend(self, snap, color_mode):
        """Level swatches "L0 L1 .." in the top-left corner, and the simulated time.
        Level colours are the legend of every mode's most important question: where
        is the solver refining."""
        scale = max(1, int(round(self.height / 220)))
        pad = 4 * scale
        x, y = pad, self.height - pad
        box = 5 * scale
        if color_mode == "level":
            for lvl in range(int(snap.levels)):
                self._rect(x, y - box, box, box, palette.level_colour(lvl))
                self._text(f"L{lvl}", x + box + 2 * scale, y, scale, (0.85, 0.87, 0.9))
                x += box + 2 * scale + 3 * 4 * scale + pad
        self._text(f"t={float(snap.time):.2f}s", x, y, scale, (0.85, 0.87, 0.9))


def rasterize(
    snapshot,
    width: int = 960,
    height: int = 540,
    color_mode: str = "level",
    show_virtual: bool = False,
    camera: OrbitCamera | None = None,
    legend: bool = True,
    style: Style | None = None,
    rest_density: float | None = None,
    marks=(),
    surface: bool = False,
    tint: bool = False,
) -> np.ndarray:
    """One-shot convenience: render ``snapshot`` into an (height, width, 3) uint8 image."""
    return Rasterizer(width, height).render(
        snapshot, color_mode, show_virtual, camera, legend, style, rest_density, marks, surface, tint
    )

"""The GGUI renderer: the one drawing routine behind the interactive window and the
offscreen (``show_window=False``) recorder, so a video looks like the window.

It reads a snapshot (numpy, host side), packs GGUI's vertex buffers with numpy
(:mod:`mrsph.app.vbo`: no Taichi kernel to compile, at the first frame or ever), and
draws

* 2D: ``canvas.circles`` with per-vertex colour and radius, in painter's order
  (coarse under fine, virtual ones shown smaller on top), obstacles filled with ``canvas.triangles``,
  domain and obstacle outlines with ``canvas.lines``, letterboxed by
  :class:`~mrsph.app.view.View2D`;
* 3D: ``scene.particles`` with per-vertex colour and radius, obstacle shells as small
  spheres, domain and box-obstacle wireframes with ``scene.lines``, seen through an
  :class:`~mrsph.app.view.OrbitCamera` (y up, framed on the domain at first);
* a legend sub-window (level colours, or the colormap range) and the simulated time;
* marks of what acts on the water (the mouse's reach, the scene's stirrers) as circles
  (3D: rings facing the camera), and, in the water view (``surface=True``), the fluid
  as a filled, level-tinted area with its outline (2D) or a lit mesh (3D) from
  :mod:`mrsph.io.surface` instead of the particles.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import taichi as ti

from . import geometry, palette
from . import legend as key_panel
from .palette import Style
from .raster import AMBIENT, DIFFUSE, LINE_WIDTH_FRACTION
from .vbo import Vertices, pack
from .view import OrbitCamera, View2D, fitted_view, framed_camera

#: Vertices per scene.mesh call: GGUI 1.7.4 on lavapipe drew nothing of a mesh of
#: 75 600 vertices (pool_3d's first water view was invisible; 60 000 and 66 000 drew),
#: so larger meshes are drawn in parts of this many. A multiple of 3: whole triangles.
MESH_CHUNK = 65535
#: 3D line width handed to scene.lines (pixels where the driver supports wide lines).
LINE_WIDTH_3D = 2.0
#: The 2D water view's lit free surface: its line width (a fraction of the height).
SURFACE_LINE_FRACTION = 1.6 * LINE_WIDTH_FRACTION


class Renderer:
    """Draws snapshots into a ``ti.ui.Window`` (visible or offscreen).

    ``camera`` (3D) is created on the first frame from the scene's ``render`` settings
    or the domain box, and is then the caller's to move (the window orbits, pans and
    zooms it); :meth:`reset_view` frames it again.
    """

    def __init__(self, window, style: Style | None = None, scene=None):
        self.window = window
        self.canvas = window.get_canvas()
        self.style = style or Style()
        self.scene_settings = scene  # for the scene's camera_position / camera_lookat
        self.camera: OrbitCamera | None = None
        #: 2D only: (x0, y0, x1, y1) fractions of the window (y up) the domain is fitted
        #: into; the window leaves out its HUD panel.
        self.viewport = (0.0, 0.0, 1.0, 1.0)
        self._scene3d = None
        self._ti_camera = None
        self.gpu = Vertices()  # this frame's vertex buffers
        self._water_edge = None
        self.dim, self.tint, self.surface = 1.0, False, False
        self.legend_shown = False
        self._legend_rows: list = []
        #: the window keeps the legend one size in every colour mode (the view would jump
        #: on c); a recording sizes it to its mode
        self.legend_rows_for_all = False
        #: wall seconds the last frame spent on the water view's surface (bench reads it)
        self.surface_s = 0.0
        self._water_cache = None  # (snapshot, colours, surface) of the last frame
        self._shell_key = None
        self._shell_r, self._shells = 0.0, None  # obstacle shells (3D), kept while they hold

    # -- view --------------------------------------------------------------------------
    @property
    def size(self) -> tuple[int, int]:
        w, h = self.window.get_window_shape()
        return int(w), int(h)

    def view2d(self, snapshot) -> View2D:
        """The 2D world -> canvas map for the current window size (mouse mapping uses
        this same object, so a click lands where it is drawn): the domain fitted into
        ``viewport``, clear of the legend when it is drawn."""
        w, h = self.size
        x0, y0, x1, y1 = self.viewport
        region = (x0 * w, y0 * h, x1 * w, y1 * h)
        avoid = self._legend_avoid(snapshot)
        return fitted_view(snapshot.domain_min, snapshot.domain_max, w, h, region=region, avoid=avoid)

    def legend_box_px(self, snapshot=None) -> tuple[int, int, int, int]:
        """(x, y, width, height) of the legend in pixels, y down; zero when not drawn.
        Its rows: as many as the longest list of any colour mode where the window keeps
        one size for all (``legend_rows_for_all``), else the frame's own."""
        if not self.legend_shown:
            return (0, 0, 0, 0)
        rows = key_panel.MAX_ROWS if self.legend_rows_for_all or snapshot is None else len(self._legend_rows)
        return key_panel.box_px(self.size, rows)

    def clear(self) -> None:
        """A frame of background only (nothing to show yet)."""
        self.canvas.set_background_color(tuple(float(c) for c in self.style.background))

    def ensure_camera(self, snapshot) -> OrbitCamera:
        """The 3D camera; framed, when there is none, within ``viewport`` (the window
        leaves out its HUD panel) and clear of the legend (mrsph.app.view.framed_camera)."""
        if self.camera is None:
            self.camera = framed_camera(
                self.scene_settings,
                snapshot.domain_min,
                snapshot.domain_max,
                self.size,
                self.viewport,
                self._legend_avoid(snapshot),
            )
        return self.camera

    def _legend_avoid(self, snapshot):
        """The legend's box in pixels (x0, y0, x1, y1; y up), with its margin, or None."""
        if not self.legend_shown:
            return None
        w, h = self.size
        lx, ly, lw, lh = self.legend_box_px(snapshot)
        return (lx, h - ly - lh - key_panel.MARGIN_PX, lx + lw + key_panel.MARGIN_PX, h)

    def reset_view(self, scene=None, style: Style | None = None) -> None:
        """Forget the camera (re-framed on the next draw); optionally a new scene/style."""
        self.camera = None
        if scene is not None:
            self.scene_settings = scene
        if style is not None:
            self.style = style

    # -- drawing -----------------------------------------------------------------------
    def draw(
        self,
        snapshot,
        color_mode: str = "level",
        show_virtual: bool = False,
        legend: bool = True,
        rest_density: float | None = None,
        marks=(),
        surface: bool = False,
        tint: bool = False,
        dim: float = 1.0,
    ) -> None:
        """Draw one frame (call ``window.show()`` or read the image buffer afterwards).
        ``marks``: :class:`~mrsph.app.geometry.Mark` circles to draw over the fluid;
        ``surface``: the water view, ``tint``: in the colour mode's colours; ``dim``:
        the fluid's brightness (the window dims a scene it is leaving)."""
        self.marks, self.surface, self.tint = list(marks or ()), bool(surface), bool(tint)
        self.legend_shown = bool(legend)
        self._legend_rows = key_panel.lines(snapshot, color_mode, self.surface, self.tint) if legend else []
        self.dim = float(dim)
        self.canvas.set_background_color(tuple(float(c) for c in self.style.background))
        rgb = palette.colours(snapshot, color_mode, rest_density=rest_density)
        if self.dim != 1.0:
            rgb = (rgb * self.dim).astype(np.float32)
        keep = np.ones(len(rgb), dtype=bool) if show_virtual else ~palette.is_virtual(snapshot.kind)
        self.gpu.new_frame()
        if snapshot.dim == 2:
            self._draw_canvas(snapshot, rgb, keep)
        else:
            self._draw_scene(snapshot, rgb, keep)
        if legend:
            rows = self._legend_rows
            tri, col = key_panel.swatch_triangles(rows, self.size, self.legend_box_px(snapshot))
            self.gpu.triangles(self.canvas, pack(tri, colour=col), per_colour=True)
            key_panel.draw_panel(self.window.get_gui(), rows, self.size, self.legend_box_px(snapshot))

    def _draw_canvas(self, snap, rgb, keep):
        """2D, in painter's order: the water body (water view), the particles, the
        drops, the world outside the domain covered, the obstacles, the lines."""
        view = self.view2d(snap)
        h = view.height
        level = np.asarray(snap.level)
        virt = palette.is_virtual(snap.kind)
        water = self._water(snap, rgb)
        if water is not None:
            if len(water.triangles):
                tri = view.world_to_canvas(water.triangles)
                self.gpu.triangles(self.canvas, pack(tri, colour=water.colours), per_colour=True)
            keep = keep & virt  # the body stands for the real particles
            self._water_edge = water.surface
        idx = np.nonzero(keep)[0]
        # Painter's order: coarse to fine, so fine detail is on top; virtual ones last, smaller
        idx = idx[np.lexsort((-level[idx], virt[idx]))]
        if len(idx):
            pos = view.world_to_canvas(np.asarray(snap.x)[idx, :2])
            # per_vertex_radius is a fraction of the window height in GGUI's canvas.
            rad = view.radius_px(np.asarray(snap.radius)[level[idx]]) * palette.DISC_SCALE * self.style.point_scale / h
            rad = np.where(virt[idx], palette.VIRTUAL_SCALE * rad, rad)
            self.gpu.circles(self.canvas, pack(pos, radius=rad, colour=rgb[idx]), per_colour=True, per_radius=True)
        if water is not None and len(water.drops):
            r = view.radius_px(water.drop_radius) / h
            drops = pack(view.world_to_canvas(water.drops), radius=r, colour=water.drop_colours)
            self.gpu.circles(self.canvas, drops, per_colour=True, per_radius=True)
        # what lies outside the domain is the background: the discs and the body's
        # edge at the walls stop at them (and the obstacles, drawn next, cover theirs)
        outside = geometry.outside_domain_triangles(view, snap.domain_min, snap.domain_max)
        self.gpu.triangles(self.canvas, pack(outside), False, tuple(float(c) for c in self.style.background))
        tris = [geometry.obstacle_triangles(o) for o in snap.obstacles]
        if tris:
            tri = view.world_to_canvas(np.concatenate(tris))
            self.gpu.triangles(self.canvas, pack(tri), False, palette.OBSTACLE_FILL)
        if self._water_edge is not None and len(self._water_edge):
            edge = pack(view.world_to_canvas(self._water_edge))
            self.gpu.lines(self.canvas, edge, SURFACE_LINE_FRACTION, False, [c * self.dim for c in palette.WATER_EDGE])
        segs, cols = self._outline_segments(snap, 2)
        self.gpu.lines(self.canvas, pack(view.world_to_canvas(segs), colour=cols), LINE_WIDTH_FRACTION, True)

    def _water(self, snap, rgb):
        """The water view (mrsph.app.geometry.water), or None when it is off; the time
        it took in ``surface_s`` (the same snapshot and colours: reused, at no cost)."""
        import time

        self._water_edge = None
        if not self.surface:
            self.surface_s = 0.0
            self._water_cache = None
            return None
        key = (self.tint, self.dim)
        cached = self._water_cache
        if cached is not None and cached[0] is snap and cached[1] == key and np.array_equal(cached[2], rgb):
            # the same snapshot and colours (paused, or the simulation did not advance)
            self.surface_s = 0.0
            return cached[3]
        t0 = time.perf_counter()
        out = geometry.water(snap, rgb, self.tint, self.dim)
        self.surface_s = time.perf_counter() - t0
        self._water_cache = (snap, key, np.array(rgb), out)
        return out

    def _outline_segments(self, snap, dim):
        """Domain outline and obstacle outlines (2D) or box wireframes (3D), the water's
        outline (2D water view) and the marks, with colours."""
        parts = [(geometry.domain_segments(snap.domain_min, snap.domain_max), palette.DOMAIN_COLOUR)]
        for o in snap.obstacles:
            if dim == 2 or o.get("shape") == "box":
                parts.append((geometry.obstacle_segments(o, dim), palette.OBSTACLE_EDGE))
        facing = self.camera.basis()[0] if dim == 3 and self.camera is not None else None
        for mark in getattr(self, "marks", ()):
            parts.append((geometry.mark_segments(mark, dim, facing), palette.MARK_COLOURS[mark.kind]))
        segs = np.concatenate([p for p, _ in parts])
        cols = np.concatenate([np.tile(np.asarray(c, np.float32), (len(p), 1)) for p, c in parts])
        return segs, cols

    def _draw_scene(self, snap, rgb, keep):
        cam = self.ensure_camera(snap)
        if self._scene3d is None:
            self._scene3d = self.window.get_scene()
            self._ti_camera = ti.ui.Camera()
        scene, tc = self._scene3d, self._ti_camera
        tc.position(*cam.position)
        tc.lookat(*cam.look_at)
        tc.up(0.0, 1.0, 0.0)
        tc.fov(cam.fov)
        tc.z_near(cam.z_near)
        tc.z_far(cam.z_far)
        scene.set_camera(tc)
        # A headlight a little above-left of the eye: same look as the rasteriser.
        forward, right, up = cam.basis()
        light = cam.position + (up * 0.45 - right * 0.25) * cam.distance
        scene.ambient_light((AMBIENT,) * 3)
        scene.point_light(tuple(light), (DIFFUSE,) * 3)

        water = self._water(snap, rgb)
        if water is not None:
            verts, normals, vrgb = water[1], water[2], water[3]
            for start in range(0, len(verts), MESH_CHUNK):
                part = slice(start, start + MESH_CHUNK)
                self.gpu.mesh(scene, pack(verts[part], normal=normals[part], colour=vrgb[part]), per_colour=True)
            keep = keep & palette.is_virtual(snap.kind)
        if keep.any():
            rad = np.asarray(snap.radius, np.float64)[np.asarray(snap.level)[keep]] * self.style.point_scale
            rad = np.where(palette.is_virtual(snap.kind)[keep], palette.VIRTUAL_SCALE * rad, rad)
            fluid = pack(np.asarray(snap.x)[keep], radius=rad, colour=rgb[keep])
            self.gpu.particles(scene, fluid, per_colour=True, per_radius=True, radius=float(rad.max()))
        self._draw_shells(scene, snap)
        segs, cols = self._outline_segments(snap, 3)
        self.gpu.scene_lines(scene, pack(segs, colour=cols), LINE_WIDTH_3D, per_colour=True)
        self.canvas.scene(scene)

    def _draw_shells(self, scene, snap):
        """Obstacles as point-sampled shells; resampled only when the obstacles change."""
        key = repr(snap.obstacles)
        if key != self._shell_key:
            shells = [geometry.obstacle_shell(o) for o in snap.obstacles]
            pts = [p for p, _ in shells if len(p)]
            self._shell_r = min([r for p, r in shells if len(p)], default=0.0)
            self._shells = pack(np.concatenate(pts)) if pts else pack(np.zeros((0, 3)))
            self._shell_key = key
        colour = tuple(min(c * 1.5, 1.0) for c in palette.OBSTACLE_FILL)
        self.gpu.particles(scene, self._shells, False, False, colour, self._shell_r)


class ImguiIniGuard:
    """ImGui inside GGUI saves its window layout to ``./imgui.ini`` (a few seconds after
    a panel first appears, and when the window closes). The app places its panels
    itself, so the file is clutter in the user's directory: at the end, put back what
    was there before (remove the file, or restore its old content)."""

    def __init__(self):
        self.path = Path.cwd() / "imgui.ini"
        try:
            self.before = self.path.read_bytes()
        except OSError:
            self.before = None

    def cleanup(self) -> None:
        try:
            if self.before is None:
                self.path.unlink(missing_ok=True)
            elif not self.path.exists() or self.path.read_bytes() != self.before:
                self.path.write_bytes(self.before)
        except OSError:
            pass


def image_from_window(window) -> np.ndarray:
    """The window's current frame as an (H, W, 3) uint8 image, top row first.

    ``get_image_buffer_as_numpy`` returns (W, H, 4) floats indexed [x, y] with y up
    (checked by rendering a dot at canvas (0.1, 0.1): it lands at buffer [0.1 W, 0.1 H]),
    so transpose to rows and flip them.
    """
    buf = window.get_image_buffer_as_numpy()
    rgb = np.clip(buf[:, :, :3], 0.0, 1.0)
    return np.ascontiguousarray((rgb.transpose(1, 0, 2)[::-1] * 255.0 + 0.5).astype(np.uint8))

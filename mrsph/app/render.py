"""The GGUI renderer: the one drawing routine behind the interactive window and the
offscreen (``show_window=False``) recorder, so a video looks like the window.

It reads a snapshot (numpy, host side), uploads it into Taichi fields sized for a
capacity that only grows (no per-frame field creation: each new field costs a
compile and a memory block Taichi never returns), and draws

* 2D: ``canvas.circles`` with per-vertex colour and radius, in painter's order
  (virtual under real, coarse under fine), obstacles filled with ``canvas.triangles``,
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

``canvas.circles`` / ``canvas.lines`` / ``canvas.triangles`` always draw their whole
field, so unused slots are parked far outside the view (``_PARK``) with radius 0.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import taichi as ti

from . import geometry, palette
from .palette import Style
from .raster import AMBIENT, DIFFUSE, LINE_WIDTH_FRACTION
from .view import OrbitCamera, View2D, camera_for_scene, scene_setting

#: Where unused slots go: far outside the [0, 1]^2 canvas and any 3D view.
_PARK = -1.0e6
#: Smallest capacity of a particle buffer, and how much it grows when it must: growing
#: by half again keeps reallocations rare while a refining fluid gains particles.
_MIN_CAPACITY = 1024
#: Vertices per scene.mesh field: GGUI 1.7.4 on lavapipe drew nothing of a mesh of
#: 75 600 vertices (pool_3d's first water view was invisible; 60 000 and 66 000 drew),
#: so larger meshes are drawn in parts of this many. A multiple of 3: whole triangles.
MESH_CHUNK = 65535
_GROWTH = 1.5
#: 3D line width handed to scene.lines (pixels where the driver supports wide lines).
LINE_WIDTH_3D = 2.0
#: Legend sub-window size in pixels: ImGui's default font is 13 px with ~4 px spacing,
#: plus a title bar; sized in pixels so the text fits at any window size.
LEGEND_WIDTH_PX = 230
LEGEND_LINE_PX = 17
LEGEND_CHROME_PX = 38
LEGEND_MARGIN_PX = 8


class _Buffer:
    """A Taichi field of ``components``-vectors (or scalars when 0) that grows on demand.

    ``upload(a)`` writes ``a`` (n rows) into the first n slots and parks the rest, using
    a persistent numpy staging array so a frame allocates nothing on the Taichi side.
    """

    def __init__(self, components: int, park: float, max_capacity: int | None = None):
        self.components, self.park, self.max_capacity = components, park, max_capacity
        self.capacity = 0
        self.field = None
        self._staging = None

    def _allocate(self, n: int) -> None:
        cap = max(_MIN_CAPACITY, int(n * _GROWTH) if self.capacity else n)
        if self.max_capacity:
            cap = max(min(cap, self.max_capacity), n)
        shape = (cap, self.components) if self.components else (cap,)
        if self.components:
            self.field = ti.Vector.field(self.components, ti.f32, shape=cap)
        else:
            self.field = ti.field(ti.f32, shape=cap)
        self._staging = np.full(shape, self.park, dtype=np.float32)
        self.capacity = cap

    def upload(self, a: np.ndarray):
        a = np.asarray(a, dtype=np.float32)
        n = len(a)
        if n > self.capacity:
            self._allocate(n)
        self._staging[:n] = a
        self._staging[n:] = self.park
        self.field.from_numpy(self._staging)
        return self.field


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
        self._pos2 = _Buffer(2, _PARK)
        self._pos3 = _Buffer(3, _PARK)
        self._col = _Buffer(3, 0.0)
        self._rad = _Buffer(0, 0.0)
        self._tri = _Buffer(2, _PARK)
        self._line2 = _Buffer(2, _PARK)
        self._line3 = _Buffer(3, _PARK)
        self._line_col = _Buffer(3, 0.0)
        self._shell_pos = _Buffer(3, _PARK)
        self._mesh: list = []  # 3D water: (vertices, normals, colours) per chunk
        self._mesh_c = _Buffer(3, 0.0)
        self._area_v = _Buffer(2, _PARK)
        #: wall seconds the last frame spent on the water view's surface (bench reads it)
        self.surface_s = 0.0
        self._water_cache = None  # (snapshot, colours, surface) of the last frame
        self._shell_key = None
        self._shell_r = 0.0

    # -- view --------------------------------------------------------------------------
    @property
    def size(self) -> tuple[int, int]:
        w, h = self.window.get_window_shape()
        return int(w), int(h)

    def view2d(self, snapshot) -> View2D:
        """The 2D world -> canvas map for the current window size (mouse mapping uses
        this same object, so a click lands where it is drawn)."""
        w, h = self.size
        x0, y0, x1, y1 = self.viewport
        return View2D(snapshot.domain_min, snapshot.domain_max, w, h, region=(x0 * w, y0 * h, x1 * w, y1 * h))

    def ensure_camera(self, snapshot) -> OrbitCamera:
        """The 3D camera; framed, when there is none, within ``viewport`` (the window
        leaves out its HUD panel): on the domain box fitted to the viewport's width, or
        from the scene's ``render.camera_position`` (framed for a whole image) moved back
        by the viewport's share of the width; its target, the pivot of orbit and zoom, is
        seen at the viewport's centre (``OrbitCamera.lateral``: the projection spans the
        whole window)."""
        if self.camera is None:
            w, h = self.size
            x0, y0, x1, y1 = self.viewport
            cam = camera_for_scene(
                self.scene_settings, snapshot.domain_min, snapshot.domain_max, (x1 - x0) * w / max((y1 - y0) * h, 1.0)
            )
            if scene_setting(self.scene_settings, "render.camera_position", None) is not None:
                cam.distance /= x1 - x0
            centre = x0 + x1 - 1.0  # the viewport's centre, in [-1, 1] across the window
            cam.lateral = centre * math.tan(math.radians(cam.fov) / 2.0) * w / h
            self.camera = cam
        return self.camera

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
    ) -> None:
        """Draw one frame (call ``window.show()`` or read the image buffer afterwards).
        ``marks``: :class:`~mrsph.app.geometry.Mark` circles to draw over the fluid;
        ``surface``: the water view."""
        self.marks, self.surface = list(marks or ()), bool(surface)
        self.canvas.set_background_color(tuple(float(c) for c in self.style.background))
        rgb = palette.colours(snapshot, color_mode, rest_density=rest_density)
        keep = np.ones(len(rgb), dtype=bool) if show_virtual else ~palette.is_virtual(snapshot.kind)
        # GGUI's own staging kernels, compiled in an f64 program, warn "Assign may lose
        # precision: f32 <- f64" a dozen times: not ours to fix, so not shown (mrsph.runtime
        # runs Taichi at WARN, restored after)
        ti.set_logging_level(ti.ERROR)
        try:
            if snapshot.dim == 2:
                self._draw_canvas(snapshot, rgb, keep)
            else:
                self._draw_scene(snapshot, rgb, keep)
        finally:
            ti.set_logging_level(ti.WARN)
        if legend:
            draw_legend(self.window.get_gui(), snapshot, color_mode, self.size, rest_density=rest_density)

    def _draw_canvas(self, snap, rgb, keep):
        view = self.view2d(snap)
        h = view.height
        tris = [geometry.obstacle_triangles(o) for o in snap.obstacles]
        if tris:
            tri = view.world_to_canvas(np.concatenate(tris))
            self.canvas.triangles(self._tri.upload(tri), color=palette.OBSTACLE_FILL)
        level = np.asarray(snap.level)
        virt = palette.is_virtual(snap.kind)
        water = self._water(snap, rgb)
        if water is not None:
            tri, tri_rgb, edge = water[1], water[2], water[3]
            if len(tri):
                self.canvas.triangles(
                    self._area_v.upload(view.world_to_canvas(tri)), per_vertex_color=self._mesh_c.upload(tri_rgb)
                )
            keep = keep & virt  # the surface stands for the real particles
            self._water_edge = edge
        idx = np.nonzero(keep)[0]
        # Painter's order: virtual first, then coarse to fine, so fine detail is on top.
        idx = idx[np.lexsort((-level[idx], ~virt[idx]))]
        if len(idx):
            pos = view.world_to_canvas(np.asarray(snap.x)[idx, :2])
            # per_vertex_radius is a fraction of the window height in GGUI's canvas.
            rad = view.radius_px(np.asarray(snap.radius)[level[idx]]) * self.style.point_scale / h
            self.canvas.circles(
                self._pos2.upload(pos),
                radius=0.0,
                per_vertex_color=self._col.upload(rgb[idx]),
                per_vertex_radius=self._rad.upload(rad),
            )
        segs, cols = self._outline_segments(snap, 2)
        self.canvas.lines(
            self._line2.upload(view.world_to_canvas(segs)),
            width=LINE_WIDTH_FRACTION,
            per_vertex_color=self._line_col.upload(cols),
        )

    def _water(self, snap, rgb):
        """The water view's surface, or None when it is off (timed: surface_s)."""
        import time

        self._water_edge = None
        if not self.surface:
            self.surface_s = 0.0
            self._water_cache = None
            return None
        cached = self._water_cache
        if cached is not None and cached[0] is snap and np.array_equal(cached[1], rgb):
            # the same snapshot and colours (paused, or the simulation did not advance):
            # the same surface, at no cost
            self.surface_s = 0.0
            return cached[2]
        t0 = time.perf_counter()
        out = geometry.water(snap, rgb)
        self.surface_s = time.perf_counter() - t0
        self._water_cache = (snap, np.array(rgb), out)
        return out

    def _outline_segments(self, snap, dim):
        """Domain outline and obstacle outlines (2D) or box wireframes (3D), the water's
        outline (2D water view) and the marks, with colours."""
        parts = [(geometry.domain_segments(snap.domain_min, snap.domain_max), palette.DOMAIN_COLOUR)]
        for o in snap.obstacles:
            if dim == 2 or o.get("shape") == "box":
                parts.append((geometry.obstacle_segments(o, dim), palette.OBSTACLE_EDGE))
        if getattr(self, "_water_edge", None) is not None and len(self._water_edge):
            parts.append((self._water_edge, palette.WATER_EDGE))
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
            if len(verts):
                for k, start in enumerate(range(0, len(verts), MESH_CHUNK)):
                    if k == len(self._mesh):
                        self._mesh.append(tuple(_Buffer(3, p, MESH_CHUNK) for p in (_PARK, 0.0, 0.0)))
                    part = slice(start, start + MESH_CHUNK)
                    bv, bn, bc = self._mesh[k]
                    scene.mesh(
                        bv.upload(verts[part]),
                        normals=bn.upload(normals[part]),
                        per_vertex_color=bc.upload(vrgb[part]),
                        two_sided=True,
                        vertex_count=len(verts[part]),
                    )
            keep = keep & palette.is_virtual(snap.kind)
        n = int(keep.sum())
        if n:
            rad = np.asarray(snap.radius, np.float64)[np.asarray(snap.level)[keep]] * self.style.point_scale
            scene.particles(
                self._pos3.upload(np.asarray(snap.x)[keep]),
                radius=float(rad.max()),
                per_vertex_color=self._col.upload(rgb[keep]),
                per_vertex_radius=self._rad.upload(rad),
                index_count=n,
            )
        self._draw_shells(scene, snap)
        segs, cols = self._outline_segments(snap, 3)
        scene.lines(
            self._line3.upload(segs),
            width=LINE_WIDTH_3D,
            per_vertex_color=self._line_col.upload(cols),
            vertex_count=len(segs),
        )
        self.canvas.scene(scene)

    def _draw_shells(self, scene, snap):
        """Obstacles as point-sampled shells; resampled only when the obstacles change."""
        key = repr(snap.obstacles)
        if key != self._shell_key:
            shells = [geometry.obstacle_shell(o) for o in snap.obstacles]
            pts = [p for p, _ in shells if len(p)]
            self._shell_n = sum(len(p) for p in pts)
            self._shell_r = min([r for p, r in shells if len(p)], default=0.0)
            if self._shell_n:
                self._shell_pos.upload(np.concatenate(pts))
            self._shell_key = key
        if self._shell_n:
            colour = tuple(min(c * 1.5, 1.0) for c in palette.OBSTACLE_FILL)
            scene.particles(self._shell_pos.field, radius=self._shell_r, color=colour, index_count=self._shell_n)


def legend_rect(snapshot, color_mode: str, window_size) -> tuple[float, float, float, float]:
    """(x, y, width, height) of the legend as fractions of the window: top-left corner."""
    lines = 1 + {"level": int(snapshot.levels), "kind": len(palette.KIND_NAMES), "speed": 3, "density": 4}.get(
        color_mode, 0
    )
    w, h = window_size
    return (
        LEGEND_MARGIN_PX / w,
        LEGEND_MARGIN_PX / h,
        min(LEGEND_WIDTH_PX / w, 0.5),
        min((LEGEND_CHROME_PX + LEGEND_LINE_PX * lines) / h, 0.9),
    )


def draw_legend(gui, snapshot, color_mode: str, window_size, rest_density=None) -> None:
    """Legend sub-window: what the colours mean, and the simulated time."""
    x, y, w, h = legend_rect(snapshot, color_mode, window_size)
    # ImGui applies a panel's size only when it first appears: one panel per (mode,
    # level count) so each gets the size its lines need ("##..." is not shown).
    with gui.sub_window(f"Legend##{color_mode}{int(snapshot.levels)}", x, y, w, h):
        gui.text(f"t = {float(snapshot.time):.3f} s")
        if color_mode == "level":
            stats = getattr(snapshot, "stats", {}) or {}
            for lvl in range(int(snapshot.levels)):
                tag = " (finest)" if lvl == 0 and snapshot.levels > 1 else ""
                count = stats.get(f"n_level_{lvl}")
                count = f"  {count}" if count is not None else ""
                gui.text(f"level {lvl}{tag}{count}", color=tuple(float(c) for c in palette.level_colour(lvl)))
        elif color_mode == "kind":
            for code, name in enumerate(palette.KIND_NAMES):
                gui.text(f"{code} {name}", color=tuple(float(c) for c in palette.KIND_COLOURS[code]))
        elif color_mode == "speed":
            top = palette.default_speed_scale(snapshot.domain_min, snapshot.domain_max)
            gui.text("speed |v|")
            gui.text("0 m/s", color=tuple(float(c) for c in palette.speed_colormap(np.array([0.0]))[0]))
            gui.text(
                f"{top:.2f} m/s and above", color=tuple(float(c) for c in palette.speed_colormap(np.array([1.0]))[0])
            )
        elif color_mode == "density":
            hw = palette.DENSITY_RATIO_HALF_RANGE
            gui.text("density rho / rho0")
            for t, label in ((0.0, f"{1 - hw:.2f} and below"), (0.5, "1.00 (rest)"), (1.0, f"{1 + hw:.2f} and above")):
                gui.text(label, color=tuple(float(c) for c in palette.density_colormap(np.array([t]))[0]))


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

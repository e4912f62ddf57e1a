"""Palette, view transforms, the numpy rasteriser and the GGUI renderer (offscreen).

GGUI tests skip with the reason when ``vulkan_available()`` says no. Every drawing test
runs in 2D and 3D on the stand-in simulation of ``fake_app``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from fake_app import FakeSimulation

from mrsph.app import palette
from mrsph.app.raster import Rasterizer, rasterize
from mrsph.app.view import OrbitCamera, View2D

DIMS = [2, 3]
W, H = 480, 270
# The legend occupies the top-left corner in both renderers (different fonts): leave it
# out when comparing where the scene is drawn.
LEGEND_BOX = (slice(0, 130), slice(0, 250))


@pytest.fixture(scope="module")
def taichi_cpu(taichi_f32):
    """Taichi on the CPU (f32) for this module, reset afterwards: conftest's
    ``taichi_f32`` does ti.init / ti.reset through mrsph.runtime."""
    import taichi as ti

    return ti


@pytest.fixture(scope="module")
def vulkan():
    from mrsph.app.record import vulkan_available

    ok, why = vulkan_available()
    if not ok:
        pytest.skip(f"GGUI offscreen rendering unavailable: {why}")
    return why


def fake_snapshot(dim, frames=2, **kw):
    sim = FakeSimulation(dim=dim, **kw)
    for _ in range(frames):
        sim.advance_frame()
    return sim.snapshot()


def background_mask(img) -> np.ndarray:
    bg = np.array(palette.BACKGROUND) * 255.0
    return np.abs(img.astype(np.float32) - bg).max(axis=2) > 30


# ----------------------------------------------------------------------------- palette
@pytest.mark.parametrize("dim", DIMS)
@pytest.mark.parametrize("mode", palette.COLOR_MODES)
def test_colours_every_mode(dim, mode):
    snap = fake_snapshot(dim, frames=1)
    rgb = palette.colours(snap, mode)
    assert rgb.shape == (len(snap.x), 3) and rgb.dtype == np.float32
    assert np.all((rgb >= 0) & (rgb <= 1)), f"{mode}: colours outside [0, 1]: min {rgb.min():.4f}, max {rgb.max():.4f}"
    # The continuous modes must map their input: three real particles (virtual ones
    # are greyed out) get chosen values, and their colours are read off the colormaps.
    a, b, c = np.nonzero(~palette.is_virtual(snap.kind))[0][:3]
    if mode == "speed":
        scale = palette.default_speed_scale(snap.domain_min, snap.domain_max)
        snap.v[a] = 0.0
        snap.v[b] = 0.0
        snap.v[b][0] = scale  # |v| = the top of the colormap
        rgb = palette.colours(snap, mode)
        want = palette.speed_colormap(np.array([0.0, 1.0]))
        np.testing.assert_allclose(
            rgb[[a, b]],
            want,
            atol=1e-5,
            err_msg=f"{dim}D: |v| = 0 and |v| = {scale:.3f} m/s coloured "
            f"{rgb[[a, b]].tolist()}; expected {want.tolist()}",
        )
        gap = float(np.linalg.norm(rgb[b] - rgb[a]))
        assert gap > 0.5, f"{dim}D: slowest and fastest colours only {gap:.3f} apart"
    elif mode == "density":
        rho0 = float(FakeSimulation.REST_DENSITY)
        half = palette.DENSITY_RATIO_HALF_RANGE
        snap.rho[[a, b, c]] = rho0 * np.array([1.0, 1.0 - 0.6 * half, 1.0 + 0.6 * half])
        rgb = palette.colours(snap, mode, rest_density=rho0)
        # rest density at the midpoint (grey), -/+ 60 % of the half range at 0.2 / 0.8
        want = palette.density_colormap(np.array([0.5, 0.2, 0.8]))
        np.testing.assert_allclose(
            rgb[[a, b, c]],
            want,
            atol=1e-5,
            err_msg=f"{dim}D: rho / rho0 = 1, {1 - 0.6 * half}, {1 + 0.6 * half} "
            f"coloured {rgb[[a, b, c]].tolist()}; expected {want.tolist()}",
        )
        lo, hi = rgb[b], rgb[c]
        assert lo[2] > lo[0] + 0.2 and hi[0] > hi[2] + 0.2, (
            f"{dim}D: too light should be blue, compressed red: got {lo} and {hi}"
        )


def test_level_colours_distinct_and_finest_warm():
    lv = palette.LEVEL_COLOURS
    d = np.linalg.norm(lv[:, None] - lv[None], axis=2) + np.eye(len(lv))
    assert d.min() > 0.2, f"two level colours are too close (min distance {d.min():.3f})"
    r, g, b = lv[0]
    assert r > b and r > 0.8, f"level 0 should be warm and bright, got {lv[0]}"


def test_virtual_particles_are_greyed():
    snap = fake_snapshot(2, frames=0)
    rgb = palette.colours(snap, "level")
    virt = palette.is_virtual(snap.kind)
    assert virt.any()
    lvl = snap.level[virt][0]
    sat = lambda c: c.max(axis=-1) - c.min(axis=-1)  # noqa: E731
    assert sat(rgb[virt][0]) < sat(palette.level_colour(lvl)), "virtual colour not washed out"


def test_unknown_colour_mode_is_refused():
    with pytest.raises(ValueError, match="colour mode"):
        palette.colours(fake_snapshot(2, frames=0), "rainbow")


# ----------------------------------------------------------------------------- views
def test_view2d_letterbox_keeps_aspect_and_round_trips():
    view = View2D((0, 0), (2, 1), 1000, 1000)
    corners = view.world_to_px(np.array([[0, 0], [2, 1]]))
    size = corners[1] - corners[0]
    assert math.isclose(size[0] / size[1], 2.0, rel_tol=1e-9), "domain aspect ratio not kept"
    assert math.isclose((corners[0][1] + corners[1][1]) / 2, 500.0), "domain not centred vertically"
    p = np.array([[0.3, 0.7], [1.9, 0.1]])
    np.testing.assert_allclose(view.canvas_to_world(view.world_to_canvas(p)), p, atol=1e-12)


def test_orbit_camera_ray_hits_projected_point():
    cam = OrbitCamera.from_box((0, 0, 0), (1, 0.6, 0.5), aspect=16 / 9)
    p = np.array([[0.8, 0.1, 0.2]])
    px, depth = cam.project(p, 1600, 900)
    o, d = cam.ray(px[0, 0] / 1600, px[0, 1] / 900, 16 / 9)
    closest = o + d * float((p[0] - o) @ d)
    np.testing.assert_allclose(closest, p[0], atol=1e-9)
    assert depth[0] > 0


def test_orbit_camera_matches_ggui_camera(taichi_cpu):
    """Same view and the same perspective scale as GGUI's camera, so the rasteriser and
    the mouse picking agree with what GGUI draws."""
    ti = taichi_cpu
    cam = OrbitCamera.from_box((0, 0, 0), (1.2, 0.7, 0.6), aspect=16 / 9)
    cam.orbit(0.4, -0.1)
    tc = ti.ui.Camera()
    tc.position(*cam.position)
    tc.lookat(*cam.target)
    tc.up(0, 1, 0)
    tc.fov(cam.fov)
    view = np.array(tc.get_view_matrix()).T  # GGUI returns it column-major
    np.testing.assert_allclose(view, cam.view_matrix(), atol=1e-5)
    proj = np.array(tc.get_projection_matrix(16 / 9)).T
    mine = cam.projection_matrix(16 / 9)
    np.testing.assert_allclose([proj[0, 0], proj[1, 1]], [mine[0, 0], mine[1, 1]], rtol=1e-5)


@pytest.mark.parametrize("given", [False, True], ids=["auto", "scene-camera"])
def test_3d_camera_frames_the_box_left_of_the_panel(given):
    """The window leaves the right 30 % to its panel (viewport x in [0, 0.7]): the
    domain box's corners are all drawn inside the viewport, its centre near the
    viewport's centre; with a scene's own camera (framed for the whole image) too."""
    from types import SimpleNamespace

    from mrsph.app.render import Renderer
    from mrsph.scene.config import load_scene

    w, h = 1280, 720
    window = SimpleNamespace(get_canvas=lambda: None, get_window_shape=lambda: (w, h))
    scene = load_scene("dam_break_obstacle_3d")
    lo, hi = np.asarray(scene.domain.min, float), np.asarray(scene.domain.max, float)
    renderer = Renderer(window, scene=scene if given else None)
    renderer.viewport = (0.0, 0.0, 0.7, 1.0)
    cam = renderer.ensure_camera(SimpleNamespace(domain_min=lo, domain_max=hi))
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    px, depth = cam.project(corners, w, h)
    assert (depth > 0).all(), f"box corners behind the camera: depths {np.round(depth, 3).tolist()}"
    assert px[:, 0].min() >= 0 and px[:, 0].max() <= 0.7 * w, (
        f"box drawn over x = {px[:, 0].min():.0f} .. {px[:, 0].max():.0f} px; the viewport ends at {0.7 * w:.0f}"
    )
    # the pivot (the box centre, or the scene's look-at point) stays at the viewport's
    # centre through orbit and zoom
    for move in ("start", "orbit", "zoom"):
        if move == "orbit":
            cam.orbit(math.pi, 0.2)
        elif move == "zoom":
            cam.zoom(0.5)
        pivot, depth = cam.project(cam.target[None], w, h)
        assert depth[0] > 0 and pivot[0, 0] == pytest.approx(0.35 * w, abs=1.0), (
            f"after {move}: the pivot at x = {pivot[0, 0]:.0f} px, the viewport's centre at {0.35 * w:.0f}"
        )


# ----------------------------------------------------------------------------- raster
@pytest.mark.parametrize("dim", DIMS)
def test_raster_frame_shows_level_colours(dim, tmp_path):
    snap = fake_snapshot(dim)
    img = rasterize(snap, W, H)
    assert img.shape == (H, W, 3) and img.dtype == np.uint8
    assert background_mask(img).mean() > 0.02, "frame is (nearly) empty"
    counts = palette.count_level_pixels(img, snap.levels)
    assert sum(c > 50 for c in counts) >= 2, f"fewer than two level colours visible: {counts}"


@pytest.mark.parametrize("dim", DIMS)
def test_raster_orientation_up_is_up(dim):
    """A lone particle high in the domain is drawn in the upper half of the image."""
    snap = fake_snapshot(dim, frames=0, obstacles=False)
    keep = np.zeros(len(snap.x), dtype=bool)
    keep[0] = True
    for name in ("x", "v", "m", "rho", "level", "kind"):
        setattr(snap, name, getattr(snap, name)[keep])
    snap.x[0] = snap.domain_min + (snap.domain_max - snap.domain_min) * 0.5
    snap.x[0][1] = snap.domain_min[1] + 0.9 * (snap.domain_max[1] - snap.domain_min[1])
    snap.kind[0] = 0
    snap.level[0] = snap.levels - 1
    img = rasterize(snap, W, H, legend=False)
    rows = np.nonzero(palette.level_mask(img, snap.levels - 1).any(axis=1))[0]
    assert len(rows), "particle not drawn"
    assert rows.mean() < H / 2, f"particle near the top of the domain drawn at row {rows.mean():.0f} of {H}"


@pytest.mark.parametrize("dim", DIMS)
def test_raster_30k_particles_960x540_smoke(dim):
    """Smoke test: a 30k-particle frame at 960x540 renders and shows fluid. (Speed is
    not asserted here: timings belong in a benchmark, not in a test on a noisy VM.)"""
    spacing = 0.0031 if dim == 2 else 0.0118
    snap = fake_snapshot(dim, frames=0, spacing=spacing)
    assert len(snap.x) >= 25_000, len(snap.x)
    img = Rasterizer(960, 540).render(snap, show_virtual=True)
    assert img.shape == (540, 960, 3), img.shape
    covered = float(background_mask(img).mean())
    assert covered > 0.05, f"{len(snap.x)} particles cover {covered:.1%} of the frame"


# ----------------------------------------------------------------------------- GGUI
@pytest.fixture(scope="module")
def offscreen(taichi_cpu, vulkan):
    from mrsph.app.render import ImguiIniGuard

    guard = ImguiIniGuard()  # ImGui writes ./imgui.ini when the window goes
    window = taichi_cpu.ui.Window("mrsph test", (W, H), show_window=False)
    yield window
    window.destroy()
    guard.cleanup()


def ggui_frame(window, snap, renderer=None):
    from mrsph.app.render import Renderer, image_from_window

    renderer = renderer or Renderer(window)
    renderer.draw(snap)
    image_from_window(window)  # ImGui lays out its panels on the first frame
    renderer.draw(snap)
    return image_from_window(window)


@pytest.mark.parametrize("dim", DIMS)
def test_ggui_offscreen_frame_shows_level_colours(dim, offscreen):
    snap = fake_snapshot(dim)
    img = ggui_frame(offscreen, snap)
    assert img.shape == (H, W, 3)
    assert background_mask(img).mean() > 0.02, "frame is (nearly) empty"
    counts = palette.count_level_pixels(img, snap.levels)
    assert sum(c > 50 for c in counts) >= 2, f"fewer than two level colours visible: {counts}"


@pytest.mark.parametrize("dim", DIMS)
def test_ggui_and_raster_draw_the_same_picture(dim, offscreen):
    """Same framing: the drawn (non-background) areas of both renderers overlap."""
    snap = fake_snapshot(dim)
    a = background_mask(ggui_frame(offscreen, snap))
    b = background_mask(rasterize(snap, W, H))
    a[LEGEND_BOX] = b[LEGEND_BOX] = False
    iou = (a & b).sum() / max((a | b).sum(), 1)
    assert iou > 0.6, f"GGUI and raster frames differ: IoU of drawn pixels {iou:.2f}"


def test_ggui_orientation_up_is_up(offscreen):
    """The buffer-to-image conversion keeps up up and left left."""
    from mrsph.app.render import image_from_window

    offscreen.get_canvas().set_background_color((0, 0, 0))
    ti = pytest.importorskip("taichi")
    pts = ti.Vector.field(2, ti.f32, 1)
    pts.from_numpy(np.array([[0.1, 0.9]], np.float32))  # canvas: left, top
    offscreen.get_canvas().circles(pts, radius=0.05, color=(1.0, 0.0, 0.0))
    img = image_from_window(offscreen)
    ys, xs = np.nonzero(img[:, :, 0] > 128)
    assert len(ys)
    assert ys.mean() < H * 0.3 and xs.mean() < W * 0.3, (ys.mean(), xs.mean())


@pytest.mark.parametrize("dim", DIMS)
def test_renderer_compiles_no_kernel(offscreen, monkeypatch, dim):
    """The renderer packs GGUI's vertex buffers with numpy (mrsph.app.vbo): a frame of
    particles, of the water view, one with more particles and a 3D one after a 2D one
    compile no Taichi kernel (each cost 50-90 ms at a scene's first frame)."""
    from taichi.lang import kernel_impl

    from mrsph.app.render import Renderer

    compiled = []
    materialize = kernel_impl.Kernel.materialize

    def counted(self, *args, **kwargs):
        compiled.append(self.func.__name__)
        return materialize(self, *args, **kwargs)

    r = Renderer(offscreen)
    ggui_frame(offscreen, fake_snapshot(2, frames=0), r)  # the window's own first frame
    monkeypatch.setattr(kernel_impl.Kernel, "materialize", counted)
    for snap in (fake_snapshot(dim, frames=0, spacing=0.03), fake_snapshot(dim, frames=0)):
        r.draw(snap)
        r.draw(snap, surface=True)
        r.draw(snap, color_mode="speed", marks=())
    assert not compiled, compiled


# ----------------------------------------------------------------------------- legend, layout
@pytest.mark.parametrize("dim", DIMS)
def test_every_legend_entry_has_its_swatch_and_fits_the_panel(dim):
    """In every colour mode, particles or water, tinted or not: each line after the
    first (the time and title) has a colour, the swatch strip gets a square for each,
    and no line is longer than the panel holds."""
    from mrsph.app import legend

    snap = fake_snapshot(dim)
    for mode in palette.COLOR_MODES:
        for surface, tint in ((False, False), (True, False), (True, True)):
            rows = legend.lines(snap, mode, surface, tint)
            assert rows[0].colour is None and all(r.colour is not None for r in rows[1:]), (mode, surface, rows)
            assert all(len(r.text) <= legend.CHARS for r in rows), [r.text for r in rows if len(r.text) > legend.CHARS]
            assert len(rows) <= legend.MAX_ROWS, (mode, len(rows))
            tri, col = legend.swatch_triangles(rows, (1280, 720))
            assert len(tri) == 6 * len(rows), "one square per entry and the strip"
    # the speed legend's top entry is near white: it has its square like the rest
    top = legend.lines(snap, "speed")[-1]
    assert top.text.endswith("and above") and min(top.colour) > 0.8


def test_the_2d_view_keeps_the_domain_clear_of_the_legend():
    from mrsph.app.view import fitted_view

    w, h = 960, 540
    box = (8, h - 8 - 120, 8 + 272, h)  # the legend, pixels y up
    view = fitted_view((0.0, 0.0), (1.6, 0.8), w, h, avoid=box)
    (x0, y0), (x1, y1) = view.world_to_px(np.array([[0.0, 0.0], [1.6, 0.8]]))
    assert x0 >= box[2] or y1 <= box[1], f"the domain ({x0:.0f}, {y0:.0f}) .. ({x1:.0f}, {y1:.0f}) under {box}"
    full = fitted_view((0.0, 0.0), (1.6, 0.8), w, h)
    assert view.scale > 0.7 * full.scale, "clear of the legend at too high a price"
    tall_window = fitted_view((0.0, 0.0), (1.6, 0.8), 900, 1400, avoid=(8, 1400 - 128, 280, 1400))
    assert tall_window.scale == fitted_view((0.0, 0.0), (1.6, 0.8), 900, 1400).scale, "moved where it was clear"


@pytest.mark.parametrize("given", [False, True], ids=["auto", "scene-camera"])
def test_the_3d_camera_keeps_the_box_clear_of_the_legend(given):
    from mrsph.app.view import framed_camera
    from mrsph.scene.config import load_scene

    w, h = 1280, 720
    scene = load_scene("demo_3d")
    lo, hi = np.asarray(scene.domain.min, float), np.asarray(scene.domain.max, float)
    box = (8, h - 8 - 154, 8 + 272, h)
    cam = framed_camera(scene if given else None, lo, hi, (w, h), (0.0, 0.0, 0.73, 1.0), avoid=box)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    px, depth = cam.project(corners, w, h)
    assert (depth > 0).all()
    assert px[:, 0].min() >= box[2] or px[:, 1].max() <= box[1], f"box corners {np.round(px).tolist()} under {box}"
    assert px[:, 0].max() <= 0.73 * w, "the box reaches under the HUD"


def test_virtual_particles_shown_are_drawn_over_the_real_ones():
    """``v``: each virtual particle sits on real matter of another level, so it is drawn
    last, at half its size, where its own colour shows at its centre; drawn under the
    real ones it showed only at the surface."""
    snap = fake_snapshot(2, frames=0)
    virt = np.flatnonzero(palette.is_virtual(snap.kind))
    rgb = palette.colours(snap, "level")
    r = Rasterizer(960, 540)
    img = r.render(snap, show_virtual=True, legend=False)
    px = np.round(r.view2d(snap).world_to_px(np.asarray(snap.x)[virt, :2]) - 0.5).astype(int)
    seen = img[img.shape[0] - 1 - px[:, 1], px[:, 0]].astype(np.float32)  # pixel rows run down
    own = np.abs(seen - rgb[virt] * 255.0).max(axis=1) <= 3.0
    assert own.mean() > 0.9, f"{own.mean():.0%} of {len(virt)} virtual particles show their own colour"

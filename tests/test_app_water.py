"""What acts on the water, drawn; the water view; the OBJ surface dump.

Rendered frames of the stand-in simulation, by the rasteriser and (where Vulkan works)
by the GGUI renderer the window and recordings share: the mouse's reach (white) and a
stirrer (magenta) show their colours on their circles; the water view fills the fluid.
"""

from __future__ import annotations

import numpy as np
import pytest
from fake_app import FakeSimulation

from mrsph.app import palette
from mrsph.app.geometry import Mark
from mrsph.app.view import OrbitCamera, View2D

W, H = 640, 360


def _snap(dim):
    sim = FakeSimulation(dim=dim, obstacles=False)
    return sim.snapshot()


@pytest.fixture(scope="module", params=["raster", "ggui"])
def render(request):
    """render(snap, marks, surface) -> (H, W, 3) image, by one backend."""
    if request.param == "raster":
        from mrsph.app.raster import rasterize

        yield lambda snap, marks, surface: rasterize(snap, W, H, legend=False, marks=marks, surface=surface)
        return
    from mrsph.app.record import vulkan_available

    ok, why = vulkan_available()
    if not ok:
        pytest.skip(f"no Vulkan for GGUI: {why}")
    from mrsph import runtime
    from mrsph.app.palette import Style
    from mrsph.app.record import _GguiFrames

    runtime.reset()
    runtime.ensure("cpu")
    from mrsph.app.render import image_from_window

    frames = _GguiFrames(W, H, Style(), None)

    def draw(snap, marks, surface):
        # no legend: the scene framed on the whole image, as _project frames it
        frames.renderer.draw(snap, "level", False, legend=False, marks=marks, surface=surface)
        return image_from_window(frames.window)

    draw.renderer = frames.renderer
    yield draw
    frames.close()
    runtime.reset()


def _ggui(render):
    """The GGUI renderer behind ``render``; skips the rasteriser's turn."""
    renderer = getattr(render, "renderer", None)
    if renderer is None:
        pytest.skip("GGUI renderer only")
    return renderer


def _project(snap, p):
    """Pixel (column, row from the top) of world point p as the renderers frame it."""
    if snap.dim == 2:
        px = View2D(snap.domain_min, snap.domain_max, W, H).world_to_px(np.asarray(p)[None])[0]
    else:
        cam = OrbitCamera.from_box(snap.domain_min, snap.domain_max, W / H)
        px = cam.project(np.asarray(p)[None], W, H)[0][0]
    return int(px[0]), H - 1 - int(px[1])


def _colour_near(img, col_row, colour, reach=40, tol=0.12):
    c, r = col_row
    patch = img[max(r - reach, 0) : r + reach, max(c - reach, 0) : c + reach].astype(float) / 255.0
    return int((np.abs(patch - np.asarray(colour)).max(axis=-1) < tol).sum())


@pytest.mark.parametrize("dim", [2, 3])
def test_mouse_circle_and_stirrer_are_drawn_where_they_act(render, dim):
    snap = _snap(dim)
    mid = (snap.domain_min + snap.domain_max) / 2.0
    mouse = mid.copy()
    stirrer = mid.copy()
    stirrer[0] += 0.3 * (snap.domain_max[0] - snap.domain_min[0])
    bare = render(snap, [], False)
    img = render(snap, [Mark(mouse, 0.08, "mouse"), Mark(stirrer, 0.08, "stirrer")], False)
    for point, kind in ((mouse, "mouse"), (stirrer, "stirrer")):
        colour = palette.MARK_COLOURS[kind]
        at = _project(snap, point)
        found, before = _colour_near(img, at, colour), _colour_near(bare, at, colour)
        assert found > 40 + before, (
            f"{dim}D: {found} pixels of the {kind} colour {colour} within "
            f"40 px of its centre {at} ({before} without the marks)"
        )
    # the mouse's circle is around its centre, not on it
    c, r = _project(snap, mouse)
    assert _colour_near(img, (c, r), palette.MARK_COLOURS["mouse"], reach=2) == 0


@pytest.mark.parametrize("dim", [2, 3])
def test_water_view_fills_the_fluid(render, dim):
    """Inside the fluid block, the water view covers (nearly) every pixel with a colour
    that is not the background; the particle view leaves gaps between the discs."""
    snap = _snap(dim)
    x = np.asarray(snap.x)[~palette.is_virtual(snap.kind)]
    lo, hi = x.min(axis=0), x.max(axis=0)
    if dim == 2:
        (c0, r1), (c1, r0) = _project(snap, lo + 0.2 * (hi - lo)), _project(snap, hi - 0.2 * (hi - lo))
    else:  # around the middle of the top face, which the default camera sees from above
        c, r = _project(snap, np.array([(lo[0] + hi[0]) / 2, hi[1], (lo[2] + hi[2]) / 2]))
        c0, c1, r0, r1 = c - 8, c + 8, r + 2, r + 12
    bg = np.asarray(palette.Style().background) * 255.0
    frac = []
    for surface in (False, True):
        img = render(snap, [], surface).astype(float)
        patch = img[r0:r1, c0:c1]
        assert patch.size, (r0, r1, c0, c1)
        filled = np.abs(patch - bg).max(axis=-1) > 20
        frac.append(filled.mean())
    assert frac[1] > 0.98, f"{dim}D: the water view fills {frac[1]:.1%} of the fluid's inside"
    assert frac[1] >= frac[0], f"{dim}D: particles {frac[0]:.1%}, water view {frac[1]:.1%}"


def test_obj_dump_reads_back_with_the_fluid_volume(tmp_path):
    """A 3D block of 0.4 x 0.2 x 0.3 m in a tank its size: the OBJ is a closed mesh
    (V - E + F = 2) whose volume is the block's within 3 %; 2D: the area within 3 %. The
    smoothed surface reaches past the walls (2.6 mm in 3D at 2 cm spacing); written with
    the domain, the water mirrored at its walls, it lies on them (the volume 0.9999 of the
    block's, 0.974 without)."""
    meshio = pytest.importorskip("meshio")
    from mrsph.io.output import write_frame
    from mrsph.io.surface import mesh_volume, polygon_area

    for dim, s, size in ((3, 0.02, (0.4, 0.2, 0.3)), (2, 0.01, (0.4, 0.2))):
        x = np.stack(np.meshgrid(*[np.arange(s / 2, h, s) for h in size], indexing="ij"), -1).reshape(-1, dim)
        n = len(x)
        parts = dict(
            x=x,
            v=np.zeros_like(x),
            m=np.full(n, 1000.0 * s**dim),
            rho=np.full(n, 1000.0),
            level=np.zeros(n),
            kind=np.zeros(n),
        )
        path = write_frame(tmp_path / f"{dim}d", 0, parts, dim, "obj", (np.zeros(dim), np.array(size)))
        assert path.name == "frame_00000.obj"
        mesh = meshio.read(path)
        outside = np.maximum(-mesh.points[:, :dim], mesh.points[:, :dim] - np.array(size)).max()
        assert outside <= 0.0, f"{dim}D: the surface reaches {outside:.4g} m past the tank's walls"
        faces = mesh.cells_dict["triangle"]
        tri = mesh.points[faces]
        want = float(np.prod(size))
        if dim == 3:
            got = mesh_volume(tri)
            edges = {tuple(sorted(e)) for f in faces.tolist() for e in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0]))}
            euler = len(mesh.points) - len(edges) + len(faces)
            assert euler == 2, f"the surface is not one closed mesh: V - E + F = {euler}"
        else:
            got = polygon_area(tri[:, :, :2])
        assert abs(got / want - 1.0) < 0.03, f"{dim}D: OBJ encloses {got:.5f}, the block {want:.5f}"


def test_obj_dump_leaves_out_the_mirror_image_of_a_drop_near_a_wall(tmp_path):
    """A drop of 3 x 3 x 3 particles 1.5 spacings above the floor: the particles mirrored
    at the floor make a second drop below it, wholly outside the tank, which the OBJ
    leaves out (clipped, it was a sheet of 40 % of the mesh's vertices on the floor)."""
    meshio = pytest.importorskip("meshio")
    from mrsph.io.output import write_frame

    s = 0.02
    x = np.stack(np.meshgrid(*[np.arange(3) * s] * 3, indexing="ij"), -1).reshape(-1, 3) + [0.5, 1.5 * s, 0.5]
    n = len(x)
    parts = dict(
        x=x,
        v=np.zeros_like(x),
        m=np.full(n, 1000.0 * s**3),
        rho=np.full(n, 1000.0),
        level=np.zeros(n),
        kind=np.zeros(n),
    )
    mesh = meshio.read(write_frame(tmp_path, 0, parts, 3, "obj", (np.zeros(3), np.ones(3))))
    faces = mesh.cells_dict["triangle"]
    edges = {tuple(sorted(e)) for f in faces.tolist() for e in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0]))}
    parts_count = (len(mesh.points) - len(edges) + len(faces)) // 2
    on_floor = int((mesh.points[:, 1] <= 1e-12).sum())
    assert parts_count == 1 and on_floor == 0, f"{parts_count} closed parts, {on_floor} vertices on the floor"


def _filled_top(render, snap) -> float:
    """Share of a patch in the middle of the 3D fluid's top face that is not background."""
    x = np.asarray(snap.x)[~palette.is_virtual(snap.kind)]
    lo, hi = x.min(axis=0), x.max(axis=0)
    c, r = _project(snap, np.array([(lo[0] + hi[0]) / 2, hi[1], (lo[2] + hi[2]) / 2]))
    patch = render(snap, [], True).astype(float)[r + 2 : r + 12, c - 8 : c + 8]
    bg = np.asarray(palette.Style().background) * 255.0
    return float((np.abs(patch - bg).max(axis=-1) > 20).mean())


def test_a_3d_water_mesh_of_200k_vertices_is_drawn(render, monkeypatch):
    """GGUI 1.7.4 on lavapipe draws nothing of a large scene.mesh field (pool_3d's
    marching-tetrahedra mesh, 75 600 vertices, was invisible): the renderer draws a mesh
    in parts of 65 535 vertices. The fake pool's own mesh, repeated to 200 000 vertices,
    covers the top face as the mesh once does (drawn whole: 13 %)."""
    from mrsph.app import geometry

    _ggui(render)
    snap = _snap(3)
    once = geometry.water(snap, palette.colours(snap, "level"))
    reps = 3 * 65535 // len(once[1]) + 1
    monkeypatch.setattr(
        geometry, "water", lambda s, rgb, *_: ("mesh",) + tuple(np.tile(a, (reps, 1)) for a in once[1:])
    )
    assert reps * len(once[1]) > 3 * 65535
    frac = _filled_top(render, snap)
    assert frac > 0.98, f"a mesh of {reps * len(once[1])} vertices fills {frac:.1%} of the top face"


@pytest.mark.parametrize("dim", [2, 3])
def test_water_view_is_not_recomputed_for_the_same_snapshot(render, monkeypatch, dim):
    """Paused (the window draws the same snapshot again), the surface is reused; a new
    snapshot, or other colours, computes it again."""
    from mrsph.app import geometry

    renderer = _ggui(render)
    calls = []
    real = geometry.water
    monkeypatch.setattr(geometry, "water", lambda s, rgb, *more: calls.append(1) or real(s, rgb, *more))
    snap = _snap(dim)
    render(snap, [], True)
    render(snap, [], True)
    assert len(calls) == 1 and renderer.surface_s == 0.0, f"{len(calls)} surfaces for one snapshot"
    renderer.draw(snap, "speed", surface=True)
    assert len(calls) == 2, "other colours did not recompute the surface"
    render(_snap(dim), [], True)
    assert len(calls) == 3, "a new snapshot did not recompute the surface"


def _pool_snapshot(width=1.0, depth=0.3, s=0.01, drop=None):
    """A 2D pool from wall to wall of a 1 x 0.6 m domain, and optionally one particle (a
    drop) at ``drop``."""
    from mrsph.io.snapshot import Snapshot

    x = np.stack(np.meshgrid(np.arange(s / 2, width, s), np.arange(s / 2, depth, s), indexing="ij"), -1).reshape(-1, 2)
    if drop is not None:
        x = np.concatenate([x, [drop]])
    n = len(x)
    return Snapshot(
        dim=2,
        levels=1,
        time=0.0,
        frame=0,
        x=x,
        v=np.zeros_like(x),
        m=np.full(n, 1000.0 * s * s),
        rho=np.full(n, 1000.0),
        level=np.zeros(n, np.int32),
        kind=np.zeros(n, np.int32),
        radius=np.array([s / 2]),
        domain_min=np.array([0.0, 0.0]),
        domain_max=np.array([1.0, 0.6]),
        obstacles=[],
        stats={},
    )


def test_the_2d_water_body_meets_the_walls_and_darkens_with_depth():
    """The body reaches the walls and the floor (the particles mirrored there: without,
    its edge stood half a spacing and more inside them), its free surface is lit, and
    its colour goes from the shallow water's at the surface to darker at the floor."""
    from mrsph.app import geometry
    from mrsph.io.surface import ISO, phi_at

    water = geometry.water(_pool_snapshot(), None)
    lo, hi = water.triangles.min(axis=0), water.triangles.max(axis=0)
    assert lo[0] <= 0.0 and hi[0] >= 1.0 and lo[1] <= 0.0, f"the body spans {lo} .. {hi}"
    corners = np.array([[0.002, 0.002], [0.998, 0.002], [0.002, 0.15], [0.5, 0.002]])
    phi = phi_at(water.grid, corners)
    assert np.all(phi >= ISO), f"the body leaves the floor's corners and walls: phi {np.round(phi, 3)} there"
    assert abs(hi[1] - 0.3) < 0.01, f"the surface at {hi[1]:.4f} m, the pool 0.3 m deep"
    seg = water.surface.reshape(-1, 2, 2)
    assert len(seg) and np.all(np.abs(seg[..., 1] - 0.3) < 0.01), "lit segments off the free surface"
    assert seg[..., 0].min() < 0.05 and seg[..., 0].max() > 0.95, "the lit surface does not span the pool"
    y = water.triangles[:, 1]
    top, bottom = water.colours[y > 0.28].mean(axis=0), water.colours[(y < 0.02) & (y > -0.001)].mean(axis=0)
    assert top.sum() > bottom.sum() + 0.3, f"colour at the surface {top}, at the floor {bottom}"
    assert len(water.drops) == 0, f"{len(water.drops)} drops in a calm pool"


def test_a_particle_away_from_the_body_is_a_drop():
    from mrsph.app import geometry

    water = geometry.water(_pool_snapshot(drop=(0.5, 0.5)), None)
    assert len(water.drops) == 1 and np.allclose(water.drops[0], (0.5, 0.5)), water.drops
    tinted = geometry.water(_pool_snapshot(drop=(0.5, 0.5)), np.tile([1.0, 0.5, 0.0], (3001, 1)), tint=True)
    assert np.allclose(tinted.drop_colours, [1.0, 0.5, 0.0]), "a tinted drop is not the particle's colour"


def test_depth_is_measured_to_the_interpolated_surface():
    """Depth under a flat surface is the height below it, within a tenth of a cell, not
    a whole number of cells (those drew stripes along an uneven surface)."""
    from mrsph.io import surface as sf

    snap = _pool_snapshot()
    top = snap.x[:, 1] > 0.29
    snap.x[top, 1] += 0.0037  # the top row up: the surface near 0.3037 m, between two nodes
    grid = sf.volume_fraction(snap.x, snap.m, snap.rho, snap.level, snap.kind)
    depth = sf.depth_below_surface(grid)
    y = grid.origin[1] + np.arange(grid.phi.shape[1]) * grid.cell
    col = depth[grid.phi.shape[0] // 2]
    inside = (y > 0.05) & (y < 0.25)
    surface_y = y[inside] + col[inside]
    assert np.ptp(surface_y) < 0.1 * grid.cell, f"surface heights {surface_y.min():.5f} .. {surface_y.max():.5f}"
    upper = y > 0.1
    crossing = np.interp(-sf.ISO, -grid.phi[grid.phi.shape[0] // 2][upper], y[upper])  # where φ falls through ISO
    assert abs(surface_y.mean() - crossing) < 0.05 * grid.cell, (surface_y.mean(), crossing)
    assert abs(crossing - y[np.searchsorted(y, crossing)]) > 0.2 * grid.cell, "the surface is on a node"
    assert np.all(col[y > 0.32] == 0.0)


def test_a_stirrer_parked_out_of_the_water_is_not_marked():
    """A stirrer is marked where it acts: on its path, and after its path ends while water
    is within its radius; parked above the water (demo_2d's, lifted over the post at the
    end of its path), it acts on nothing and its circle is left out."""
    from mrsph.app.geometry import stirrer_marks

    snap = _snap(2)
    top = float(np.asarray(snap.x)[:, 1].max())
    inside = [0.3, 0.5 * top]
    above = [0.3, top + 0.3]
    path = [[0.0, *inside], [1.0, *above]]
    scene = {"dim": 2, "stirrers": [{"radius": 0.05, "path": path, "loop": False}]}
    assert len(stirrer_marks(scene, 0.5, snap)) == 1, "on its path"
    assert stirrer_marks(scene, 2.0, snap) == [], "parked above the water"
    assert len(stirrer_marks(scene, 2.0)) == 1, "no frame given: every stirrer"
    scene["stirrers"][0]["path"] = [[0.0, *above], [1.0, *inside]]
    assert len(stirrer_marks(scene, 2.0, snap)) == 1, "parked in the water"
    scene["stirrers"][0]["path"] = [[0.0, *above], [1.0, *above]]
    scene["stirrers"][0]["loop"] = True
    assert len(stirrer_marks(scene, 2.0, snap)) == 1, "a looping path never ends, in the air or not"

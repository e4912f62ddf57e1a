"""The disturbance (what the mouse and stirrers hand to the solver), on real simulations.

A drag must change velocities only within its radius and along the drag, and raise the
wanted level (refine) there; once it stops, the wanted level falls back. And one offscreen
frame of a real adaptive scene must show at least two level colours.
"""

import numpy as np
import pytest

from mrsph.scene.config import load_scene
from mrsph.scene.interaction import Disturbance
from mrsph.simulation import Simulation

pytestmark = pytest.mark.usefixtures("fresh_program")


def block_scene(dim):
    """A resting block without gravity, two levels, refined only where disturbed."""
    lo, hi = [0.0] * dim, [1.0] * dim
    return {
        "description": "disturbance test",
        "dim": dim,
        "domain": {"min": lo, "max": hi},
        "particles": {"spacing": 0.025 if dim == 2 else 0.04},
        "physics": {"gravity": [0.0] * dim},
        "fluid": {"viscosity": 1.0, "stiffness": 400.0, "blocks": [{"min": [0.1] * dim, "max": [0.9] * dim}]},
        "adaptivity": {"enabled": True, "levels": 2, "interval": 1, "band": 0.05},
        "criteria": [{"type": "disturbance", "level": 0}],
    }


@pytest.mark.slow_params("3d")  # the quick run keeps 2D (conftest.py, "two tiers")
def test_drag_pushes_inside_its_radius_along_the_drag_and_refines(dim):
    sim = Simulation(load_scene(block_scene(dim)), arch="cpu")
    before = sim.particles(virtual=False)
    assert (before["level"] == 1).all(), "with nothing disturbed, every particle is coarse"
    centre = np.full(dim, 0.5)
    radius, strength, drag = 0.15, 40.0, np.zeros(dim)
    drag[0] = 2.0
    sim.set_disturbance(Disturbance(tuple(centre), radius, strength, "push", tuple(drag)))
    for _ in range(5):
        sim.step()
    after = sim.particles(virtual=False)
    d = np.linalg.norm(after["x"] - centre, axis=1)
    inside, outside = d < 0.6 * radius, d > radius + 2 * 0.08  # 0.08 = a coarse support
    vx_in = after["v"][inside, 0].mean()
    speed_out = np.linalg.norm(after["v"][outside], axis=1).max()
    # The push relaxes u toward the drag velocity u_d: du/dt = strength w (u_d - u) with
    # w = (1 - (r/R)^2)^2, so from rest u = u_d (1 - exp(-strength w t)) per particle
    # (they move ~0.3 mm in these 5 steps, so w at the end will do). The fluid's own
    # forces only spread that momentum outward (viscosity, pressure), so the mean inside
    # is at most this (+ ~1 % for the explicit step, (1 - k w dt)^n < exp(-k w t)), and
    # viscosity drains only a few % in 5 steps (measured 0.966 pred in 2D, 0.927 in 3D).
    # Half the strength gives ~0.5 pred, twice it or a dropped w ~1.5-1.9 pred.
    w = (1.0 - (d[inside] / radius) ** 2) ** 2
    pred = float(np.mean(drag[0] * (1.0 - np.exp(-strength * w * sim.time))))
    assert 0.8 * pred <= vx_in <= 1.1 * pred, (
        f"{dim}D: mean x velocity inside the drag {vx_in:.5f} m/s after t = {sim.time:.5f} s; "
        f"the relaxation predicts {pred:.5f} (ratio {vx_in / pred:.3f}, expected 0.8 .. 1.1)"
    )
    side = np.abs(after["v"][inside, 1:].mean(axis=0)).max()
    assert side <= 1e-3 * vx_in, (
        f"{dim}D: sideways mean velocity {side:.3g} m/s vs {vx_in:.4f} along the drag; "
        f"expected < 0.1 % (the block is symmetric about the drag's axis)"
    )
    assert speed_out < 0.1 * vx_in, (
        f"{dim}D: fastest particle well outside the radius moves at {speed_out:.4f} m/s; "
        f"expected < 10 % of the push ({vx_in:.4f})"
    )
    fine = after["level"] == 0
    assert fine.sum() > 0, f"{dim}D: no particle refined under the drag"
    assert np.linalg.norm(after["x"][fine] - centre, axis=1).max() < radius + 0.15, (
        f"{dim}D: refined particles far from the drag"
    )
    lam_in = after["lam"][inside].max()
    assert lam_in < 0.75, f"{dim}D: wanted level under the drag {lam_in:.3f}; expected < 1 - hysteresis"

    sim.set_disturbance(None)
    sim.step()
    back = sim.particles(virtual=False)
    assert back["lam"].min() >= 1.0 - 1e-6, (
        f"{dim}D: after the drag stops the wanted level must fall back to the background "
        f"(1); lowest is {back['lam'].min():.3f}"
    )


@pytest.mark.parametrize("name", ["region_2d", pytest.param("region_3d", marks=pytest.mark.slow)])
def test_offscreen_frame_of_an_adaptive_scene_shows_two_levels(name):
    from mrsph.app import palette
    from mrsph.app.record import vulkan_available
    from mrsph.app.render import ImguiIniGuard, Renderer, image_from_window

    ok, why = vulkan_available()
    if not ok:
        pytest.skip(f"GGUI offscreen rendering unavailable: {why}")
    import taichi as ti

    sim = Simulation(load_scene(name), arch="cpu")
    snap = sim.snapshot()
    assert len(set(snap.level.tolist())) >= 2, "the scene should start with two levels"
    guard = ImguiIniGuard()
    window = ti.ui.Window("mrsph test", (480, 270), show_window=False)
    try:
        renderer = Renderer(window, scene=sim.scene)
        renderer.draw(snap)
        image_from_window(window)
        renderer.draw(snap)
        img = image_from_window(window)
    finally:
        window.destroy()
        guard.cleanup()
    counts = palette.count_level_pixels(img, snap.levels)
    assert sum(c > 50 for c in counts) >= 2, f"{name}: fewer than two level colours visible: {counts}"


PATHS = [
    ([[0.0, 0.1, 0.2], [1.2, 0.9, 0.2], [1.6, 0.9, 0.7]], False),  # demo_2d's stirrer
    ([[0.0, 0.28, 0.12], [3.0, 1.0, 0.12], [6.0, 0.28, 0.12]], True),  # region_2d's region
    ([[0.5, 0.3, 0.4]], False),  # one waypoint: still
    ([[0.25, 0.0, 0.0], [0.5, 0.3, -0.1], [0.75, 0.3, 0.4], [2.0, 1.0, 1.0]], True),
]


def test_paths_on_the_device_sample_as_the_host_does():
    """``Paths.sample`` (the stirrers' and moving regions' paths, on the device) gives the
    positions and velocities of ``path_sample`` to f64 round-off: before the first
    waypoint, on and between waypoints, after the last, and through several loops."""
    import taichi as ti

    from mrsph import runtime
    from mrsph.scene.interaction import Paths, path_sample

    runtime.ensure("cpu", "f32")
    paths = Paths(2, PATHS)
    times = np.concatenate([np.linspace(-1.0, 13.0, 281), [0.0, 0.25, 0.5, 0.75, 1.2, 1.6, 2.0, 3.0, 6.0]])
    out_x = ti.Vector.field(2, ti.f64, shape=(len(PATHS), len(times)))
    out_v = ti.Vector.field(2, ti.f64, shape=(len(PATHS), len(times)))
    ts = ti.field(ti.f64, shape=len(times))
    ts.from_numpy(times)

    @ti.kernel
    def sample():
        for k, q in ti.ndrange(len(PATHS), len(times)):
            out_x[k, q], out_v[k, q] = paths.sample(k, ts[q])

    sample()
    xs, vs = out_x.to_numpy(), out_v.to_numpy()
    for k, (waypoints, loop) in enumerate(PATHS):
        for q, t in enumerate(times):
            x, v = path_sample(waypoints, t, loop)
            assert np.allclose(xs[k, q], x, rtol=0, atol=1e-12) and np.allclose(vs[k, q], v, rtol=0, atol=1e-9), (
                f"path {k} at t = {t}: device ({xs[k, q]}, {vs[k, q]}), host ({x}, {v})"
            )


@pytest.mark.slow_params("3d")  # the quick run keeps 2D (conftest.py, "two tiers")
def test_a_stirrer_is_where_its_path_says_after_every_step(dim):
    """The stirrers follow their paths on the device, one launch a step: after each step
    (and after a restore) a stirrer's slot holds the path's position and velocity at the
    simulation's time, in the solver's precision."""
    from mrsph.scene.interaction import path_sample

    scene = block_scene(dim)
    path = [[0.0] + [0.2] * dim, [0.01] + [0.8] * dim, [0.02] + [0.5] * dim]
    scene["stirrers"] = [{"radius": 0.1, "strength": 20.0, "path": path, "loop": True}]
    sim = Simulation(load_scene(scene), arch="cpu")

    def check():
        x, v = path_sample(path, sim.time, True)
        got_x, got_v = sim.disturbances.center.to_numpy()[1], sim.disturbances.velocity.to_numpy()[1]
        assert np.array_equal(got_x, x.astype(np.float32)) and np.array_equal(got_v, v.astype(np.float32)), (
            f"t = {sim.time}: stirrer at {got_x} moving {got_v}; its path says {x}, {v}"
        )

    check()
    steps = 0
    while sim.time < 0.025:  # past both waypoints and into the second lap
        sim.step()
        check()
        steps += 1
        assert steps < 5000, f"{steps} steps reached only t = {sim.time}"
    state = sim.save_state()
    sim.step()
    sim.restore_state(state)
    check()

"""The mouse in the user's time, on the real solver.

The window hands ``MouseDisturbance`` the wall-clock time between frames, and the
disturbance's target speed is capped to ``safe_speed`` (Mach 0.1 of the fluid). Here a
synthetic swipe goes through the window's own settings (``MouseDisturbance.for_domain``
with the scene's stiffness) into ``sim.set_disturbance``, one simulated frame per drawn
frame, as the window does at full speed.
"""

from __future__ import annotations

import numpy as np
import pytest

from mrsph.app.mouse import MouseDisturbance, safe_speed

pytest.importorskip("taichi")

#: A drawn frame: 60 fps wall, one simulated frame (1/30 s) each: twice real time, as on
#: a fast machine, so the disc lingers over the fluid it pushes.
FRAME_S = 1.0 / 60.0
STIFFNESS = 400.0  # c0 = 20 m/s, so the cap is 2 m/s


def pool_scene():
    """A 1 m x 0.5 m tank with water 0.2 m deep, one level (fast to build)."""
    return {
        "description": "swipe test",
        "dim": 2,
        "domain": {"min": [0.0, 0.0], "max": [1.0, 0.5]},
        "particles": {"spacing": 0.02},
        "fluid": {"viscosity": 1.0, "stiffness": STIFFNESS, "blocks": [{"min": [0.0, 0.0], "max": [1.0, 0.2]}]},
        "adaptivity": {"enabled": False, "levels": 1},
        "run": {"fps": 30},
    }


@pytest.fixture(scope="module")
def sim():
    from mrsph import runtime
    from mrsph.scene.config import load_scene
    from mrsph.simulation import Simulation

    runtime.reset()
    yield Simulation(load_scene(pool_scene()), arch="cpu")
    runtime.reset()


def swipe(sim, path, settle_frames, frame_s=None):
    """Drag the left button through ``path`` (one cursor position per drawn frame,
    frame_s (default FRAME_S) of wall time apart), then release and let the fluid run settle_frames more
    frames. Returns the top speed of the fluid over the whole run, the mean x velocity
    of the fluid within half the mouse's radius at the release, and the cap the mouse
    used."""
    from mrsph.scene.interaction import Disturbance

    frame_s = frame_s or FRAME_S
    snap = sim.snapshot(stats=False)
    mouse = MouseDisturbance.for_domain(snap.domain_min, snap.domain_max, STIFFNESS, factory=Disturbance)
    top, along = 0.0, 0.0
    for i in range(len(path) + settle_frames):
        if i < len(path):
            d = mouse.update(path[i], {"left"}, frame_s)
        else:
            d = mouse.update(None, set(), frame_s)
        sim.set_disturbance(d)
        sim.advance_frame()
        parts = sim.particles(virtual=False)
        top = max(top, float(np.linalg.norm(parts["v"], axis=1).max()))
        if i == len(path) - 1:
            near = np.linalg.norm(parts["x"] - path[-1], axis=1) < 0.5 * mouse.radius
            along = float(parts["v"][near, 0].mean())
    sim.set_disturbance(None)
    return top, along, mouse.max_speed


def line(start, end, frames):
    return [np.asarray(start) + (np.asarray(end) - np.asarray(start)) * i / (frames - 1) for i in range(frames)]


def test_a_fast_swipe_is_capped_and_a_slow_drag_moves_the_water(sim):
    cap = safe_speed(STIFFNESS, (0.0, 0.0), (1.0, 0.5))
    assert cap == pytest.approx(2.0)
    # Back and forth across the tank, 0.8 m in 0.133 s of wall time each way, three
    # times: the hand moves at 6 m/s, three times the cap. Uncapped (SAFE_MACH = 1, so
    # only the domain-size clamp of 8 m/s) the fluid reached 5.0 m/s; capped 0.92 m/s.
    sim.reset()
    there, back = line((0.1, 0.15), (0.9, 0.15), 9), line((0.9, 0.15), (0.1, 0.15), 9)
    top, _, used = swipe(sim, (there + back) * 3, settle_frames=12)
    assert used == pytest.approx(cap)
    assert top <= cap, (
        f"a fast swipe drove the fluid to {top:.3f} m/s; the mouse's cap is "
        f"{cap:.3f} m/s (Mach 0.1 of c0 = {STIFFNESS**0.5:.1f} m/s)"
    )
    # A slow drag, 0.3 m/s for 0.6 s at 30 fps in real time (one simulated frame per
    # wall frame): the water near it follows along +x.
    sim.reset()
    top, along, _ = swipe(sim, line((0.3, 0.15), (0.48, 0.15), 19), settle_frames=0, frame_s=1.0 / 30.0)
    assert along > 0.1, (
        f"a slow drag at 0.3 m/s moved the water near it at {along:.3f} m/s "
        f"along the drag (expected > 0.1 m/s, a third of the hand; measured 0.12)"
    )
    assert top < cap

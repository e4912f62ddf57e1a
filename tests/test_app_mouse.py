"""Mouse gestures -> Disturbance, and 3D picking (pure logic, no window)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mrsph.app.mouse import MouseDisturbance, pick_point, ray_box, ray_plane
from mrsph.scene.interaction import Disturbance

DT = 1.0 / 60.0
#: The documented time constant of the cursor-velocity smoothing (mouse.SMOOTHING_S),
#: written out so that a changed default is caught.
TAU = 0.05


def make(dim=2, **kw):
    kw.setdefault("factory", Disturbance)
    return MouseDisturbance(dim, radius=0.1, radius_min=0.02, radius_max=0.4, **kw)


def drag(mouse, start, step, n, buttons):
    out = []
    p = np.asarray(start, float)
    for _ in range(n):
        out.append(mouse.update(p, buttons, DT))
        p = p + step
    return out


@pytest.mark.parametrize("dim", [2, 3])
def test_left_drag_pushes_along_the_drag(dim):
    m = make(dim)
    step = np.zeros(dim)
    step[0], step[1] = 0.01, 0.005  # 0.6 m/s, 0.3 m/s at 60 fps
    ds = drag(m, np.full(dim, 0.5), step, 20, {"left"})
    assert all(d is not None and d.mode == "push" for d in ds)
    v = np.asarray(ds[-1].velocity)
    assert v.shape == (dim,)
    cos = v @ step / (np.linalg.norm(v) * np.linalg.norm(step))
    assert cos > 0.999, f"velocity {v} not along the drag {step}"
    # Exponential smoothing with the documented 50 ms time constant: frame 0 starts at
    # rest, each of the 19 later frames moves the velocity a fraction
    # alpha = 1 - exp(-DT / TAU) of the way to the cursor's velocity step / DT, so
    # v = step / DT * (1 - exp(-19 DT / TAU)) (0.9982 of it at 60 fps). Twice the time
    # constant would give 0.958 of it, another law another value: pinned to 1e-6.
    expected = step / DT * (1.0 - math.exp(-19 * DT / TAU))
    np.testing.assert_allclose(
        v, expected, rtol=1e-6, err_msg=f"{dim}D: smoothed velocity {v} vs {expected} (time constant {TAU} s)"
    )
    np.testing.assert_allclose(ds[-1].center, np.full(dim, 0.5) + 19 * step)
    assert ds[-1].radius == pytest.approx(0.1) and ds[-1].strength == m.strength


def test_first_frame_of_a_drag_is_at_rest_and_jitter_is_smoothed():
    m = make()
    d0 = m.update((0.5, 0.5), {"left"}, DT)
    assert np.allclose(d0.velocity, 0.0)
    d1 = m.update((0.51, 0.5), {"left"}, DT)
    raw = 0.01 / DT
    # one frame of the exponential smoothing: a fraction 1 - exp(-DT / TAU) of the jump
    expected = raw * (1.0 - math.exp(-DT / TAU))  # 0.28 of the raw 0.6 m/s
    assert d1.velocity[0] == pytest.approx(expected, rel=1e-6), (
        f"one-frame jump smoothed to {d1.velocity[0]:.6g} m/s; expected {expected:.6g} "
        f"(raw {raw:.6g}, time constant {TAU} s)"
    )
    assert d1.velocity[1] == 0.0, f"no sideways velocity from a jump along x: {d1.velocity}"


@pytest.mark.parametrize("buttons", [{"right"}, {"left", "shift"}, {"RMB"}, {"LMB", "Shift"}])
def test_right_drag_or_shift_left_pulls(buttons):
    m = make()
    ds = drag(m, (0.2, 0.3), np.array([0.01, 0.0]), 5, buttons)
    assert all(d.mode == "pull" for d in ds)
    assert np.allclose(ds[-1].velocity, 0.0)
    np.testing.assert_allclose(ds[-1].center, (0.24, 0.3))


def test_release_yields_none_and_forgets_the_drag():
    m = make()
    drag(m, (0.2, 0.3), np.array([0.02, 0.0]), 5, {"left"})
    assert m.update((0.3, 0.3), set(), DT) is None
    assert not m.active
    d = m.update((0.9, 0.9), {"left"}, DT)
    assert np.allclose(d.velocity, 0.0), "a new drag must not inherit the old velocity"
    assert m.update(None, {"left"}, DT) is None, "cursor outside the view: no disturbance"


def test_wheel_changes_radius_within_clamps():
    m = make()
    m.update((0.5, 0.5), set(), DT, wheel=1)
    assert m.radius > 0.1
    m.update((0.5, 0.5), {"left"}, DT, wheel=100)
    assert m.radius == pytest.approx(0.4)
    d = m.update((0.5, 0.5), {"left"}, DT, wheel=-1000)
    assert m.radius == pytest.approx(0.02) and d.radius == pytest.approx(0.02)


def test_cursor_jumps_are_clamped():
    m = make(max_speed=5.0, smoothing=0.0)
    m.update((0.0, 0.0), {"left"}, DT)
    d = m.update((10.0, 0.0), {"left"}, DT)
    assert np.linalg.norm(d.velocity) == pytest.approx(5.0)


def test_strength_and_radius_are_settable():
    m = make()
    m.strength, m.radius = 42.0, 0.3
    d = m.update((0.5, 0.5), {"left"}, DT)
    assert d.strength == 42.0 and d.radius == pytest.approx(0.3)


def test_for_domain_scales_defaults():
    m = MouseDisturbance.for_domain((0, 0), (4, 1), factory=Disturbance)
    assert m.radius == pytest.approx(0.32) and m.radius_min == pytest.approx(0.04)
    assert m.radius_max == pytest.approx(2.0)


# ----------------------------------------------------------------------------- picking
def test_pick_point_enters_the_box():
    p = pick_point((0.5, 0.5, 5.0), (0, 0, -1), (0, 0, 0), (1, 1, 1), (0.5, 0.5, 0.5))
    np.testing.assert_allclose(p, (0.5, 0.5, 1.0))


def test_pick_point_misses_box_uses_plane_facing_camera():
    o, d = np.array([3.0, 0.5, 5.0]), np.array([0.0, 0.0, -1.0])
    p = pick_point(o, d, (0, 0, 0), (1, 1, 1), (0.5, 0.5, 0.5))
    np.testing.assert_allclose(p, (3.0, 0.5, 0.5))
    # plane through the centre with an explicit normal (the camera's forward)
    d2 = np.array([0.0, -0.6, -0.8])
    p2 = pick_point((3.0, 5.0, 5.0), d2, (0, 0, 0), (1, 1, 1), (0.5, 0.5, 0.5), plane_normal=(0, 0, -1))
    assert p2[2] == pytest.approx(0.5)


def test_pick_point_from_inside_or_pointing_away_falls_back():
    p = pick_point((0.5, 0.5, 0.5), (0, 0, 1), (0, 0, 0), (1, 1, 1), (0.5, 0.5, 0.2), plane_normal=(0, 0, 1))
    # from inside the box the ray's entry (t_near = -0.5, behind the eye) does not count,
    # and the fallback plane z = 0.2 lies behind the ray too: the plane point itself
    np.testing.assert_allclose(p, (0.5, 0.5, 0.2), atol=1e-12, err_msg=f"picked {p}; expected the fallback plane point")
    far = pick_point((0.5, 0.5, 5.0), (0, 0, 1), (0, 0, 0), (1, 1, 1), (0.5, 0.5, 0.5))
    np.testing.assert_allclose(far, (0.5, 0.5, 0.5))


def test_ray_helpers():
    assert ray_box((2, 2, 2), (1, 0, 0), (0, 0, 0), (1, 1, 1)) is None
    assert ray_box((-1, 0.5, 0.5), (1, 0, 0), (0, 0, 0), (1, 1, 1)) == pytest.approx((1.0, 2.0))
    assert ray_plane((0, 0, 0), (1, 0, 0), (0, 0, 1), (0, 0, 1)) is None  # parallel


def test_safe_speed_is_mach_0_1_and_the_pull_is_capped_too():
    from mrsph.app.mouse import safe_speed

    # c0 = sqrt(400) = 20 m/s -> 2 m/s; no stiffness: 8 domain sizes per second
    assert safe_speed(400.0, (0, 0), (1, 0.5)) == pytest.approx(2.0)
    assert safe_speed(None, (0, 0), (1, 0.5)) == pytest.approx(8.0)
    m = MouseDisturbance.for_domain((0, 0), (1, 0.5), 400.0, factory=Disturbance)
    assert m.max_speed == pytest.approx(2.0)
    m.strength, m.radius = 100.0, 0.4
    d = m.update((0.5, 0.25), {"right"}, DT)
    # the pull's target speed is strength x distance, at most strength x radius at the rim
    assert d.mode == "pull" and d.strength * d.radius == pytest.approx(2.0), (
        f"pull strength {d.strength} x radius {d.radius} = {d.strength * d.radius} m/s, cap 2 m/s"
    )

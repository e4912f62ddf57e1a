"""The soak (tools/soak.py): demo_2d stirred at the strongest settings the window offers.

- ``test_soak_full`` (marker ``soak``, skipped unless ``--soak``): 10^5 steps, about an
  hour each on 2 cores. Run it with ``python3 -m pytest -q --soak -m soak``.
  It runs wcsph, and dfsph in one thread and in two (docs/validation.md, "Stirred soak");
  no dfsph solve may stop at its maximum iterations.
- ``test_soak_short``: a SHORT soak of 1000 steps in -m slow, with each pressure solver and
  gestures of 0.025 s so that it pushes, pulls and lets go within its ~0.09 s, its
  kernels compiled without the advanced optimisation passes, as the quick run compiles.
- The checker itself is tested on hand-made particles, so that a passing soak means the
  checks could have failed.
"""

import math
import re
from pathlib import Path

import numpy as np
import pytest
from toolload import load_tool

REPO = Path(__file__).resolve().parent.parent


def _soak_tool():
    return load_tool("soak")


soak_tool = _soak_tool()


def test_strength_is_the_window_slider_maximum():
    """The soak stirs at the HUD slider's top, one constant (mrsph/app/mouse.py) both read."""
    from mrsph.app import mouse

    source = (REPO / "mrsph" / "app" / "hud.py").read_text()
    assert re.search(r'"slider", "strength", m\.strength, 0\.0, STRENGTH_MAX,', source), (
        "the HUD's strength slider does not end at mouse.STRENGTH_MAX"
    )
    assert soak_tool.STRENGTH_MAX == mouse.STRENGTH_MAX == 100.0


def test_the_soak_caps_its_cursor_harder_than_the_window_unless_asked():
    """By default the cursor may ask for 8 domain sizes a second (12.8 m/s in demo_2d);
    ``--window-cap`` caps it as the window does, at a tenth of sqrt(fluid.stiffness)."""
    from mrsph.app.mouse import safe_speed
    from mrsph.scene.config import load_scene

    data = load_scene("demo_2d").data
    harsh, window = soak_tool.soak_mouse(data), soak_tool.soak_mouse(data, window_cap=True)
    assert harsh.max_speed == pytest.approx(8.0 * 1.6), harsh.max_speed
    assert (
        window.max_speed
        == pytest.approx(safe_speed(data["fluid"]["stiffness"], data["domain"]["min"], data["domain"]["max"]))
        == pytest.approx(2.0)
    )
    assert harsh.strength == window.strength == soak_tool.STRENGTH_MAX and harsh.radius == pytest.approx(0.8)


def test_obstacle_sdf_matches_boxes_and_circles():
    obstacles = [
        {"shape": "box", "min": [1.0, 0.0], "max": [2.0, 1.0]},
        {"shape": "sphere", "center": [5.0, 5.0], "radius": 1.0},
    ]
    x = np.array([[1.5, 0.5], [1.1, 0.5], [0.0, 0.5], [3.0, 2.0], [5.0, 5.5], [5.0, 7.0]])
    expected = [-0.5, -0.1, 1.0, math.sqrt(2.0), -0.5, 1.0]
    np.testing.assert_allclose(soak_tool.obstacle_sdf(x, obstacles), expected, atol=1e-12)
    assert np.isinf(soak_tool.obstacle_sdf(x, [])).all()
    # the box stands on the floor: with the domain its bottom face is shut, the distance
    # inside is to an open face and the distance outside is unchanged
    domain = {"min": [0.0, 0.0], "max": [8.0, 8.0]}
    x = np.array([[1.5, 0.0], [1.1, 0.01], [1.5, 0.9], [0.0, 0.5], [3.0, 2.0]])
    expected = [-0.5, -0.1, -0.1, 1.0, math.sqrt(2.0)]
    np.testing.assert_allclose(soak_tool.obstacle_sdf(x, obstacles[:1], domain), expected, atol=1e-12)


def _parts(x, m, kind=None):
    x = np.asarray(x, np.float32)
    n = len(x)
    return {
        "x": x,
        "v": np.zeros_like(x),
        "m": np.asarray(m, np.float32),
        "kind": np.zeros(n, np.int32) if kind is None else np.asarray(kind, np.int32),
        "level": np.zeros(n, np.int32),
    }


SCENE = {
    "dim": 2,
    "domain": {"min": [0.0, 0.0], "max": [2.0, 1.0]},
    "obstacles": [{"shape": "box", "min": [1.0, 0.0], "max": [1.2, 0.5]}],
}


def test_checks_pass_on_a_clean_state_and_flag_each_fault():
    good = _parts([[0.5, 0.5], [1.5, 0.2], [1.2, 0.3]], [0.1, 0.1, 0.2])
    mass0 = math.fsum([float(np.float32(0.1)), float(np.float32(0.1)), float(np.float32(0.2))])
    assert soak_tool.check_state(good, SCENE, mass0, 1e-6) == []
    cases = [
        ("NaN", _parts([[np.nan, 0.5], [1.5, 0.2], [1.2, 0.3]], [0.1, 0.1, 0.2])),
        ("outside the domain", _parts([[2.1, 0.5], [1.5, 0.2], [1.2, 0.3]], [0.1, 0.1, 0.2])),
        ("inside an obstacle", _parts([[1.1, 0.3], [1.5, 0.2], [1.2, 0.3]], [0.1, 0.1, 0.2])),
        # on the floor under the box, whose bottom face is shut (mrsph/sph/boundary.py)
        ("inside an obstacle", _parts([[1.1, 0.0], [1.5, 0.2], [1.2, 0.3]], [0.1, 0.1, 0.2])),
        ("real mass", _parts([[0.5, 0.5], [1.5, 0.2], [1.2, 0.3]], [0.1, 0.1, 0.2000001])),
    ]
    for what, parts in cases:
        problems = soak_tool.check_state(parts, SCENE, mass0, 1e-6)
        assert len(problems) == 1 and what in problems[0], (what, problems)
    # virtual particles carry no mass of their own and may sit in walls (solver.py)
    virtual = _parts([[0.5, 0.5], [1.5, 0.2], [1.2, 0.3], [1.1, 0.3]], [0.1, 0.1, 0.2, 0.4], kind=[0, 0, 0, 4])
    assert soak_tool.check_state(virtual, SCENE, mass0, 1e-6) == []


def test_mass_is_exact_where_only_full_groups_merge_and_to_round_off_elsewhere():
    full = {**SCENE, "dim": 2, "adaptivity": {"enabled": True, "merge_min_children": 4, "merge_remnants": False}}
    partial = {**full, "adaptivity": {**full["adaptivity"], "merge_remnants": True}}
    assert soak_tool.mass_rtol(full) == 0.0 and soak_tool.mass_rtol(SCENE) == 0.0
    assert soak_tool.mass_rtol(partial) == soak_tool.PARTIAL_MASS_RTOL
    m = [0.1, 0.1, 0.2]
    mass0 = math.fsum(float(np.float32(v)) for v in m)
    rounded = _parts([[0.5, 0.5], [1.5, 0.2], [1.2, 0.3]], [0.1, 0.1, 0.2000001])  # 2.5e-7
    assert soak_tool.check_state(rounded, partial, mass0, 1e-6) == []
    assert len(soak_tool.check_state(rounded, full, mass0, 1e-6)) == 1
    lost = _parts([[0.5, 0.5], [1.2, 0.3]], [0.1, 0.2])
    assert "real mass" in soak_tool.check_state(lost, partial, mass0, 1e-6)[0]


def test_cursor_pushes_pulls_and_lets_go_inside_the_fluid():
    from mrsph.scene.config import load_scene

    data = load_scene("demo_2d").data
    cursor = soak_tool.ScriptedCursor(data, speed=10.0, gesture_s=0.5)
    assert [cursor.buttons(t) for t in (0.1, 0.6, 1.1, 1.6)] == [{"left"}, {"right"}, set(), {"left"}]
    pts = np.array([cursor.position(t) for t in np.linspace(0.0, 3.0, 301)])
    assert (pts >= [0.0, 0.0]).all() and (pts <= [1.6, 0.32]).all()
    step = np.linalg.norm(np.diff(pts[:, :1], axis=0), axis=1) / 0.01
    assert step.max() == pytest.approx(10.0, rel=1e-6)


@pytest.mark.slow  # a long run, in -m slow (conftest.py, "two tiers")
@pytest.mark.parametrize("solver", ["wcsph", "dfsph", "pbf"])
def test_soak_short(fresh_program, monkeypatch, solver):
    """SHORT soak (1000 steps, not the 10^5 of test_soak_full) with each pressure solver:
    every check passes, the stirring refines the fluid and the summary line says so, and no
    dfsph density solve stops at its maximum (``strict``). Each level's median mass
    stays within what absorption allows, [absorb_below, ABSORB_CAP] = [0.5, 2] of
    nominal: the mass cascade of partial merges read medians of 0.21-0.50
    (docs/validation.md, "Masses near their level's nominal mass"). Not at most 1: with
    two threads the run differs each time, and a nearly empty level's median can read
    above 1."""
    # compiled as the quick run compiles (conftest.py): so compiled, this soak found a NaN
    # that the optimised kernels' fast math hid (an overflowed list's own image at r = 0,
    # METHOD.md §10)
    monkeypatch.setenv("TI_ADVANCED_OPTIMIZATION", "0")
    res = soak_tool.soak(
        steps=1000,
        check_every=125,
        gesture_s=0.025,
        overrides=(f'fluid.solver="{solver}"',),
        strict=solver == "dfsph",  # no density solve at its maximum, as in the full soak
    )
    print(res.summary())
    assert res.ok, res.failures
    assert res.steps == 1000 and res.checks == 8
    assert res.splits > 0 and res.n_real_max > res.n_real_min
    assert 0.0 < res.min_dt and res.max_speed > 1.0
    assert res.refused == 0 or res.warnings
    line = res.summary()
    assert line.startswith("soak demo_2d: 1000 steps") and line.endswith("8 checks: OK")
    assert len(res.mass_ratio) == 3 and "median mass / nominal by level" in line, line
    from mrsph.multires.absorb import ABSORB_CAP

    assert all(0.5 - 1e-6 <= r <= ABSORB_CAP + 1e-6 for r in res.mass_ratio if not math.isnan(r)), (
        f"median mass / nominal by level {res.mass_ratio}; expected within [0.5, {ABSORB_CAP}]"
    )


@pytest.mark.slow  # a demo build, in -m slow with the short soaks that share its kernels
def test_strict_soak_fails_on_a_solve_stopped_at_its_maximum(fresh_program, monkeypatch):
    """The check behind the full soak's ``strict``: with dfsph.max_iterations = 1 every
    density solve of the stirred demo stops at its maximum, which the summary counts and
    ``strict`` turns into a failure at the first check."""
    monkeypatch.setenv("TI_ADVANCED_OPTIMIZATION", "0")
    res = soak_tool.soak(
        steps=20,
        check_every=10,
        gesture_s=0.025,
        # shorten_steps = 0: a solve at its maximum would otherwise halve the step and retry
        overrides=(
            'fluid.solver="dfsph"',
            "dfsph.max_iterations=1",
            "dfsph.density_tolerance=1e-9",
            "dfsph.shorten_steps=0",
        ),
        strict=True,
    )
    assert res.unconverged >= 10 and not res.ok, (res.unconverged, res.failures)
    assert "stopped at their maximum iterations" in res.failures[0], res.failures
    assert f"solves at their maximum {res.unconverged}" in res.summary(), res.summary()


def test_a_collapsed_step_fails_the_soak_once_enough_windows_have_passed():
    """The step check: a window whose mean step falls below STALL_FRACTION of the median
    window's fails, as the dfsph soak's did when a caged fine particle's pressure took its
    step from 0.2 ms to 2 us (docs/validation.md, "Stirred soak"); a stir's usual swings
    (0.4-3 times the median) and the run's first windows do not."""
    typical = [2e-4, 1e-4, 4e-4, 2.5e-4, 0.9e-4, 3e-4, 2e-4, 1.5e-4, 2e-4, 5e-4, 2e-4]
    assert soak_tool.stalled(typical) is None
    assert soak_tool.stalled(typical + [0.8e-4]) is None
    line = soak_tool.stalled(typical + [3e-6])
    assert line and line.startswith("the step collapsed: 3e-06 s"), line
    assert "0.015 of the run's median 0.0002 s" in line, line
    # too few windows to know the run's step
    assert soak_tool.stalled(typical[: soak_tool.STALL_WINDOWS - 1] + [3e-6]) is None


def test_mass_ratios_are_per_level_medians_of_the_real_particles():
    """The summary's mass drift: real particles only (a virtual one's mass is a share of
    its owner's), over the level's nominal mass; nan for a level with no real particle."""
    from mrsph.sph.particles import REGULAR, TRANSIENT_CHILD, VIRTUAL_CHILD

    parts = {
        "kind": np.array([REGULAR, REGULAR, TRANSIENT_CHILD, VIRTUAL_CHILD, REGULAR]),
        "level": np.array([0, 0, 0, 0, 1]),
        "m": np.array([1.0, 0.5, 0.25, 9.0, 1.0], np.float32),
    }
    r = soak_tool.mass_ratios(parts, [1.0, 4.0, 16.0])
    assert r[:2] == [0.5, 0.25] and np.isnan(r[2]), r


@pytest.mark.soak
@pytest.mark.parametrize(
    ("solver", "threads"),
    [("wcsph", 1), ("dfsph", 1), ("dfsph", 2), ("pbf", 1)],
    ids=["wcsph", "dfsph", "dfsph-2", "pbf"],
)
def test_soak_full(fresh_program, solver, threads):
    """The soak proper: 10^5 steps at the strongest stirring (about an hour each), with
    every solver (``fluid.solver``; pbf with the demo's own iteration bounds), dfsph also in
    two threads, where the coupling's atomic adds make each run its own (docs/validation.md,
    "Stirred soak"). No dfsph solve may stop at its maximum iterations (``strict``); pbf's
    may, warned, as its crammed corner needs more than its 8 at times."""
    res = soak_tool.soak(
        steps=100_000,
        check_every=500,
        overrides=(f'fluid.solver="{solver}"',),
        threads=threads,
        strict=solver == "dfsph",
    )
    print(res.summary())
    assert res.ok, res.failures
    assert res.steps == 100_000 and res.splits > 0 and res.merges > 0

"""The HUD's pressure-solver lines and the solver switch's check, without a window.

The window test (tests/test_app_window.py) presses the switch's key on a real scene; this
one holds what the HUD says for a stats row of each solver (and of one the HUD has never
heard of, with counts the others lack, or with keys missing), that the switch cycles the
schema's list whatever its length, and that a scene which cannot take the next solver is
refused with its reason in one line, before any rebuild.
"""

from __future__ import annotations

import pytest

from mrsph.app import switch
from mrsph.app.hud import HUD_TEXT_CHARS, Message, solver_lines
from mrsph.app.switch import next_solver, running_solver, why_not
from mrsph.scene.config import load_scene

#: A stats row of Simulation.stats() with fluid.solver = "dfsph" (the solver's keys only).
DFSPH_ROW = {
    "solver": "dfsph",
    "density_iterations": 7.4,
    "divergence_iterations": 2.0,
    "density_error": 0.00085,
    "unconverged": 0,
}


def test_dfsph_row_shows_iterations_of_each_solve_and_the_density_error():
    lines = solver_lines(DFSPH_ROW, "dfsph", tolerance=0.001)
    assert lines == [
        "solver dfsph   (s: next pbf)",
        "iterations/step: density 7.4, divergence 2.0",
        "density error 0.085 % (tolerance 0.1 %)",
    ], lines
    # every line fits the panel's width
    assert all(len(line) <= HUD_TEXT_CHARS for line in lines), [len(line) for line in lines]


def test_dfsph_row_counts_solves_stopped_at_their_maximum():
    lines = solver_lines({**DFSPH_ROW, "unconverged": 3}, "dfsph")
    assert lines[-1] == "3 solves stopped at max. iterations", lines
    assert lines[2] == "density error 0.085 %", "no tolerance given, none shown"


def test_dfsph_row_counts_steps_halved_for_the_solve():
    assert "2 steps halved for the solve" in solver_lines({**DFSPH_ROW, "shortened": 2}, "dfsph")
    assert not any("halved" in line for line in solver_lines({**DFSPH_ROW, "shortened": 0}, "dfsph"))


def test_wcsph_row_shows_the_mean_compression_and_no_iterations():
    row = {
        "solver": "wcsph",
        "density_iterations": 0.0,
        "divergence_iterations": 0.0,
        "density_error": 0.0031,
        "unconverged": 0,
    }
    assert solver_lines(row, "wcsph") == ["solver wcsph   (s: next dfsph)", "mean compression 0.31 %"]
    ready = solver_lines(row, "wcsph", next_ready=True)[0]
    assert ready == "solver wcsph   (s: next dfsph, ready)" and len(ready) <= HUD_TEXT_CHARS


def test_a_solver_the_hud_does_not_know_shows_its_figures_and_clamped_only_above_zero():
    """A third solver (pbf) iterates its density solve and counts clamped corrections: the
    HUD names it, shows its iterations and error from the row, and its clamped count only
    when there is one; a row without the divergence solve's key shows none of it."""
    row = {"solver": "pbf", "density_iterations": 4.0, "density_error": 0.002, "unconverged": 0, "clamped": 0}
    seen = set()
    lines = solver_lines(row, "pbf", seen=seen)
    assert lines[0].startswith("solver pbf"), lines
    assert lines[1:] == ["iterations/step: density 4.0", "density error 0.2 %"], lines
    lines = solver_lines({**row, "clamped": 12}, "pbf", seen=seen)
    assert lines[-1] == "12 particles slowed by the velocity clamp", lines
    # a later row of fewer iterations keeps the line (the HUD's rows do not jump)
    assert solver_lines({**row, "density_iterations": 0.0}, "pbf", seen=seen)[1] == "iterations/step: density 0.0"


def test_a_row_with_keys_missing_or_null_shows_what_it_has():
    assert solver_lines({}, "dfsph")[0].startswith("solver dfsph")
    assert solver_lines({"solver": "dfsph", "density_iterations": None, "density_error": None}, None) == [
        "solver dfsph   (s: next pbf)"
    ]
    assert solver_lines({"n_real": 10}, None) == []


def test_switch_cycles_the_schema_choices(monkeypatch):
    assert next_solver("wcsph") == "dfsph" and next_solver("dfsph") == "pbf" and next_solver("pbf") == "wcsph"
    # a solver joins the schema: s goes through them all, in the schema's order
    monkeypatch.setattr(switch, "solver_names", lambda: ("wcsph", "dfsph", "pbf", "iisph"))
    assert [next_solver(s) for s in ("wcsph", "dfsph", "pbf", "iisph")] == ["dfsph", "pbf", "iisph", "wcsph"]
    assert next_solver("unknown") == "wcsph"


def test_switch_refuses_a_scene_that_cannot_take_dfsph_in_one_line():
    ok = load_scene("demo_2d", ['fluid.solver="wcsph"'])
    assert running_solver(ok) == "wcsph"
    assert why_not(ok, "dfsph") is None
    assert running_solver(load_scene("demo_2d")) == "pbf" and why_not(load_scene("demo_2d"), "wcsph") is None
    symmetric = load_scene("demo_2d", ['fluid.solver="wcsph"', "adaptivity.coupling=symmetric"])
    why = why_not(symmetric, "dfsph")
    assert why is not None and why.startswith("cannot switch to dfsph: "), why
    assert "adaptivity.coupling" in why and "\n" not in why, why
    assert str(symmetric.path) not in why, f"the scene's path is noise in the HUD: {why}"


def test_switch_says_the_stand_in_has_no_solver():
    from fake_app import FakeSimulation

    fake = FakeSimulation(dim=2)
    assert running_solver(fake.scene) is None
    assert why_not(fake.scene, "dfsph") == "this simulation has no pressure solver to switch"


def test_a_message_says_what_happened_and_goes_a_failure_stays():
    m = Message()
    m.set("opened demo_3d in 3.4 s", now=0.0)
    assert m.shown(now=1.0) == "opened demo_3d in 3.4 s" and m.shown(now=100.0) == ""
    m.set("simulation stopped: NaN", sticky=True, now=0.0)
    assert m.shown(now=100.0) == "simulation stopped: NaN"


@pytest.mark.parametrize("dim", [2, 3])
def test_the_hud_fits_its_window_at_1280x720(dim):
    """The HUD's rows for each solver (and the stand-in) fit a 720-pixel window."""
    from types import SimpleNamespace

    from fake_app import FakeSimulation

    from mrsph.app import hud

    snap = FakeSimulation(dim=dim).snapshot()
    lives = {"wcsph": ("fluid.viscosity", "fluid.stiffness"), "dfsph": ("fluid.viscosity",), "pbf": ("pbf.xsph",)}
    for solver, live in (*lives.items(), (None, None)):
        app = _fake_app(snap, solver, live)
        rows = hud.hud_rows(app, snap)
        height = hud.panel_height(rows)
        assert height <= 720 - 2 * hud.HUD_MARGIN_PX, f"{solver}: the HUD needs {height} px"
        texts = [r[1] for r in rows if r[0] == "text"]
        assert all(len(t) <= HUD_TEXT_CHARS for t in texts), [t for t in texts if len(t) > HUD_TEXT_CHARS]
    del SimpleNamespace


def _fake_app(snap, solver, live):
    """What hud.hud_rows reads of the window."""
    from types import SimpleNamespace

    from mrsph.app.hud import Rates, Speed
    from mrsph.app.mouse import MouseDisturbance

    app = SimpleNamespace(
        fps=14.2,
        scene_name="demo_2d_with_a_long_name",
        speed=Speed(),
        opening=None,
        paused=False,
        frame_sim=0.01,
        frame_dt=1 / 30,
        solver=solver,
        tolerance=0.001,
        solver_seen=set(),
        next_ready=lambda: True,  # the longest solver line
        message=Message(),
        rates=Rates(),
        params={"fluid.viscosity": 4.0, "fluid.stiffness": 400.0, "pbf.xsph": 0.1, "gravity_y": -9.81},
        slider_max={"fluid.viscosity": 20.0, "fluid.stiffness": 1600.0, "pbf.xsph": 1.0},
        mouse=MouseDisturbance.for_domain(snap.domain_min, snap.domain_max, 400.0),
        refinement=True,
        show_virtual=False,
        surface=False,
        tint=False,
        color_mode="level",
    )
    app.message.set("opened demo_2d with wcsph in 2.8 s, and a long tail to wrap over two lines")
    app.takes = lambda key: live is None or key in live
    for name in ("toggle_pause", "step_frame", "reset_sim", "switch_solver", "step_scene", "toggle_help"):
        setattr(app, name, lambda: None)
    app.later = app.next_colour = app.set_refinement = app._set_param = app._set_gravity_y = lambda *a: None
    return app

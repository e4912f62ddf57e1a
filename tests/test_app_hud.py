"""The HUD's pressure-solver lines and the solver switch's check, without a window.

The window test (tests/test_app_window.py) presses the switch's key on a real scene; this
one holds what the HUD says for a stats row of each solver, and that a scene which cannot
take the other solver is refused with its reason in one line, before any rebuild.
"""

from __future__ import annotations

from mrsph.app.hud import solver_lines
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
        "solver dfsph   (s: switch to pbf)",
        "iterations/step: density 7.4, div 2.0",
        "density error 0.085 % (tol 0.1 %)",
    ], lines
    # every line fits the panel's width
    assert all(len(line) <= 40 for line in lines), [len(line) for line in lines]


def test_dfsph_row_counts_solves_stopped_at_their_maximum():
    lines = solver_lines({**DFSPH_ROW, "unconverged": 3}, "dfsph")
    assert lines[-1] == "3 solves stopped at max iterations", lines
    assert lines[2] == "density error 0.085 %", "no tolerance given, none shown"


def test_wcsph_row_shows_the_mean_compression_and_no_iterations():
    row = {
        "solver": "wcsph",
        "density_iterations": 0.0,
        "divergence_iterations": 0.0,
        "density_error": 0.0031,
        "unconverged": 0,
    }
    assert solver_lines(row, "wcsph") == ["solver wcsph   (s: switch to dfsph)", "mean compression 0.31 %"]


def test_row_without_a_solver_names_the_scenes_and_the_stand_in_has_none():
    # a row taken before the solver keys existed: the running scene's name is shown
    assert solver_lines({}, "dfsph")[0].startswith("solver dfsph")
    assert solver_lines({"n_real": 10}, None) == []


def test_switch_cycles_the_schema_choices():
    assert next_solver("wcsph") == "dfsph" and next_solver("dfsph") == "pbf" and next_solver("pbf") == "wcsph"


def test_switch_refuses_a_scene_that_cannot_take_dfsph_in_one_line():
    ok = load_scene("demo_2d", ['fluid.solver="wcsph"'])
    assert running_solver(ok) == "wcsph"
    assert why_not(ok, "dfsph") is None
    assert running_solver(load_scene("demo_2d")) == "dfsph" and why_not(load_scene("demo_2d"), "wcsph") is None
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

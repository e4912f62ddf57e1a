"""The resting tanks' tools: tools/tank_rest.py, the resting tank's harness (docs/validation.md,
"Resting tank"), whose runs are judged by hand, so only what it runs is tested here; and
tools/column_heave.py, the deep column step by step, whose measures are held on a column
that rests; and that each of these, tools/box_overtop.py, tools/marin_approach.py and tools/box_gate.py answers a
bad key with one line."""

import subprocess
import sys

import pytest
from toolload import load_tool


def test_nudges_move_one_key_each_by_about_round_off(dim):
    tool = load_tool("tank_rest")
    runs = tool.nudged(dim, "dfsph", ["dfsph.correction_time=0.003"])
    assert runs[0] == ["dfsph.correction_time=0.003"]
    assert len(runs) == 1 + len(tool.NUDGES), runs
    moved = sorted(r[-1] for r in runs[1:])
    # the test's tank: viscosity 2.0, the default tolerance 0.001
    assert moved == [
        "dfsph.density_tolerance=0.00099",
        "dfsph.density_tolerance=0.00101",
        "fluid.viscosity=1.98",
        "fluid.viscosity=2.02",
    ], moved
    assert all(r[0] == "dfsph.correction_time=0.003" for r in runs[1:]), runs


@pytest.mark.parametrize("tool", ["tank_rest", "column_heave", "box_overtop", "marin_approach", "box_gate"])
def test_a_bad_key_is_one_line_naming_it(tool):
    proc = subprocess.run(
        [sys.executable, f"tools/{tool}.py", "--set", "dfsph.correction_time=true"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert lines == ["--set dfsph.correction_time: wrong type (got true (boolean); expected a number >= 0)"], lines


def test_column_heave_reads_a_resting_wcsph_column_as_hydrostatic():
    """tools/column_heave.py on the deep tank made coarse (20 layers), under wcsph, which
    rests: the floor's pressure reads hydrostatic and the column does not heave."""
    tool = load_tool("column_heave")
    out = tool.heave("tank_rest_2d", "wcsph", ["particles.spacing=0.02"], 0.05, 20)
    assert 0.9 < out["floor_min"] <= out["floor_max"] < 1.1, out
    assert out["heave"] < 0.005, out


def test_column_heave_predicts_the_density_change_with_the_density_s_own_kernel():
    """The prediction check (--predict) on a column started off equilibrium, which rings: the
    density's own kernel (poly6) predicts each step's change to first order, so far closer
    than the solves' spiky gradient does."""
    tool = load_tool("column_heave")
    sets = ["particles.spacing=0.02", "fluid.hydrostatic_start=false"]
    out = tool.heave("tank_rest_2d", "wcsph", sets, 0.02, 10, predict=5)
    for band in ("floor", "inner"):
        assert abs(out[f"{band} actual"]) > 1e-4, out  # it moves
        assert out[f"{band} poly6 rms"] < 0.1 * out[f"{band} spiky rms"], out
        assert out[f"{band} poly6 rms"] < 0.05 * abs(out[f"{band} actual"]) + 1e-5, out

"""tools/tank_rest.py: the resting tank's harness (docs/validation.md, "Resting tank");
its runs are judged by hand, so only what it runs is tested here."""

import subprocess
import sys

from toolload import load_tool


def test_nudges_move_one_key_each_by_about_round_off(dim):
    tool = load_tool("tank_rest")
    runs = tool.nudged(dim, "dfsph", ["dfsph.warm_start=0.4"])
    assert runs[0] == ["dfsph.warm_start=0.4"]
    assert len(runs) == 1 + len(tool.NUDGES), runs
    moved = sorted(r[-1] for r in runs[1:])
    # the test's tank: viscosity 2.0, the default tolerance 0.001
    assert moved == [
        "dfsph.density_tolerance=0.00099",
        "dfsph.density_tolerance=0.00101",
        "fluid.viscosity=1.98",
        "fluid.viscosity=2.02",
    ], moved
    assert all(r[0] == "dfsph.warm_start=0.4" for r in runs[1:]), runs


def test_a_bad_key_is_one_line_naming_it():
    proc = subprocess.run(
        [sys.executable, "tools/tank_rest.py", "--set", "dfsph.warm_start=true"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert lines == ["--set dfsph.warm_start: wrong type (got true (boolean); expected a number in [0, 1])"], lines

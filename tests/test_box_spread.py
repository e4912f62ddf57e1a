"""tools/box_spread.py: MARIN's arrivals over runs that differ by round-off (docs/validation.md,
the adaptive runs' H1). Checked on made-up runs: the members are validate.py's runs under their
own keys, the plain run first; the table's spread and offset are the members' own."""

import subprocess
import sys

import numpy as np
import pytest
from toolload import load_tool

B = load_tool("box_spread")
V = load_tool("validate")


def _run(solver, mode, k, h1):
    """A made-up run of member ``k`` whose H1 rises through 2 cm at ``h1`` s and 6 cm 0.1 s later,
    H2 at 0.4 s and H3 at 0.25 s."""
    t = np.round(np.arange(0.0, 1.5001, 0.002), 6)
    ramp = lambda t0: np.clip((t - t0) * 0.4 + 0.02, 0.0, None) * (t >= t0)  # noqa: E731  (4 cm in 0.1 s)
    job = B.jobs([solver], [mode], k + 1)[-1]
    run = {"t": t.tolist(), "level": [ramp(h1), ramp(0.4), ramp(0.25), 0 * t], "solver": solver, "mode": mode}
    return V.run_key(**V._key_args(job)), run


def test_each_member_is_one_gravity_the_first_the_plain_run():
    assert B.member_sets(0) == []
    sets = [B.member_sets(k)[0] for k in range(1, len(B.GRAVITY))]
    assert len(set(sets)) == len(sets)
    for k, s in enumerate(sets, start=1):
        g = float(s.split("[")[1].split(",")[1])
        assert g == -B.GRAVITY[k] and abs(g + 9.81) < 5e-5 and g != -9.81
    keys = [V.run_key(**V._key_args(j)) for j in B.jobs(["wcsph"], ["uniform"], 3)]
    assert keys[0] == f"box-3d-wcsph-uniform-s{V.scene_spacing('box', 3):.5g}" and len(set(keys)) == 3


def test_arrivals_read_2_and_6_cm():
    _, run = _run("wcsph", "uniform", 0, 1.0)
    got = B.arrivals(run)
    assert got == pytest.approx([1.0, 1.1, 0.4, 0.25], abs=0.003)


def test_the_table_gives_the_members_spread_and_the_adaptive_offset():
    runs = dict(
        [_run("pbf", "uniform", k, h) for k, h in enumerate((1.00, 1.02, 1.04))]
        + [_run("pbf", "adaptive", k, h) for k, h in enumerate((1.05, 1.07, 1.09))]
    )
    got = B.gathered(B.members(runs, ["pbf"], ["uniform", "adaptive"], 3))
    assert got["pbf", "uniform"][:, 0] == pytest.approx([1.0, 1.02, 1.04], abs=0.003)
    d, two_se = B.offset(got["pbf", "adaptive"][:, 0], got["pbf", "uniform"][:, 0])
    assert d == pytest.approx(0.05, abs=0.002) and two_se == pytest.approx(2 * np.sqrt(2 * 0.02**2 / 3), abs=0.003)
    text = B.table(got)
    assert "| pbf uniform | 3 | 1.02" in text and "(1.00" in text and "1.04" in text
    assert "| pbf: adaptive off uniform | | +0.05" in text
    # a member missing from the cache is left out, not read as another's
    del runs[next(iter(runs))]
    assert len(B.gathered(B.members(runs, ["pbf"], ["uniform", "adaptive"], 3))["pbf", "uniform"]) == 2


@pytest.mark.parametrize("count", ["1", "9"])
def test_bad_members_get_one_line(count):
    """One member has no spread; more than ``GRAVITY`` holds have no gravity of their own."""
    out = subprocess.run(
        [sys.executable, str(V.ROOT / "tools" / "box_spread.py"), "--members", count, "--report"],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 2 and out.stderr.strip().count("\n") == 0 and f"--members {count}" in out.stderr


def test_the_validation_table_reads_the_adaptive_offset_over_the_members():
    """validate.py's table gives an adaptive box run's arrival off uniform over the cached
    members, each probe from its own column; with fewer than two members, the one pair's."""
    R = load_tool("validate_report")
    runs = dict(
        [_run("wcsph", "uniform", k, h) for k, h in enumerate((1.00, 1.02, 1.04))]
        + [_run("wcsph", "adaptive", k, h) for k, h in enumerate((1.05, 1.07, 1.09))]
    )
    for r in runs.values():
        r.update(spacing=round(V.scene_spacing("box", 3), 5), probes=[{"arrival": 0.5}] * 3)
    keys = {m: V.run_key(**V._key_args(B.jobs(["wcsph"], [m], 1)[0])) for m in ("uniform", "adaptive")}
    ada, uni = runs[keys["adaptive"]], runs[keys["uniform"]]
    gap, two_se, over = R._arrival_gap(runs, ada, uni, 0)
    assert gap == pytest.approx(0.05, abs=0.002) and two_se > 0.01 and over == "3 runs each"
    assert R._arrival_gap(runs, ada, uni, 1)[0] == pytest.approx(0.0, abs=0.002)  # H2, not H1's body
    for key in [k for k in runs if "adaptive" in k and k != keys["adaptive"]]:
        del runs[key]
    ada["probes"] = [{"arrival": 0.61}] * 3
    gap, two_se, over = R._arrival_gap(runs, ada, uni, 0)
    assert gap == pytest.approx(0.11) and np.isnan(two_se) and over == ""

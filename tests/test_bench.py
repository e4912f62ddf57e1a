"""The benchmark (``python3 main.py bench``) and its plot (tools/plot_bench.py).

The pair arithmetic, the table and the case sizes are checked on hand-made numbers
(no Taichi); smoke runs of the command line check that the cases run and write the
documented JSON keys, not what the timings are: the rendered demo in the quick run, every
kind of case (a run, a pair, the demo) in -m slow.
"""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
from toolload import load_tool

from mrsph.cli.bench import (
    MULTIRES_PHASES,
    UNIFORM_OVERRIDE,
    _cases,
    _table,
    advanced_optimization,
    fluid_volume,
    gpu_name,
    pair_summary,
    solve_iterations,
)
from mrsph.scene.config import load_scene

REPO = Path(__file__).resolve().parent.parent
TIMEOUT_S = 600

ROW_KEYS = {
    "case",
    "neighbour_passes_per_step",
    "neighbour_passes_per_sim_s",
    "neighbour_passes_per_wall_s",
    "density_error",
    "clamped",
    "kind",
    "scene",
    "overrides",
    "dim",
    "adaptive",
    "levels",
    "arch",
    "finest_spacing",
    "uniform_equivalent",
    "warm",
    "interval",
    "n_real",
    "n_virtual",
    "per_level",
    "per_level_virtual",
    "steps",
    "wall_s",
    "steps_per_s",
    "particle_steps_per_s",
    "sim_s_per_wall_s",
    "compile_s",
    "phase_share",
    "rss_mb",
    "peak_mb",
    "repeats",
    "walls",
}
PAIR_KEYS = {
    "pair",
    "adaptive_case",
    "uniform_case",
    "dim",
    "finest_spacing",
    "levels",
    "warm",
    "interval",
    "speedup",
    "particle_ratio",
    "step_ratio",
    "multires_share",
}
DEMO_KEYS = {
    "renderer",
    "rendered_sim_s_per_wall_s",
    "width",
    "height",
    "frames",
    "frames_per_s",
    "render_ms",
    "render_share",
    "render_compile_s",
    "fluid_volume",
    "reference_particles",
    "reference_spacing",
    "spacing_ratio",
    "surface_ms",
    "window_frame_ms",
    "surface_share",
    "surface_net_ms",
}


def _row(case, adaptive, wall, n_real, steps, shares, **kw):
    row = {
        "case": case,
        "kind": "pair",
        "pair": "p",
        "dim": 2,
        "adaptive": adaptive,
        "levels": 2 if adaptive else 1,
        "finest_spacing": 0.0035,
        "warm": 0.24,
        "interval": 0.01,
        "wall_s": wall,
        "n_real": n_real,
        "n_virtual": 10 if adaptive else 0,
        "steps": steps,
        "steps_per_s": steps / wall,
        "particle_steps_per_s": n_real * steps / wall,
        "sim_s_per_wall_s": 0.01 / wall,
        "compile_s": 1.0,
        "phase_share": shares,
        "per_level": [100, n_real - 100] if adaptive else [n_real],
        "rss_mb": 100.0,
        "peak_mb": 200.0,
    }
    row.update(kw)
    return row


ADAPTIVE = _row(
    "p adaptive",
    True,
    2.0,
    3000,
    600,
    {"forces": 0.5, "adapt": 0.1, "virtual_coupling": 0.15, "virtual_advect": 0.05, "density": 0.2},
)
UNIFORM = _row("p uniform", False, 8.0, 12000, 400, {"forces": 0.6, "density": 0.4})


def test_pair_ratios_on_hand_made_rows():
    p = pair_summary(ADAPTIVE, UNIFORM)
    assert p["speedup"] == pytest.approx(4.0)  # 8 s uniform / 2 s adaptive
    assert p["particle_ratio"] == pytest.approx(4.0)  # 12000 / 3000
    assert p["step_ratio"] == pytest.approx(1.5)  # 600 / 400
    assert p["multires_share"] == pytest.approx(0.3)  # adapt + virtual_coupling + virtual_advect
    assert set(MULTIRES_PHASES) == {"adapt", "virtual_coupling", "virtual_advect"}
    assert p["pair"] == "p" and p["adaptive_case"] == "p adaptive" and p["uniform_case"] == "p uniform"
    assert set(p) == PAIR_KEYS


@pytest.mark.parametrize("key, value", [("interval", 0.02), ("warm", 0.1), ("finest_spacing", 0.005), ("dim", 3)])
def test_a_pair_must_cover_the_same_interval_and_resolution(key, value):
    with pytest.raises(ValueError, match=key):
        pair_summary(ADAPTIVE, {**UNIFORM, key: value})


def test_a_pair_is_adaptive_then_uniform():
    with pytest.raises(ValueError, match="adaptive row and a uniform row"):
        pair_summary(UNIFORM, ADAPTIVE)


def test_table_has_a_pair_line_under_the_uniform_run():
    text = _table([ADAPTIVE, UNIFORM], [pair_summary(ADAPTIVE, UNIFORM)])
    lines = text.splitlines()
    uniform = next(i for i, line in enumerate(lines) if line.startswith("p uniform"))
    assert (
        lines[uniform + 2]
        .strip()
        .startswith(
            "=> adaptive vs uniform: 4.00x faster, 4.00x fewer real particles, 1.50x the steps; multires phases 30%"
        )
    )
    assert "levels [100, 2900]" in text and "peak memory: 200 MB" in text


def test_case_names_match_their_particle_counts():
    """The "~10k" in a case's name is the lattice count its overrides give (within 10 %)."""
    for case in _cases(full=True):
        scene = load_scene(case.scene, list(case.overrides))
        n = scene.estimate_particles()
        if "~" in case.name:
            nominal = float(case.name.split("~")[1].rstrip("k")) * 1000
            assert abs(n - nominal) <= 0.1 * nominal, (case.name, n)
        if case.kind == "pair":
            assert scene.data["adaptivity"]["enabled"], case.name
            assert load_scene(case.scene, list(case.overrides) + [UNIFORM_OVERRIDE]).estimate_particles() == n
            assert 2_000 <= n <= 200_000, (case.name, n)  # the 3D 5 mm twin: 166k
    kinds = {c.kind for c in _cases(full=False)}
    assert kinds == {"run", "pair", "demo"}
    quick_pairs = {load_scene(c.scene).data["dim"] for c in _cases(full=False) if c.kind == "pair"}
    assert quick_pairs == {2, 3}


def test_demo_iterations_are_the_step_weighted_mean_of_its_frames():
    """The demo row's iterations come from its frames' snapshots, each of which takes the
    solver's counters (a row read after them said 0.00 iterations a step)."""
    frames = [
        (10, {"density_iterations": 2.0, "divergence_iterations": 1.0}),
        (30, {"density_iterations": 6.0, "divergence_iterations": 0.0}),
    ]
    got = solve_iterations(frames)
    assert got == pytest.approx({"density_iterations": 5.0, "divergence_iterations": 0.25}), got
    wcsph = [(10, {"density_iterations": None, "divergence_iterations": None})]
    assert solve_iterations(wcsph) == {} and solve_iterations([]) == {}


@pytest.mark.parametrize(
    "flag, expected", [(None, True), ("0", False), (" 0 ", False), ("-0", False), ("1", True), ("", True), ("2", True)]
)
def test_advanced_optimization_reads_the_flag_as_taichi_does(monkeypatch, flag, expected):
    if flag is None:
        monkeypatch.delenv("TI_ADVANCED_OPTIMIZATION", raising=False)
    else:
        monkeypatch.setenv("TI_ADVANCED_OPTIMIZATION", flag)
    assert advanced_optimization() is expected, flag


def test_gpu_name_is_asked_only_of_a_cuda_run(monkeypatch, tmp_path):
    """The JSON's ``gpu`` names the card a CUDA run used (nvidia-smi's line), and is None
    for CPU runs and where nvidia-smi is missing or fails."""
    assert gpu_name({"x64"}) is None
    fake = tmp_path / "nvidia-smi"
    fake.write_text("#!/bin/sh\necho 'NVIDIA H200, 143771 MiB, 580.159.04'\n")
    fake.chmod(0o755)
    monkeypatch.setenv("PATH", f"{tmp_path}{os.pathsep}{os.environ['PATH']}")
    assert gpu_name({"cuda"}) == "NVIDIA H200, 143771 MiB, 580.159.04"
    fake.write_text("#!/bin/sh\nexit 9\n")
    assert gpu_name({"cuda"}) is None
    monkeypatch.setenv("PATH", str(tmp_path / "nowhere"))
    assert gpu_name({"cuda"}) is None


def test_fluid_volume_of_the_demo():
    scene = load_scene("demo_2d")
    blocks = scene.data["fluid"]["blocks"]
    expected = sum((b["max"][0] - b["min"][0]) * (b["max"][1] - b["min"][1]) for b in blocks)
    assert fluid_volume(scene) == pytest.approx(expected, rel=1e-12)


#: The smoke run's --set: a key whose change recompiles no kernel (the demo already has it).
SMOKE_SET = "fluid.viscosity=4.0"


def _bench_smoke(tmp_path, cases: list) -> tuple:
    """One short run of ``cases`` through the command line at 5 % of their intervals:
    (the JSON's rows by case name, the JSON, the process). Checks what every row must
    hold: the documented keys, the override, a profiled interval timed phase by phase,
    and its line in the table; not what the timings are."""
    out = tmp_path / "bench.json"
    case_args = [arg for case in cases for arg in ("--case", case)]
    proc = subprocess.run(
        [
            sys.executable,
            "main.py",
            "bench",
            *case_args,
            "--repeats",
            "1",
            "--interval-scale",
            "0.05",
            "--json",
            str(out),
            "--set",
            SMOKE_SET,
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(out.read_text())
    rows = {r["case"]: r for r in result["cases"]}
    # the default test run compiles without Taichi's optimisation passes (conftest.py)
    optimised = advanced_optimization()
    assert result["advanced_optimization"] is optimised
    assert ("TI_ADVANCED_OPTIMIZATION=0" in proc.stderr) is not optimised, proc.stderr[-2000:]
    assert result["overrides"] == [SMOKE_SET]
    assert result["gpu"] is None, result["gpu"]  # this suite runs on the CPU
    for r in rows.values():
        assert ROW_KEYS <= set(r), ROW_KEYS - set(r)
        assert SMOKE_SET in r["overrides"], r["overrides"]
        assert r["repeats"] == 1 and len(r["walls"]) == 1 and r["wall_s"] > 0 and r["steps"] > 0
        if not r["adaptive"]:
            assert r["per_level"] == [r["n_real"]]
        assert math.isclose(sum(r["phase_share"].values()), 1.0, rel_tol=1e-9)
        # the profiled interval times the step phase by phase, not as the one launch of
        # an unprofiled step (fused.py), which would leave these at 0
        # (a pbf step has no force pass: its solver's iterations hold the viscosity)
        phases = ("grid", "density", "timestep", "integrate")
        phases += ("pressure",) if r["solver"] == "pbf" else ("forces",)
        for phase in phases:
            assert r["phase_share"].get(phase, 0.0) > 0.0, (r["case"], phase, r["phase_share"])
        assert r["case"] in proc.stdout
    return rows, result, proc


def _check_demo_row(demo: dict, stdout: str) -> None:
    """The rendered demo's own keys: its frames, its renderer and its surface's share."""
    assert DEMO_KEYS <= set(demo) and demo["renderer"] in ("ggui", "raster")
    assert demo["frames"] >= 1 and demo["frames_per_s"] > 0 and "render" in demo["phase_share"]
    assert demo["rendered_sim_s_per_wall_s"] > 0 and demo["neighbour_passes_per_step"] >= 2
    assert demo["reference_spacing"] == pytest.approx((demo["fluid_volume"] / 10_000) ** 0.5)
    assert demo["surface_share"] == pytest.approx(demo["surface_ms"] / demo["window_frame_ms"])
    assert 0 < demo["surface_ms"] < demo["window_frame_ms"]
    assert "rendered in real time" in stdout and "% of a window frame with it" in stdout
    assert "neighbour passes:" in stdout


def test_bench_smoke_the_rendered_demo(tmp_path):
    """The quick run's smoke test of ``bench``: the rendered demo alone, the case a user
    runs first, with every key a row and a demo row hold. Every kind of case runs in
    the next test (-m slow): four builds, 100 s of this suite's ten minutes."""
    rows, _, proc = _bench_smoke(tmp_path, ["demo_2d"])
    assert list(rows) == ["demo_2d rendered"]
    _check_demo_row(rows["demo_2d rendered"], proc.stdout)


@pytest.mark.slow
def test_bench_smoke_writes_json_with_every_key(tmp_path):
    """Every kind of case (a run, a pair, the rendered demo) in one bench run: the pair's
    summary joins its two rows, and the table prints them all."""
    rows, result, proc = _bench_smoke(
        tmp_path, ["dam_break_2d uniform ~10k", "dam_break_obstacle_2d s=3.5mm", "demo_2d"]
    )
    assert list(rows) == [
        "dam_break_2d uniform ~10k",
        "dam_break_obstacle_2d s=3.5mm adaptive",
        "dam_break_obstacle_2d s=3.5mm uniform",
        "demo_2d rendered",
    ]
    assert rows["dam_break_2d uniform ~10k"]["n_real"] == 10082
    adaptive, uniform = rows["dam_break_obstacle_2d s=3.5mm adaptive"], rows["dam_break_obstacle_2d s=3.5mm uniform"]
    assert adaptive["adaptive"] and not uniform["adaptive"] and uniform["levels"] == 1
    assert uniform["n_real"] == uniform["uniform_equivalent"] == adaptive["uniform_equivalent"]
    (pair,) = result["pairs"]
    assert set(pair) == PAIR_KEYS
    assert pair["speedup"] == pytest.approx(uniform["wall_s"] / adaptive["wall_s"])
    assert "=> adaptive vs uniform:" in proc.stdout
    _check_demo_row(rows["demo_2d rendered"], proc.stdout)


def test_bench_rejects_an_unknown_case():
    proc = subprocess.run(
        [sys.executable, "main.py", "bench", "--case", "no such case"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert proc.returncode == 2 and "no case matches" in proc.stderr and "Traceback" not in proc.stderr


def test_bench_lists_the_cases_case_chooses():
    proc = subprocess.run(
        [sys.executable, "main.py", "bench", "--case", "pbf", "--list"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    lines = proc.stdout.strip().splitlines()
    assert proc.returncode == 0 and lines and all("pbf" in line for line in lines), proc.stdout + proc.stderr


def test_bench_refuses_a_bad_override_before_running():
    """A bad --set is one line per problem and exit 2 before any case compiles, said once
    even though it is wrong in both chosen cases."""
    proc = subprocess.run(
        [sys.executable, "main.py", "bench", "--case", "demo", "--set", 'fluid.solver="implicit"'],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        'python3 main.py bench: --set fluid.solver: unknown choice (got "implicit"; '
        'expected one of "wcsph", "dfsph", "pbf")'
    ], proc.stderr


def test_bench_refuses_an_unwritable_json_before_running(tmp_path):
    """--json into a path under a file: one line and exit 2, before any case runs (it
    used to end the whole benchmark in a FileNotFoundError traceback)."""
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    proc = subprocess.run(
        [sys.executable, "main.py", "bench", "--json", str(a_file / "r.json"), "--case", "10k"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        f"python3 main.py bench: error: --json {a_file}: exists and is not a directory"
    ], proc.stderr


# ----------------------------------------------------------------------------- the plot
def _plot_tool():
    return load_tool("plot_bench")


def _sweep_result():
    rows = []
    for dim, spacings in ((2, (0.005, 0.0035, 0.0025)), (3, (0.02, 0.015, 0.012))):
        for s in spacings:
            n = round(0.15 / s**dim) if dim == 2 else round(0.02 / s**dim)
            for adaptive, wall in ((True, n * 1e-4), (False, n * 4e-4)):
                rows.append(
                    {
                        "kind": "pair",
                        "dim": dim,
                        "adaptive": adaptive,
                        "finest_spacing": s,
                        "uniform_equivalent": n,
                        "wall_s": wall,
                        "interval": 0.01,
                    }
                )
    rows.append(
        {
            "kind": "run",
            "dim": 2,
            "adaptive": False,
            "finest_spacing": 0.0035,
            "uniform_equivalent": 10082,
            "wall_s": 1.0,
            "interval": 0.02,
        }
    )
    return {"cases": rows, "pairs": [], "repeats": 1, "arch": "cpu"}


def test_plot_curves_take_pair_rows_by_dimension_and_mode():
    curves = _plot_tool().curves(_sweep_result())
    assert sorted(curves) == [2, 3]
    for dim in (2, 3):
        for adaptive, factor in ((True, 1e-4), (False, 4e-4)):
            pts = curves[dim][adaptive]
            assert len(pts) == 3
            assert [p[0] for p in pts] == sorted(p[0] for p in pts)  # by resolution
            for n, seconds_per_s, _s in pts:
                assert seconds_per_s == pytest.approx(n * factor / 0.01)


def test_plot_writes_a_png(tmp_path):
    pytest.importorskip("matplotlib")
    import imageio.v3 as iio

    path = _plot_tool().plot(_sweep_result(), tmp_path / "bench.png")
    img = iio.imread(path)
    assert img.ndim == 3 and img.shape[1] > img.shape[0] > 300

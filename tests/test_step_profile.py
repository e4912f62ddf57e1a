"""tools/step_profile.py: one short run through its command line (it leans on Taichi's
profiler internals, which a Taichi update could move)."""

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def test_step_profile_lists_tasks_and_calls():
    proc = subprocess.run(
        [
            sys.executable,
            "tools/step_profile.py",
            "dam_break_2d",
            "--set",
            "particles.spacing=0.02",
            "--warm",
            "2",
            "--steps",
            "3",
            "--top",
            "5",
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = proc.stdout
    assert "dam_break_2d particles.spacing=0.02:" in out and "solver wcsph" in out, out
    tasks = out.split("task\n")[1].split("\n\n")[0].splitlines()
    assert len(tasks) == 5 and any("_range_for" in t for t in tasks), out
    # a weakly compressible step of a uniform run is one launch (sph/step.py)
    calls = out.split("calls from Python into Taichi: ")[1].splitlines()
    assert calls[0].startswith("1.0 a step") and calls[1].endswith("  Segment.run"), out
    assert "calls from Python into Taichi: " in out


def test_step_profile_by_phase_names_the_phases_kernels():
    proc = subprocess.run(
        [
            sys.executable,
            "tools/step_profile.py",
            "dam_break_2d",
            "--set",
            "particles.spacing=0.02",
            "--warm",
            "2",
            "--steps",
            "3",
            "--by-phase",
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = proc.stdout
    assert ", phase by phase" in out, out
    # the sort, the density, the forces and the end of the step, each launched alone
    for kernel in ("PoolSort.run", "Density.run", "Forces.run", "Integrator.timestep", "Integrator.integrate"):
        assert f"  {kernel}\n" in out, out


def test_step_profile_refuses_a_bad_override():
    proc = subprocess.run(
        [sys.executable, "tools/step_profile.py", "dam_break_2d", "--set", "fluid.nope=1"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.startswith("step_profile: --set fluid.nope: unknown key"), proc.stderr

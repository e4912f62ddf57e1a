"""Taichi start-up and end (mrsph/runtime.py): the automatic thread count and the core
pinning that goes with one thread, a Simulation outliving its program, and the programs'
ends one at a time."""

import os
from pathlib import Path

import pytest

from mrsph import runtime
from mrsph.scene.config import load_scene


def test_auto_threads_by_starting_particles():
    demo = load_scene("demo_2d")  # adaptive, starts at its coarsest level
    assert runtime.starting_particles(demo) == demo.estimate_particles() // 16
    assert runtime.auto_threads(demo) == 1
    big = load_scene("dam_break_2d", ["particles.spacing=0.0016"])  # ~48k particles
    assert runtime.starting_particles(big) > runtime.AUTO_ONE_THREAD_BELOW[2]
    assert runtime.auto_threads(big) is None
    assert runtime.auto_threads(big, 3) == 3 and runtime.auto_threads(demo, None) is None


@pytest.mark.skipif(
    not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
    reason="needs a CPU affinity of two cores or more",
)
def test_one_thread_is_pinned_and_released():
    before = os.sched_getaffinity(0)
    runtime.reset()
    try:
        runtime.ensure("cpu", "f32", threads=1)
        pinned = os.sched_getaffinity(0)
        assert len(pinned) == 1 and pinned <= before, f"affinity with one thread: {pinned}"
        runtime.ensure("cpu", "f32")  # all cores again: the pin is undone
        assert os.sched_getaffinity(0) == before
    finally:
        runtime.reset()
    assert os.sched_getaffinity(0) == before


def test_a_simulation_whose_fields_were_freed_says_so():
    """Taichi frees every field when it starts again (here for another thread count): the
    first Simulation's next call says so in one line, where its step failed deep in Taichi
    (TaichiIndexError) and a read of its particles crashed the process."""
    from mrsph.simulation import Simulation, SimulationError

    scene = load_scene(
        {
            "description": "a small tank",
            "dim": 2,
            "domain": {"min": [0.0, 0.0], "max": [0.2, 0.2]},
            "particles": {"spacing": 0.02},
            "fluid": {"blocks": [{"min": [0.0, 0.0], "max": [0.2, 0.1]}]},
        }
    )
    runtime.reset()
    try:
        first = Simulation(scene, threads=1)
        first.step()
        second = Simulation(scene, threads=2)
        for call in (first.step, first.particles, first.save_state, first.reset, lambda: first.set_disturbance(None)):
            with pytest.raises(SimulationError, match="fields were freed when Taichi was initialised again"):
                call()
        assert second.step() > 0.0
    finally:
        runtime.reset()


@pytest.mark.skipif(os.name != "posix", reason="the lock is POSIX's flock")
def test_processes_end_their_taichi_programs_one_at_a_time(tmp_path):
    """The window and its simulations' processes end together, and each writes its
    kernels into the offline cache as it ends; Taichi's own lock gives up when another
    holds it ("Lock ... failed"), losing them. ``runtime.finish`` takes a lock beside the
    cache first: a process that ends while another holds it waits."""
    import fcntl
    import subprocess
    import sys
    import time

    cache = tmp_path / "ticache"
    code = (
        "from mrsph import runtime\n"
        "runtime.ensure('cpu')\n"
        "print('started', flush=True)\n"
        "runtime.finish()\n"
        "print('finished', flush=True)\n"
    )
    env = {**os.environ, "TI_OFFLINE_CACHE_FILE_PATH": str(cache)}
    cache.parent.mkdir(parents=True, exist_ok=True)
    with open(tmp_path / "mrsph-finish.lock", "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        proc = subprocess.Popen(
            [sys.executable, "-c", code], env=env, cwd=Path(__file__).resolve().parent.parent,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )  # fmt: skip
        seen = []
        while not seen or seen[-1] != "started":  # Taichi's banner comes first
            seen.append(proc.stdout.readline().strip())
            assert seen[-1] or proc.poll() is None, seen
        time.sleep(2.0)
        assert proc.poll() is None, f"finish() did not wait for the lock: {proc.stdout.read()}"
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0 and "finished" in out, out
    assert "Lock" not in out, out


def _loops_hidden_in_kernel_ifs(source: str) -> list[str]:
    """Every ``@ti.kernel``, and every ``ti.func`` named ``*_func`` (a pass's body, which its
    kernel and the fused step call at their top level: fused.py), whose body has a loop
    inside a run-time ``if`` at its top level (a ``ti.static`` condition or loop is
    unrolled at compile time and looked through)."""
    import ast

    found = []
    tree = ast.parse(source)
    for fn in ast.walk(tree):
        if not isinstance(fn, ast.FunctionDef):
            continue
        decorators = [ast.unparse(d) for d in fn.decorator_list]
        if not any("kernel" in d or ("func" in d and fn.name.endswith("_func")) for d in decorators):
            continue

        def walk(stmts, name):
            for s in stmts:
                if isinstance(s, ast.If) and "ti.static" in ast.unparse(s.test):
                    walk(s.body + s.orelse, name)
                elif isinstance(s, ast.If):
                    if any(isinstance(sub, ast.For) for sub in ast.walk(s)):
                        found.append(f"{name} (line {s.lineno}: if {ast.unparse(s.test)})")
                elif isinstance(s, ast.For) and "ti.static" in ast.unparse(s.iter):
                    walk(s.body, name)

        walk(fn.body, fn.name)
    return found


def test_no_kernel_hides_a_particle_loop_inside_a_top_level_if():
    """Only a kernel's outermost loops run in parallel: one inside a run-time ``if`` runs
    on one thread, which a GPU pays a thousandfold (the DFSPH sweep's ``if mode ==
    DENSITY: for i in range(n)`` took 8 of its 9 ms at 100k particles on an H200). Put
    the condition in the loop's bound or body instead."""
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent / "mrsph"
    hidden = [
        f"{path.relative_to(root.parent)}: {k}"
        for path in sorted(root.rglob("*.py"))
        for k in _loops_hidden_in_kernel_ifs(path.read_text())
    ]
    assert not hidden, f"loops that would run on one thread: {hidden}"
    # the check itself finds one
    planted = "@ti.kernel\ndef k(n: ti.i32, m: ti.i32):\n    if m == 1:\n        for i in range(n):\n            pass\n"
    assert _loops_hidden_in_kernel_ifs(planted) == ["k (line 3: if m == 1)"]
    assert _loops_hidden_in_kernel_ifs(planted.replace("@ti.kernel\ndef k(", "@ti.func\ndef k_func(")) == [
        "k_func (line 3: if m == 1)"
    ]


# ---------------------------------------------------------------- kernel_build.py
@pytest.fixture
def checked_positions(taichi_f32):
    """Every position message the memoized ``get_pos_info`` returns while the test builds
    kernels, compared with the one Taichi's own function makes for the same node."""
    from taichi.lang.ast import ast_transformer_utils as utils

    from mrsph import kernel_build

    assert kernel_build.installed() == (True, ""), kernel_build.installed()
    memoized = utils.ASTTransformerContext.get_pos_info
    original = memoized.original
    seen = {"calls": 0, "wrong": []}

    def checked(ctx, node):
        got, want = memoized(ctx, node), original(ctx, node)
        seen["calls"] += 1
        if got != want:
            seen["wrong"].append((got, want))
        return got

    utils.ASTTransformerContext.get_pos_info = checked
    yield seen
    utils.ASTTransformerContext.get_pos_info = memoized


def test_remembered_positions_are_taichis_own(checked_positions):
    """Two nodes on one line, the same nodes at the same columns on two lines, one
    function inlined at three call sites of two kernels: each node keeps its own message
    (a key without the column would give the second ``a`` of a line the first one's
    caret; a key without the line, the second line the first one's)."""
    import taichi as ti

    x = ti.field(float, shape=4)

    @ti.func
    def twice(a, b):
        c = a * b + a
        d = a - b - a
        return c + d

    @ti.kernel
    def first():
        for i in x:
            x[i] = twice(x[i], 2.0) + twice(1.0, x[i])

    @ti.kernel
    def second():
        for i in x:
            x[i] = twice(x[i], x[i])

    first()
    second()
    assert checked_positions["calls"] > 20, checked_positions
    assert not checked_positions["wrong"], (
        f"{len(checked_positions['wrong'])} message(s) differ; first: {checked_positions['wrong'][0]}"
    )


def test_a_compile_error_still_points_at_its_line(taichi_f32):
    """A kernel's error names its file, its line and a caret under the expression, after a
    first kernel built the same function and a line above built the same nodes at the
    same columns (the memoized source and positions)."""
    import inspect

    import taichi as ti

    x = ti.field(float, shape=4)

    @ti.func
    def shaped(a):
        return a + 1.0

    @ti.kernel
    def fine():
        for i in x:
            x[i] = shaped(x[i])

    a_defined_name = 1.0  # as long as the missing name: the two lines differ only in their line

    @ti.kernel
    def broken():
        for i in x:
            x[i] = shaped(x[i]) + a_defined_name
            x[i] = shaped(x[i]) + undefined_name  # noqa: F821

    fine()
    with pytest.raises(Exception) as err:
        broken()
    lines, first = inspect.getsourcelines(broken.__wrapped__ if hasattr(broken, "__wrapped__") else broken)
    line = first + next(k for k, text in enumerate(lines) if "undefined_name" in text)
    msg = str(err.value)
    assert f"line {line}, in broken" in msg and "^" in msg and "undefined_name" in msg, msg

"""Where a step's time goes, task by task, and how often Python calls into Taichi.

    python3 tools/step_profile.py demo_2d
    python3 tools/step_profile.py dam_break_3d --set particles.spacing=0.0063 --set 'fluid.solver="dfsph"' --arch gpu
    python3 tools/step_profile.py demo_2d --warm 200 --steps 100 --top 20
    python3 tools/step_profile.py demo_2d --by-phase

``bench`` times phases; this looks one level down, at what a GPU or a profiler sees.
After ``--warm`` steps it runs ``--steps`` more and prints:

- the calls from Python into Taichi a step, by name: kernel launches, and the fields
  read or written from Python (each a synchronising kernel of its own). Counted by
  wrapping Taichi's ``Kernel.__call__`` and the fields' item access;
- Taichi's kernel profiler (``ti.init(kernel_profiler=True)``) over the same steps: the
  time of each *task*. A kernel is one task per top-level loop, named ``..._range_for``,
  plus ``..._serial`` tasks for what runs between them on one thread. A ``_serial`` task
  high in the list is a loop that a GPU runs on one thread, as a profile on an H200
  found (docs/performance.md, "On a GPU").

The counts come from a second pass over the same number of steps, run without the
profiler (the profiler syncs after every task).

A weakly compressible step is one launch (``mrsph/sph/step.py``), so its tasks are named
``_fused_..._kernel_K``; ``--by-phase`` steps pass by pass instead, as ``bench``'s
profiled interval does, so that each task carries its pass's kernel name (``run``,
``timestep``, ...), at the cost of the launches the fused step saves.
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def count_calls(step, steps: int) -> collections.Counter:
    """Python's calls into Taichi during ``steps`` calls of ``step()``, by name."""
    from taichi.lang import kernel_impl
    from taichi.lang.field import ScalarField
    from taichi.lang.matrix import MatrixField

    calls = collections.Counter()
    patched = []

    def wrap(owner, attr, name_of):
        original = getattr(owner, attr)

        def counted(self, *a, **k):
            calls[name_of(self)] += 1
            return original(self, *a, **k)

        setattr(owner, attr, counted)
        patched.append((owner, attr, original))

    wrap(kernel_impl.Kernel, "__call__", lambda k: k.func.__qualname__)
    for cls in (ScalarField, MatrixField):
        wrap(cls, "__getitem__", lambda f, c=cls: f"{c.__name__} read from Python")
        wrap(cls, "__setitem__", lambda f, c=cls: f"{c.__name__} written from Python")
    try:
        for _ in range(steps):
            step()
    finally:
        for owner, attr, original in reversed(patched):
            setattr(owner, attr, original)
    return calls


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python3 tools/step_profile.py", description=__doc__.splitlines()[0])
    ap.add_argument("scene", help="a scene name or a .toml path")
    ap.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", dest="overrides", help="scene override (repeatable)"
    )
    ap.add_argument("--arch", default="cpu", choices=("cpu", "gpu"), help="Taichi backend")
    ap.add_argument("--threads", type=int, default=1, help="CPU threads (default 1, pinned)")
    ap.add_argument("--warm", type=int, default=50, help="steps before the profiled ones")
    ap.add_argument("--steps", type=int, default=50, help="profiled steps (and counted ones)")
    ap.add_argument("--top", type=int, default=25, help="tasks listed")
    ap.add_argument(
        "--by-phase", action="store_true", help="step phase by phase (each phase's own kernels), not as one launch"
    )
    args = ap.parse_args(argv)
    if min(args.warm, args.steps - 1, args.top - 1, args.threads - 1) < 0:
        ap.error("--warm must be >= 0, and --steps, --top and --threads >= 1")

    os.environ["TI_KERNEL_PROFILER"] = "1"  # read by the ti.init that Simulation makes
    import taichi as ti

    from mrsph.scene.config import SceneError, load_scene
    from mrsph.simulation import Simulation

    try:
        scene = load_scene(args.scene, args.overrides)
    except SceneError as e:
        for line in e.problems:
            print(f"step_profile: {line}", file=sys.stderr)
        return 2
    sim = Simulation(scene, arch=args.arch, threads=args.threads, profile=args.by_phase)
    print(
        f"{' '.join([scene.name] + args.overrides)}: {sim.stats()['n_real']} real particles, "
        f"arch {sim.arch_name}, solver {scene.params.fluid.solver}"
        f"{', phase by phase' if args.by_phase else ''}",
        flush=True,
    )
    for _ in range(args.warm):
        sim.step()
    ti.sync()
    ti.profiler.clear_kernel_profiler_info()
    t0, start = time.perf_counter(), sim.time
    for _ in range(args.steps):
        sim.step()
    ti.sync()
    wall = time.perf_counter() - t0
    print(
        f"{args.steps} profiled steps from t = {start:.4g} s: {1e3 * wall / args.steps:.3f} ms a step "
        f"with the profiler's syncs"
    )
    tasks = _tasks()
    total = sum(t for t, _ in tasks.values())
    print(f"\ntasks, by total time over the {args.steps} steps ({total:.4f} s in all):")
    print(f"{'ms a step':>10} {'launches a step':>16} {'mean ms':>8}  task")
    for name, (total, count) in sorted(tasks.items(), key=lambda kv: -kv[1][0])[: args.top]:
        print(f"{1e3 * total / args.steps:10.3f} {count / args.steps:16.2f} {1e3 * total / count:8.3f}  {name}")
    calls = count_calls(sim.step, args.steps)
    print(f"\ncalls from Python into Taichi: {sum(calls.values()) / args.steps:.1f} a step")
    for name, n in calls.most_common():
        print(f"{n / args.steps:8.2f}  {name}")
    return 0


def _tasks() -> dict:
    """{task name: (total seconds, launches)} since the profiler was last cleared. Read
    from the default profiler's per-name statistics, which ``get_total_time`` fills
    (taichi 1.7 has no public call that returns them)."""
    from taichi.profiler.kernel_profiler import get_default_kernel_profiler

    prof = get_default_kernel_profiler()
    prof.get_total_time()
    return {name: (st.total_time / 1e3, st.counter) for name, st in prof._statistical_results.items()}


if __name__ == "__main__":
    sys.exit(main())

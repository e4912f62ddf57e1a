"""``python3 main.py bench``: how fast mrsph runs, and where the time goes.

The package: ``cases.py`` (what is timed), ``runs.py`` (a scene, a pair), ``demo.py``
(the demos, rendered), ``report.py`` (the table), and the command here.

Every case builds its scene in a fresh Taichi program and takes one step, which
compiles every kernel of the step (kernels come from Taichi's offline cache when an
earlier run compiled them); that is the compile time, reported on its own. It then runs
a warm-up, times a fixed simulated interval ``repeats`` times in a row and reports
medians: real, virtual and per-level particles, steps per second, particle-steps per
second (real particles × steps / wall seconds), simulated seconds per wall second, the
share of step time per phase (measured with a device sync around each phase, in one
extra profiled interval, so that the timed runs carry no sync overhead), the resident
memory at the end of the case and the peak resident memory of the process.

Three kinds of case:

- **run**: one scene (the uniform dam breaks).
- **pair**: an adaptive scene run twice at the same finest spacing, once adaptive and
  once uniform (``adaptivity.enabled = false`` puts every particle at
  ``particles.spacing``, the finest level's spacing), each timed on the same simulated
  intervals after the same warm-up, turn about from their saved warm states (so that the
  machine's slow spells fall on both). The pair line gives the speed-up (uniform wall time /
  adaptive wall time), the particle ratio (uniform real particles / adaptive real
  particles), the step ratio (adaptive steps / uniform steps: the time step follows the
  finest level, but the flows differ) and the share of the adaptive run's step time taken
  by the multiresolution phases (adapt, virtual_coupling, virtual_advect).
- **demo**: a demo scene from t = 0 over ``interval`` simulated seconds (its opening
  stir included), each repeat from a reset: first the simulation alone, frame after
  frame (its simulated seconds per wall second), then rendered offscreen by the app's
  frame source (GGUI when Vulkan works, else the numpy rasteriser) in real time, as a
  window keeping up with the clock would run it: each frame advances by the wall time
  the last one took (at most ``REAL_TIME_CAP_S``, and within the window's frame budget),
  is snapshotted and drawn; it reports rendered frames per second and the pace
  (simulated seconds per wall second) of that, and the finest spacing next to the
  spacing of a 10k-particle uniform run of the same fluid volume. Then the water view's
  cost as the interactive window pays it: frames advanced by the window's default frame
  budget and drawn with the water view, the surface's own time and its share of such a
  frame (at most a quarter is the aim).

Every row also counts the neighbour passes (loops over every particle's neighbours) a
step makes (``Simulation.neighbour_passes``) and so per simulated and per wall second.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from .cases import DEMO_REFERENCE_PARTICLES, KINDS, MULTIRES_PHASES, UNIFORM_OVERRIDE, Case, _cases
from .demo import run_demo
from .report import _table, advanced_optimization, gpu_name
from .runs import fluid_volume, pair_summary, run_case, run_pair, solve_iterations

__all__ = [
    "DEMO_REFERENCE_PARTICLES", "KINDS", "MULTIRES_PHASES", "UNIFORM_OVERRIDE", "Case", "_cases", "_table",
    "advanced_optimization", "fluid_volume", "gpu_name", "main", "pair_summary", "run_case", "run_cases",
    "run_demo", "run_pair", "solve_iterations",
]  # fmt: skip


def _scene_problems(cases) -> list[str]:
    """Every problem of the cases' scenes with their overrides, once each (none: [])."""
    from mrsph.scene.config import SceneError, load_scene

    problems = []
    for c in cases:
        try:
            load_scene(c.scene, list(c.overrides))
        except SceneError as e:  # a bad --set is the same problem in every case
            problems += [line for line in e.problems if line not in problems]
    return problems


def run_cases(cases, repeats, arch, threads="auto", log=None) -> tuple[list, list]:
    """Run cases in order: (rows, pair summaries)."""
    rows, pairs = [], []
    for c in cases:
        if log:
            log(f"running {c.name} ({c.kind}) ...")
        args = (c.name, c.scene, c.overrides, c.warm, c.interval, repeats, arch, threads)
        if c.kind == "pair":
            pair_rows, summary = run_pair(*args)
            rows += pair_rows
            pairs.append(summary)
        elif c.kind == "demo":
            rows.append(run_demo(*args))
        else:
            rows.append(run_case(*args))
    return rows, pairs


def main(argv=None) -> int:
    from ..options import HelpFormatter, Parser, file_problem, positive_float, positive_int, threads_arg

    ap = Parser(
        prog="python3 main.py bench",
        description=__doc__.splitlines()[0].replace("``", ""),
        formatter_class=HelpFormatter,
    )
    ap.add_argument(
        "--full", action="store_true", help="the long set: adds 50k 2D and 100k 3D dam breaks and finer pairs"
    )
    ap.add_argument("--repeats", type=positive_int, default=3, help="timed runs per case (median)")
    ap.add_argument("--arch", default="cpu", choices=("auto", "cpu", "gpu"), help="Taichi backend")
    ap.add_argument(
        "--threads",
        type=threads_arg,
        default="auto",
        help="CPU threads for the cpu backend (default auto: as the app, one pinned "
        "thread for scenes that start under 12k particles in 2D, 4k in 3D, else all cores)",
    )
    ap.add_argument(
        "--interval-scale",
        type=positive_float,
        default=1.0,
        metavar="F",
        help="multiply every warm-up and timed interval by F (0.05: a smoke run)",
    )
    ap.add_argument("--json", metavar="FILE", help="also write the results as JSON (default: no file)")
    ap.add_argument(
        "--case",
        action="append",
        default=None,
        help="run only cases whose name contains this text (repeatable; default: all)",
    )
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        dest="overrides",
        help="a scene override added to every chosen case, after the case's own "
        "(repeatable), e.g. --set 'fluid.solver=\"dfsph\"' (default: none)",
    )
    ap.add_argument("--list", action="store_true", help="list the cases (those --case chooses) and exit")
    args = ap.parse_args(argv)
    cases = [c for c in _cases(args.full) if not args.case or any(t in c.name for t in args.case)]
    if args.list and cases:
        for c in cases:
            print(f"{c.name:40s} {c.kind:5s} {c.scene} {' '.join(c.overrides)}")
        return 0
    if not cases:
        print(
            f"python3 main.py bench: no case matches {args.case} (see --list{'' if args.full else ' and --full'})",
            file=sys.stderr,
        )
        return 2
    problem = file_problem("--json", Path(args.json)) if args.json else None
    if problem:  # before the cases run, not after
        print(f"python3 main.py bench: {problem}", file=sys.stderr)
        return 2
    scale = args.interval_scale
    cases = [
        c._replace(warm=c.warm * scale, interval=c.interval * scale, overrides=c.overrides + tuple(args.overrides))
        for c in cases
    ]
    problems = _scene_problems(cases)
    if problems:  # a bad --set, found before the first case compiles
        for line in problems:
            print(f"python3 main.py bench: {line}", file=sys.stderr)
        return 2
    optimised = advanced_optimization()
    if not optimised:  # the default test run sets it (tests/conftest.py)
        print(
            "python3 main.py bench: warning: TI_ADVANCED_OPTIMIZATION=0: Taichi compiles "
            "without its optimisation passes, so these timings are not the program's",
            file=sys.stderr,
        )
    rows, pairs = run_cases(
        cases, args.repeats, args.arch, args.threads, log=lambda m: print(m, file=sys.stderr, flush=True)
    )
    print(_table(rows, pairs))
    if args.json:
        import platform

        with open(args.json, "w") as fh:
            json.dump(
                {
                    "machine": platform.processor() or platform.machine(),
                    "cpus": os.cpu_count(),
                    "gpu": gpu_name({r["arch"] for r in rows}),
                    "arch": args.arch,
                    "threads": args.threads,
                    "repeats": args.repeats,
                    "interval_scale": scale,
                    "overrides": args.overrides,
                    "advanced_optimization": optimised,
                    "cases": rows,
                    "pairs": pairs,
                },
                fh,
                indent=2,
            )
    return 0

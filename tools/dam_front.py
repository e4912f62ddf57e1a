"""The adaptive dam break's front against the uniform run's, over perturbed settings.

    python3 tools/dam_front.py --dim 3                          # the test's settings
    python3 tools/dam_front.py --dim 3 --viscosity 0.97,1,1.03 --cfl 0.18,0.2,0.22
    python3 tools/dam_front.py --dim 2 --set adaptivity.release_factor=0.8 --uniform
    python3 tools/dam_front.py --dim 3 --solver dfsph --cfl 0.36,0.4,0.44 --uniform
    python3 tools/dam_front.py --dim 2 --solver pbf --cfl 16,18,20,22,24 --uniform

The scene is the one ``tests/test_adaptive_flow.py`` checks (``refined_dam``: a dam break
in a long tank, two levels, 1 and 2 cm, refined within 3 cm of a low block; the earlier
three-level scene is ``--set adaptivity.levels=3 --set criteria.0.distance=0.1 --set
adaptivity.band=0 --set adaptivity.merge_remnants=false``), and so is the front
(``body_front``: the largest x of the connected bodies holding at least 5 % of the mass).
Each combination of a viscosity factor and a CFL number runs in its own process, ``--jobs``
at a time, one core each. Without ``--uniform`` the error is taken against the uniform
fronts measured at the test's own settings (:data:`UNIFORM_FRONT`); the uniform runs move
by about 1 cm over these perturbations, which ``--uniform`` measures
(it runs each uniform twin too: about 90 s each in 3D on one core).

Why a tool: a single run says little. The front at 1 s spreads by several per cent over
viscosities and CFL numbers a few per cent apart, so a change is judged over several of
them (docs/validation.md, "Adaptive dam break against uniform").
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# Uniform fronts at 1 s at the test's settings (viscosity x1, the solver's default CFL
# number: physics.cfl 0.2, dfsph.cfl 0.4, pbf.substeps 20), in m.
UNIFORM_FRONT = {
    ("wcsph", 2): 1.556,
    ("wcsph", 3): 1.578,
    ("dfsph", 2): 1.581,
    ("dfsph", 3): 1.589,
    ("pbf", 2): 1.735,
}
# The key --cfl sets, and its default, per solver: pbf's step is tied to the frame, so its
# "CFL number" is its steps a frame (an int); its viscosity is XSPH's, so --viscosity,
# which scales fluid.viscosity, does not reach it.
CFL_KEY = {"wcsph": ("physics.cfl", 0.2), "dfsph": ("dfsph.cfl", 0.4), "pbf": ("pbf.substeps", 20)}


def _floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers separated by commas, got {text!r}") from None


def run_one(dim: int, solver: str, viscosity: float, cfl: float, sets: list[str], uniform: bool) -> dict:
    """One run in this process: fronts at the test's early time and at 1 s."""
    sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
    import numpy as np
    import test_adaptive_flow as flow

    from mrsph.scene.config import load_scene
    from mrsph.simulation import Simulation

    raw = flow.refined_dam(dim)
    raw["fluid"]["viscosity"] *= viscosity
    raw["fluid"]["solver"] = solver
    if uniform:
        raw = flow.uniform(raw)
    value = int(cfl) if solver == "pbf" else cfl
    scene = load_scene(raw, [f"{CFL_KEY[solver][0]}={value}", *sets])
    sim = Simulation(scene, arch="cpu", threads=1)
    out = {"dim": dim, "solver": solver, "viscosity": viscosity, "cfl": cfl, "uniform": uniform}
    counts = []
    start = time.perf_counter()
    while sim.time < flow.DAM_T - 1e-9:
        sim.advance(0.05)
        counts.append(sim.stats()["n_real"])
        if "early" not in out and sim.time > flow.EARLY_T - 1e-9:
            out["early"] = flow.body_front(sim.particles(virtual=False), sim.h0)
    out["front"] = flow.body_front(sim.particles(virtual=False), sim.h0)
    out["mean_real"] = float(np.mean(counts))
    out["wall_s"] = time.perf_counter() - start
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--dim", type=int, choices=(2, 3), required=True)
    ap.add_argument(
        "--viscosity", type=_floats, default=[1.0], help="factors on the test's viscosity, comma-separated (default 1)"
    )
    ap.add_argument("--solver", choices=tuple(CFL_KEY), default="wcsph", help="fluid.solver (default wcsph)")
    ap.add_argument(
        "--cfl",
        type=_floats,
        help="CFL numbers, comma-separated: physics.cfl with wcsph, dfsph.cfl with "
        "dfsph, pbf.substeps with pbf (default the solver's own, 0.2, 0.4 or 20, as the test runs)",
    )
    ap.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a scene override, as on the command line (repeatable)",
    )
    ap.add_argument("--uniform", action="store_true", help="also run each uniform twin and compare with it")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--one", help=argparse.SUPPRESS)  # a worker: JSON arguments
    args = ap.parse_args(argv)

    if args.one:
        sys.path.insert(0, str(ROOT))
        from mrsph.scene.config import SceneError

        try:
            print(json.dumps(run_one(**json.loads(args.one))), flush=True)
        except SceneError as e:
            print(e, file=sys.stderr)
            return 2
        return 0

    args.cfl = args.cfl or [CFL_KEY[args.solver][1]]
    jobs = [
        dict(dim=args.dim, solver=args.solver, viscosity=v, cfl=c, sets=args.sets, uniform=u)
        for v, c in itertools.product(args.viscosity, args.cfl)
        for u in ((False, True) if args.uniform else (False,))
    ]
    results, running, core = [], [], 0
    while jobs or running:
        while jobs and len(running) < max(1, args.jobs):
            job = jobs.pop(0)
            cmd = [sys.executable, __file__, "--dim", str(args.dim), "--one", json.dumps(job)]
            if hasattr(os, "sched_setaffinity") and args.jobs > 1:
                cmd = ["taskset", "-c", str(core % (os.cpu_count() or 1)), *cmd]
                core += 1
            running.append((job, subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)))
        job, proc = running.pop(0)
        stdout, stderr = proc.communicate()
        if proc.returncode != 0:
            last = (stderr.strip().splitlines() or ["no output"])[-1]
            print(f"error: viscosity x{job['viscosity']} cfl {job['cfl']}: {last}", file=sys.stderr)
            return 1
        results.append(json.loads(stdout.strip().splitlines()[-1]))

    ref = {(r["viscosity"], r["cfl"]): r["front"] for r in results if r["uniform"]}
    errors = []
    print("viscosity  cfl    front 0.4 s  front 1 s  uniform   error   real particles")
    for r in sorted((r for r in results if not r["uniform"]), key=lambda r: (r["viscosity"], r["cfl"])):
        u = ref.get((r["viscosity"], r["cfl"]), UNIFORM_FRONT[args.solver, args.dim])
        err = 100 * (r["front"] / u - 1)
        errors.append(err)
        print(
            f"x{r['viscosity']:<8g} {r['cfl']:<6g} {r['early']:9.3f} m {r['front']:8.3f} m "
            f"{u:7.3f} m {err:+6.1f} %  {r['mean_real']:8.0f}"
        )
    source = "its uniform twin" if args.uniform else f"{UNIFORM_FRONT[args.solver, args.dim]} m (test settings)"
    print(
        f"{args.dim}D {args.solver}, {len(errors)} runs against {source}: mean {sum(errors) / len(errors):+.1f} %, "
        f"{min(errors):+.1f} .. {max(errors):+.1f} %, {sum(abs(e) > 5 for e in errors)} beyond 5 %"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""How still the resting tank of ``tests/test_physics.py`` settles, over nudged settings.

    python3 tools/tank_rest.py --dim 2                               # the test's run, dfsph
    python3 tools/tank_rest.py --dim 3 --set dfsph.correction_time=0.003 --nudge
    python3 tools/tank_rest.py --dim 2 --solver wcsph

The scene is the test's (``tank_scene``: 0.3 m of water at rest in a 0.3 m tank, 2 cm
particles in 2D, 3 cm in 3D), and so is the measure: the real particles' mean speed,
sampled every 2 ms over 0.3 s after 1.5 s of settling, over √(gH) (the test asks for at
most 0.01). It advances by ``sim.advance`` where the test steps one step at a time to
read every stats row, so its float sequence, and a run's reading, may differ from the
test's own run; what it is for is the spread over runs. ``--nudge`` adds four runs with one key moved by about round-off
(``fluid.viscosity`` ×0.99 and ×1.01, ``dfsph.density_tolerance`` ×0.99 and ×1.01):
under dfsph one run lands on either side of the bound as its float sequence falls
(docs/validation.md, "Resting tank"), so a change is judged over several.
One thread, one run after another, about 10 s each in 2D and 15 s in 3D.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
for _path in (ROOT, ROOT / "tests"):  # mrsph, and the test's scene (test_physics)
    if str(_path) not in sys.path:
        sys.path.insert(0, str(_path))

#: one key moved by about round-off a run (``--nudge``): (key, factor on the test's value)
NUDGES = (
    ("fluid.viscosity", 0.99),
    ("fluid.viscosity", 1.01),
    ("dfsph.density_tolerance", 0.99),
    ("dfsph.density_tolerance", 1.01),
)


def settle(dim: int, solver: str, sets: list[str]) -> float:
    """The test's tank with ``sets`` on top: its settled mean speed over √(gH)."""
    import numpy as np
    import test_physics as tp
    from scenekit import with_solver

    from mrsph.scene.config import load_scene
    from mrsph.simulation import Simulation

    sim = Simulation(load_scene(with_solver(tp.tank_scene(dim), solver), sets), arch="cpu", threads=1)
    sim.advance(tp.SETTLE_S)
    speeds = []
    for _ in range(int(round(tp.MEASURE_S / tp.SAMPLE_S))):
        sim.advance(tp.SAMPLE_S)
        v = sim.particles(virtual=False)["v"].astype(np.float64)
        speeds.append(float(np.linalg.norm(v, axis=1).mean()))
    return float(np.mean(speeds)) / math.sqrt(tp.G * tp.TANK_H)


def nudged(dim: int, solver: str, sets: list[str]) -> list[list[str]]:
    """``sets``, then with each of :data:`NUDGES` on top (the key's value as ``sets`` or the
    scene leaves it)."""
    import test_physics as tp
    from scenekit import with_solver

    from mrsph.scene.config import load_scene

    scene = load_scene(with_solver(tp.tank_scene(dim), solver), sets)
    runs = [sets]
    for key, factor in NUDGES:
        table, name = key.split(".")
        runs.append(sets + [f"{key}={scene[table][name] * factor!r}"])
    return runs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    ap.add_argument("--dim", type=int, choices=(2, 3), default=2)
    ap.add_argument("--solver", choices=("dfsph", "wcsph"), default="dfsph")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        dest="sets",
        help="override a key of the test's scene (repeatable)",
    )
    ap.add_argument("--nudge", action="store_true", help="also run with one key moved by about round-off, four runs")
    args = ap.parse_args(argv)
    from mrsph.scene.config import SceneError

    try:
        runs = nudged(args.dim, args.solver, args.sets) if args.nudge else [args.sets]
        for sets in runs:
            t0 = time.perf_counter()
            ratio = settle(args.dim, args.solver, sets)
            label = " ".join(sets) or "(the test's scene)"
            print(
                f"{args.dim}D {args.solver} {label}: mean speed "
                f"{ratio:.4f} sqrt(gH) ({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
    except SceneError as e:
        for msg in e.problems:
            print(msg, file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

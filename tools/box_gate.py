"""MARIN's box with its reservoir released by a gate lifted from the floor, beside the same box
released at once: does the way the reservoir opens move the water's arrival behind the box?

    python3 tools/box_gate.py --quick --gate 2            # 14 layers: about 3 min
    python3 tools/box_gate.py --gate 1,2,3 --jobs 2       # 27 layers (the scene), wcsph: about 12 min

The experiment lifted a gate; tools/validate.py's box (scenes/dam_break_box_3d) releases its
reservoir at once. In 2D (tools/marin_approach.py) a gate thins the stream before the box as
the data's is thin. This runs the 3D box, uniform, with the reservoir held behind a plate four
spacings thick, across the tank and from floor to lid, that lifts at each ``--gate`` speed from
t = 0, and once released at once; and prints for H1-H3 when the water first stands 2 cm (the
validation's arrival) and 6 cm (a probe's body), H3's mean depth over ``H3_WINDOW``, and the
one clock shift that best fits H3 and H4 to MARIN's (``marin_approach.clock_fit``: a gate
whose opening the experiment's clock started during), with H1's times moved by it. One
thread a run.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
for p in (ROOT, ROOT / "tools"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

LAYERS_QUICK = 14
HEIGHTS = (0.02, 0.06)  # m: the arrival and the body
UNTIL = 1.5  # s: as the validation's box runs
#: s: the clock shifts searched; a slow gate holds the 3D stream back by more than the 2D one
SHIFTS = (-0.25, 0.1, 0.0025)


def scene_with_gate(solver: str, quick: bool, sets: list[str], gate: float | None):
    """The box scene, uniform; with ``gate`` (m/s) a plate against the reservoir's face, its last obstacle."""
    import tomllib

    import validate as V

    from mrsph.scene.config import load_scene, resolve_scene_path

    spacing = 0.55 / LAYERS_QUICK if quick else V.scene_spacing("box", 3)
    over = [f'fluid.solver="{solver}"', "adaptivity.enabled=false", f"particles.spacing={spacing!r}", *sets]
    data = tomllib.loads(resolve_scene_path(V.SCENES["box"]).read_text())
    if gate is not None:
        face, (_, lid, width) = data["fluid"]["blocks"][0]["min"][0], data["domain"]["max"]
        plate = {"shape": "box", "min": [face - 4.0 * spacing, 0.0, 0.0], "max": [face, lid, width]}
        data["obstacles"] = [*data.get("obstacles", []), plate]
    return load_scene(data, over)


def run(solver: str, quick: bool, sets: list[str], gate: float | None) -> dict:
    """One run: H1-H4 every 2 ms to ``UNTIL``; the gate, if any, moved every 1 ms."""
    import marin_approach as M
    import numpy as np
    import validate as V
    import validate_report as R

    from mrsph.simulation import Simulation

    scene = scene_with_gate(solver, quick, sets, gate)
    sim = Simulation(scene, arch="cpu", threads=1)
    k = len(scene.data["obstacles"]) - 1
    lid = float(scene.data["domain"]["max"][1])
    zc = 0.5 * float(scene.data["domain"]["max"][2])
    t, levels = [0.0], [[0.0, 0.0, 0.0, V.box_reservoir()[1]]]
    while sim.time < UNTIL - 1e-9:
        for _ in range(2):  # 1-3 mm a move at 1-3 m/s, under a tenth of a 20 mm spacing
            if gate is not None:
                M.lift(sim.boundary, scene.data["obstacles"][k], k, min(gate * sim.time, 0.99 * lid))
            sim.advance(0.001)
        r = V._real(sim)
        t.append(sim.time)
        levels.append([V.water_level(r["x"], r["vol"], r["h"], (px, zc), 0.8) for px in V.PROBES])
    t, levels = np.array(t), np.array(levels).T
    return {
        "gate": gate,
        "first": [R.rise(t, levels[p], HEIGHTS) for p in range(3)],
        "depth": R.h3_depth(t, levels[2]),
        "fit": M.clock_fit(t, levels[2], levels[3], SHIFTS),
        "n": sim.stats()["n_real"],
        "steps": sim.steps,
    }


def _fmt(v: float | None) -> str:
    return "  —  " if v is None else f"{v:.3f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--gate", default="2", help="lift speeds (m/s), comma-separated; a run released at once is added")
    ap.add_argument("--solver", default="wcsph")
    ap.add_argument("--quick", action="store_true", help=f"{LAYERS_QUICK} layers instead of the scene's 27")
    ap.add_argument("--jobs", type=int, default=1, help="runs at a time, one thread each")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE", help="a scene override")
    args = ap.parse_args(argv)
    import validate_report as R

    from mrsph.scene.config import SceneError

    try:
        gates = [float(v) for v in args.gate.split(",")]
    except ValueError:
        gates = [0.0]
    if not all(0.0 < g < float("inf") for g in gates) or args.jobs < 1:
        print(
            f"box_gate.py: --gate {args.gate!r} --jobs {args.jobs}: expected speeds > 0 (m/s), "
            "comma-separated, and at least one job",
            file=sys.stderr,
        )
        return 2
    try:
        scene_with_gate(args.solver, args.quick, args.sets, gates[0])  # a bad --set fails here, at once
    except SceneError as e:
        for msg in e.problems:
            print(msg, file=sys.stderr)
        return 2
    with ProcessPoolExecutor(args.jobs) as pool:
        futures = [pool.submit(run, args.solver, args.quick, args.sets, g) for g in (None, *gates)]
        runs = [f.result() for f in futures]

    exp = R.marin()
    ref = [R.rise(exp["t"], exp[name], HEIGHTS) for name in ("H1", "H2", "H3")]
    head = "".join(f"  {p} 2 cm  6 cm" for p in ("H1", "H2", "H3"))
    print(f"first 2 and 6 cm (s){head}   H3 depth   clock shift: H1 2 cm  6 cm   RMS H3, H4 (m)")
    print(f"  {'MARIN (Kleefsman et al. 2005)':34s}" + "".join(f"  {_fmt(a)} {_fmt(b)}" for a, b in ref), end="")
    print(f"   {R.h3_depth(exp['t'], exp['H3']):.4f}")
    layers = LAYERS_QUICK if args.quick else 27
    for r in runs:
        name = f"{args.solver}, {layers} layers, " + ("at once" if r["gate"] is None else f"gate {r['gate']:g} m/s")
        fit = r["fit"]
        moved = [None if v is None else v + fit["shift"] for v in r["first"][0]]
        print(
            f"  {name:34s}"
            + "".join(f"  {_fmt(a)} {_fmt(b)}" for a, b in r["first"])
            + f"   {r['depth']:.4f}   {fit['shift']:+.4f}: {_fmt(moved[0])} {_fmt(moved[1])}"
            + "   {H3:.4f}, {H4:.4f}".format(**fit["shifted"])
            + f"   ({r['n']} particles, {r['steps']} steps)"
            + (" the shift at the search's edge" if min(abs(fit["shift"] - e) for e in SHIFTS[:2]) < 1e-9 else "")
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

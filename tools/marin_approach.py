"""MARIN's dam break before the box: the stream along the tank's centre line, in 2D.

    python3 tools/marin_approach.py                              # wcsph at 27, 55 and 110 layers: about 2 min
    python3 tools/marin_approach.py --layers 220                 # about 12 min
    python3 tools/marin_approach.py --layers 55 --gate 2,4       # the reservoir held by a gate lifted at 2 and 4 m/s
    python3 tools/marin_approach.py --solver dfsph --layers 55   # any solver

Until the water piled against the box comes back, the flow at H3 (0.50 m from the reservoir)
does not know the box is there, and the tank is 1 m wide and the reservoir fills it, so the
flow there is the 2D dam break along the centre line. This tool runs that 2D section of
tools/validate.py's box scene (scenes/dam_break_box_3d: its tank, reservoir, fluid and time
step, without the box) to 0.8 s at finer spacings than the 3D case can afford, and prints at
H3 what validate.py's report reads: its mean height over ``H3_WINDOW`` and when its water
first stands 5 mm, 2 cm (the arrival) and 6 cm (the body), against MARIN's and against
Ritter's ideal dam break; then the RMS of H3 (to 0.7 s) and of the reservoir's level H4 (to
0.8 s) against MARIN's, as run and moved by the clock shift that fits them best. With
``--gate`` the reservoir starts behind a plate four spacings thick that lifts at that speed
from t = 0, as a real gate opens from below. Uniform, one thread.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
for p in (ROOT, ROOT / "tools"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

#: heights (m) at which H3's first time is printed: the leading film, the arrival, the body
HEIGHTS = (0.005, 0.02, 0.06)
UNTIL = 0.9  # s: past H3_WINDOW, and H4's span by the largest clock shift searched


def section(spacing: float, solver: str, sets: list[str], gate: float | None):
    """The box scene cut along its centre line, loaded as a 2D scene without the box; with
    ``gate`` (m/s) a plate four spacings thick against the reservoir's face, floor to lid."""
    import validate as V

    from mrsph.scene.config import load_scene

    data = load_scene(V.SCENES["box"]).data
    dom, block = data["domain"], data["fluid"]["blocks"][0]
    fluid = {k: data["fluid"][k] for k in ("viscosity", "stiffness")}
    fluid["solver"] = solver
    fluid["blocks"] = [{"min": block["min"][:2], "max": block["max"][:2]}]
    out = {
        "description": "MARIN's tank along its centre line, without the box (tools/marin_approach.py)",
        "dim": 2,
        "domain": {"min": dom["min"][:2], "max": dom["max"][:2]},
        "particles": {"spacing": spacing},
        "fluid": fluid,
        "pbf": data["pbf"],
        "run": {"fps": 50, "frames": round(UNTIL * 50)},
    }
    if gate is not None:
        face, lid = block["min"][0], dom["max"][1]
        out["obstacles"] = [{"shape": "box", "min": [face - 4.0 * spacing, 0.0], "max": [face, lid]}]
    return load_scene(out, sets)


def approach(spacing: float, solver: str, sets: list[str], gate: float | None) -> dict:
    """One run: H3's height every 2 ms to ``UNTIL``; its mean over H3_WINDOW and first times."""
    import numpy as np
    import validate as V
    import validate_report as R

    from mrsph.simulation import Simulation

    scene = section(spacing, solver, sets, gate)
    sim = Simulation(scene, arch="cpu", threads=1)
    block = scene.data["fluid"]["blocks"][0]
    t, h3, h4 = [0.0], [0.0], [float(block["max"][1])]
    lid = float(scene.data["domain"]["max"][1])
    while sim.time < UNTIL - 1e-9:
        for _ in range(2):  # the gate moves every 1 ms: 4 mm a move at 4 m/s, under a 10 mm spacing
            if gate is not None:
                lift(sim.boundary, scene.data["obstacles"][0], 0, min(gate * sim.time, 0.99 * lid))
            sim.advance(0.001)
        r = V._real(sim)
        t.append(sim.time)
        h3.append(V.water_level(r["x"], r["vol"], r["h"], (V.PROBES[2],), 0.8))
        h4.append(V.water_level(r["x"], r["vol"], r["h"], (V.PROBES[3],), 0.8))
    t, h3, h4 = np.array(t), np.array(h3), np.array(h4)
    return {
        "depth": R.h3_depth(t, h3),
        "first": [V.first_crossing(t, h3, h) for h in HEIGHTS],
        "fit": clock_fit(t, h3, h4),
        "steps": sim.steps,
        "n": sim.stats()["n_real"],
    }


#: s: the clock shifts searched, and the spans over which H3 and H4 are compared with the data
SHIFTS = (-0.1, 0.1, 0.0025)
SPANS = {"H3": (0.0, 0.7), "H4": (0.0, 0.8)}


def clock_fit(t, h3, h4, search: tuple = SHIFTS) -> dict:
    """The RMS (m) of H3 and H4 against the data's over ``SPANS``, as run and with the run moved
    by the one shift (s; negative: earlier) that makes their sum least: a gate that opens over
    a time, with the experiment's clock started during it, would show as a better fit shifted.
    ``search``: the first and last shifts tried and the step between them."""
    import numpy as np
    import validate as V

    exp = V.read_csv(V.DATA / "kleefsman_2005_heights.csv")

    def rms(shift):
        out = {}
        for name, run in (("H3", h3), ("H4", h4)):
            lo, hi = SPANS[name]
            span = (exp["t"] >= lo) & (exp["t"] <= hi)
            te, ref = exp["t"][span], exp[name][span]
            inside = te - shift <= t[-1]  # past the run's end np.interp would hold its last value
            out[name] = float(np.sqrt(np.mean((np.interp(te[inside] - shift, t, run) - ref[inside]) ** 2)))
        return out

    shifts = np.arange(search[0], search[1] + 1e-9, search[2])
    best = min(shifts, key=lambda s: sum(rms(s).values()))
    return {"as_run": rms(0.0), "shift": float(best), "shifted": rms(best)}


def lift(boundary, plate: dict, k: int, bottom: float) -> None:
    """Obstacle ``k``, ``plate`` as its scene gives it (a box from floor to lid), with its lower
    edge at ``bottom`` m: its foot no longer on the floor, so a particle under it is pushed out
    downwards as through any other face. Any dimension."""
    import numpy as np

    lo, hi = np.array(plate["min"], dtype=float), np.array(plate["max"], dtype=float)
    lo[1] = bottom
    boundary.box_c[k] = ((lo + hi) / 2).tolist()
    boundary.box_half[k] = ((hi - lo) / 2).tolist()
    if bottom > 0.0:
        shut = [int(v) for v in boundary.box_shut_lo[k]]
        shut[1] = 0
        boundary.box_shut_lo[k] = shut


def reference() -> list[tuple[str, float, list]]:
    """MARIN's H3 and Ritter's at its place: (name, mean height, first times)."""
    import numpy as np
    import validate as V
    import validate_report as R

    exp = R.marin()
    gate, depth = V.box_reservoir()
    t = np.arange(0.001, UNTIL, 0.001)
    ritter = V.ritter_depth(gate - V.PROBES[2], t, depth)
    return [
        ("MARIN (Kleefsman et al. 2005)", R.h3_depth(exp["t"], exp["H3"]), R.rise(exp["t"], exp["H3"], HEIGHTS)),
        ("Ritter (ideal, shallow water)", R.h3_ritter(), R.rise(t, ritter, HEIGHTS)),
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--layers", default="27,55,110", help="the reservoir's depth in spacings, comma-separated")
    ap.add_argument("--solver", default="wcsph")
    ap.add_argument("--gate", default="", help="lift speeds (m/s), comma-separated; none: released at once")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE", help="a scene override")
    args = ap.parse_args(argv)
    import validate as V

    from mrsph.scene.config import SceneError

    try:
        layers = [int(n) for n in args.layers.split(",")]
        gates = [float(v) for v in args.gate.split(",")] if args.gate else [None]
    except ValueError:
        layers, gates = [0], [None]
    if min(layers) < 1 or not all(g is None or 0.0 < g < float("inf") for g in gates):
        print(
            f"marin_approach.py: --layers {args.layers!r} --gate {args.gate!r}: "
            "expected whole numbers >= 1 and speeds > 0 (m/s), comma-separated",
            file=sys.stderr,
        )
        return 2
    _, depth = V.box_reservoir()
    lo, hi = V.H3_WINDOW
    print(
        f"H3, x = {V.PROBES[2]} m: mean height over {lo:g}-{hi:g} s (m), first at "
        + ", ".join(f"{100 * h:g} cm" for h in HEIGHTS)
        + " (s)"
    )
    for name, mean, first in reference():
        print(f"  {name:34s} {mean:.4f}  " + "  ".join(f"{f:.3f}" for f in first))
    for gate in gates:
        for n in layers:
            try:
                r = approach(depth / n, args.solver, args.sets, gate)
            except SceneError as e:
                for msg in e.problems:
                    print(msg, file=sys.stderr)
                return 2
            name = f"{args.solver}, {n} layers" + ("" if gate is None else f", gate {gate:g} m/s")
            first = "  ".join("   —  " if f is None else f"{f:.3f}" for f in r["first"])
            fit = r["fit"]
            rms = "RMS H3 {H3:.4f} m, H4 {H4:.4f} m".format(**fit["as_run"])
            moved = "{H3:.4f}, {H4:.4f}".format(**fit["shifted"])
            print(
                f"  {name:34s} {r['depth']:.4f}  {first}   {rms}; moved {fit['shift']:+.4f} s: {moved}"
                f"   ({r['n']} particles, {r['steps']} steps)",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

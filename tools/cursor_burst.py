"""What a still cursor does to water at rest: the refinement alone, no push.

    python3 tools/cursor_burst.py                                   # demo_2d, as measured
    python3 tools/cursor_burst.py --set adaptivity.split_fade=0     # without the fade
    python3 tools/cursor_burst.py --scene demo_3d --at 0.5,0.15,0.25 --radius 0.07
    python3 tools/cursor_burst.py --strength 20 --leave     # held as the window holds it, let go

The scene runs ``--settle`` simulated seconds (demo_2d's opening stir is over by then
and the pool is at rest), then the mouse's disturbance is put at ``--at`` with a
strength of 1e-6 1/s (``--strength``; the window's mouse: 20): it pulls on nothing, but
the scene's ``disturbance`` criterion refines under it, so one adaptivity pass splits
the fluid there down to the finest level. One line per time after that (``--after``,
ms): the fastest real particle, how many move faster than 1 m/s and than 0.3 m/s, the
mean speed and the kinetic energy (J per metre of depth in 2D). At rest the pool
reads a few cm/s; before ``adaptivity.split_fade`` (mrsph/multires/fade.py) demo_2d
read 11 m/s and 1,638 particles above 1 m/s 2.5 ms after the cursor came.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

#: demo_2d: the cursor in the middle of the left basin, its radius the mouse's default
#: (8 % of the domain's largest side), reaching from the floor to above the surface
AT = (0.5, 0.12)
RADIUS = 0.128
AFTER_MS = (2.5, 10.0, 20.0, 50.0, 100.0)


def speeds(sim) -> tuple[np.ndarray, float]:
    """The real particles' speeds, and their kinetic energy."""
    P = sim.particles(virtual=False)
    sp = np.linalg.norm(P["v"].astype(np.float64), axis=1)
    return sp, 0.5 * float((P["m"].astype(np.float64) * sp * sp).sum())


def line(label: str, sp: np.ndarray, ke: float) -> str:
    return (f"{label:>11}: fastest {sp.max():6.2f} m/s, {int((sp > 1.0).sum()):5d} above 1 m/s, "
            f"{int((sp > 0.3).sum()):5d} above 0.3 m/s, mean {sp.mean():.3f} m/s, KE {ke:7.2f} J")


def burst(scene: str, overrides: list[str], at, radius: float, settle: float, after_ms,
          threads: int | None, arch: str = "cpu", leave: bool = False,
          strength: float = 1e-6) -> list[tuple[float, np.ndarray, float]]:
    """[(ms after the cursor came, the real particles' speeds, their kinetic energy)], the
    first at 0 (before); with ``leave``, then the cursor goes and the same times after it
    left follow, as negative ms."""
    from mrsph.config import load_scene
    from mrsph.interaction import Disturbance
    from mrsph.solver import Simulation
    sc = load_scene(scene, overrides)
    if len(at) != sc["dim"]:
        raise SystemExit(f"--at: {len(at)} coordinates for a {sc['dim']}D scene")
    sim = Simulation(sc, arch=arch, threads=threads)
    sim.advance(settle)
    out = [(0.0, *speeds(sim))]
    sim.set_disturbance(Disturbance(tuple(at), radius, strength, "push", (0.0,) * len(at)))
    t0 = sim.time
    for ms in after_ms:
        sim.advance(t0 + 1e-3 * ms - sim.time)
        out.append((ms, *speeds(sim)))
    if leave:
        sim.set_disturbance(None)
        t0 = sim.time
        for ms in after_ms:
            sim.advance(t0 + 1e-3 * ms - sim.time)
            out.append((-ms, *speeds(sim)))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--scene", default="demo_2d", help="an adaptive scene with a disturbance criterion")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="overrides",
                    help="override a scene key (repeatable)")
    ap.add_argument("--at", default=",".join(map(str, AT)), help="the cursor's place, m (x,y[,z])")
    ap.add_argument("--radius", type=float, default=RADIUS, help="the cursor's radius, m")
    ap.add_argument("--settle", type=float, default=2.5, help="simulated seconds before the cursor comes")
    ap.add_argument("--after", default=",".join(f"{t:g}" for t in AFTER_MS),
                    help="times after it came to report, ms")
    ap.add_argument("--strength", type=float, default=1e-6,
                    help="the cursor's pull towards rest, 1/s (the window's mouse: 20; the default "
                         "only refines)")
    ap.add_argument("--threads", type=int, default=1, help="CPU threads")
    ap.add_argument("--leave", action="store_true",
                    help="then take the cursor away and report the same times after it left "
                         "(the refined fluid merges back)")
    args = ap.parse_args(argv)
    from mrsph.config import SceneError
    try:
        at = [float(c) for c in args.at.split(",")]
        after = [float(t) for t in args.after.split(",")]
    except ValueError:
        ap.error("--at and --after take comma-separated numbers")
    try:
        rows = burst(args.scene, args.overrides, at, args.radius, args.settle, after, args.threads,
                     leave=args.leave, strength=args.strength)
    except SceneError as e:
        for msg in e.problems:
            print(msg, file=sys.stderr)
        return 2
    print(f"{args.scene} {' '.join(args.overrides)}".rstrip() + f": a still cursor at {tuple(at)}, "
          f"radius {args.radius} m, strength {args.strength:g} 1/s, after {args.settle} s")
    for ms, sp, ke in rows:
        label = "before" if ms == 0 else (f"{ms:g} ms" if ms > 0 else f"gone {-ms:g} ms")
        print(line(label, sp, ke))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""What a still cursor does to water at rest: the refinement alone, no push.

    python3 tools/cursor_burst.py                                   # demo_2d, as measured
    python3 tools/cursor_burst.py --set adaptivity.split_fade=0     # without the fade
    python3 tools/cursor_burst.py --scene demo_3d --at 0.5,0.15,0.25 --radius 0.07
    python3 tools/cursor_burst.py --strength 20 --leave     # held as the window holds it, let go
    python3 tools/cursor_burst.py --drag 2,0 --at 0.3,0.12  # dragged along the floor at 2 m/s
    python3 tools/cursor_burst.py --paths                   # twelve drags: each one's peak

The scene runs ``--settle`` simulated seconds (demo_2d's opening stir is over by then
and the pool is at rest), then the mouse's disturbance is put at ``--at`` with a
strength of 1e-6 1/s (``--strength``; the window's mouse: 20): it pulls on nothing, but
the scene's ``disturbance`` criterion refines under it, so one adaptivity pass splits
the fluid there down to the finest level. One line per time after that (``--after``,
ms): the fastest real particle, how many move faster than 1 m/s and than 0.3 m/s, the
mean speed and the kinetic energy (J per metre of depth in 2D). At rest the pool
reads a few cm/s; before ``adaptivity.split_fade`` (mrsph/multires/fade.py) demo_2d
read 11 m/s and 1,638 particles above 1 m/s 2.5 ms after the cursor came.

With ``--drag`` the cursor moves instead, from ``--at`` at the given velocity (m/s),
jumping once every ``--frame`` ms as the window moves it once a frame, for ``--for`` ms;
the kinetic energy is sampled every millisecond and its peak reported with when it
came. The refinement alone should leave the pool near rest (docs/validation.md, "A
cursor in resting water").
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
#: ``--paths``: twelve drags through demo_2d's resting pool, (start, velocity m/s): along
#: the floor, through the middle, down from the surface, up from the floor, diagonals, in
#: both basins. One drag says little of a chaotic burst; their median and worst say more
#: (docs/validation.md, "A cursor in resting water").
PATHS = (
    ((0.3, 0.12), (2.0, 0.0)),
    ((0.3, 0.2), (2.0, 0.0)),
    ((0.9, 0.12), (-2.0, 0.0)),
    ((0.3, 0.12), (1.0, 0.0)),
    ((0.5, 0.3), (0.0, -1.0)),
    ((0.2, 0.1), (1.5, 1.0)),
    ((0.15, 0.25), (2.0, -0.5)),
    ((1.0, 0.25), (-1.5, 0.0)),
    ((0.6, 0.05), (0.0, 1.5)),
    ((0.4, 0.15), (-1.0, 1.0)),
    ((1.4, 0.15), (0.5, 0.0)),
    ((0.7, 0.2), (2.0, 1.0)),
)


def speeds(sim) -> tuple[np.ndarray, float]:
    """The real particles' speeds, and their kinetic energy."""
    P = sim.particles(virtual=False)
    sp = np.linalg.norm(P["v"].astype(np.float64), axis=1)
    return sp, 0.5 * float((P["m"].astype(np.float64) * sp * sp).sum())


def line(label: str, sp: np.ndarray, ke: float) -> str:
    return (
        f"{label:>11}: fastest {sp.max():6.2f} m/s, {int((sp > 1.0).sum()):5d} above 1 m/s, "
        f"{int((sp > 0.3).sum()):5d} above 0.3 m/s, mean {sp.mean():.3f} m/s, KE {ke:7.2f} J"
    )


def burst(
    scene: str,
    overrides: list[str],
    at,
    radius: float,
    settle: float,
    after_ms,
    threads: int | None,
    arch: str = "cpu",
    leave: bool = False,
    strength: float = 1e-6,
) -> list[tuple[float, np.ndarray, float]]:
    """[(ms after the cursor came, the real particles' speeds, their kinetic energy)], the
    first at 0 (before); with ``leave``, then the cursor goes and the same times after it
    left follow, as negative ms."""
    from mrsph.scene.config import load_scene
    from mrsph.scene.interaction import Disturbance
    from mrsph.simulation import Simulation

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


def drag(
    scene: str,
    overrides: list[str],
    at,
    radius: float,
    settle: float,
    velocity,
    duration_ms: float,
    frame_ms: float,
    threads: int | None,
    arch: str = "cpu",
    strength: float = 1e-6,
) -> list[tuple[float, np.ndarray, float]]:
    """[(ms after the cursor came, the real particles' speeds, their kinetic energy)], one
    a millisecond, the first at 0 (before): the cursor starts at ``at`` and jumps to
    at + velocity t every ``frame_ms``, its velocity (what its push pulls towards) the
    drag's."""
    from mrsph.scene.config import load_scene
    from mrsph.scene.interaction import Disturbance
    from mrsph.simulation import Simulation

    sc = load_scene(scene, overrides)
    if len(at) != sc["dim"] or len(velocity) != sc["dim"]:
        raise SystemExit(f"--at and --drag: {len(at)} and {len(velocity)} coordinates for a {sc['dim']}D scene")
    sim = Simulation(sc, arch=arch, threads=threads)
    sim.advance(settle)
    out = [(0.0, *speeds(sim))]
    t0 = sim.time
    for ms in range(1, int(round(duration_ms)) + 1):
        frame_start = 1e-3 * frame_ms * ((ms - 1) // frame_ms)
        centre = tuple(a + v * frame_start for a, v in zip(at, velocity))
        sim.set_disturbance(Disturbance(centre, radius, strength, "push", tuple(velocity)))
        sim.advance(t0 + 1e-3 * ms - sim.time)
        out.append((float(ms), *speeds(sim)))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    ap.add_argument("--scene", default="demo_2d", help="an adaptive scene with a disturbance criterion")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        dest="overrides",
        help="override a scene key (repeatable)",
    )
    ap.add_argument("--at", default=",".join(map(str, AT)), help="the cursor's place, m (x,y[,z])")
    ap.add_argument("--radius", type=float, default=RADIUS, help="the cursor's radius, m")
    ap.add_argument("--settle", type=float, default=2.5, help="simulated seconds before the cursor comes")
    ap.add_argument("--after", default=",".join(f"{t:g}" for t in AFTER_MS), help="times after it came to report, ms")
    ap.add_argument(
        "--strength",
        type=float,
        default=1e-6,
        help="the cursor's pull towards rest, 1/s (the window's mouse: 20; the default only refines)",
    )
    ap.add_argument("--threads", type=int, default=1, help="CPU threads")
    ap.add_argument(
        "--leave",
        action="store_true",
        help="then take the cursor away and report the same times after it left (the refined fluid merges back)",
    )
    ap.add_argument(
        "--drag",
        default=None,
        metavar="VX,VY[,VZ]",
        help="move the cursor from --at at this velocity, m/s (default: held still)",
    )
    ap.add_argument("--for", type=float, default=400.0, dest="duration", help="with --drag: how long, ms")
    ap.add_argument("--frame", type=int, default=10, help="with --drag: ms between the cursor's jumps")
    ap.add_argument(
        "--paths",
        action="store_true",
        help="drag along each of demo_2d's twelve PATHS in turn (--at and --drag unused): "
        "one line each with the kinetic energy's peak, then their median and worst",
    )
    args = ap.parse_args(argv)
    from mrsph.scene.config import SceneError

    try:
        at = [float(c) for c in args.at.split(",")]
        after = [float(t) for t in args.after.split(",")]
        velocity = None if args.drag is None else [float(c) for c in args.drag.split(",")]
    except ValueError:
        ap.error("--at, --after and --drag take comma-separated numbers")
    if args.frame < 1 or args.duration <= 0:
        ap.error(f"--frame takes an integer >= 1 (got {args.frame}) and --for a duration > 0 (got {args.duration:g})")
    if args.paths and args.scene != "demo_2d":
        ap.error(f"--paths: the paths are demo_2d's (got --scene {args.scene})")
    try:
        if args.paths:
            _paths(args)
        else:
            _one(args, at, after, velocity)
    except SceneError as e:
        for msg in e.problems:
            print(msg, file=sys.stderr)
        return 2
    return 0


def _paths(args) -> None:
    """--paths: each of PATHS dragged in turn, one line each, then the median and worst."""
    peaks = []
    for start, vel in PATHS:
        rows = drag(
            args.scene,
            args.overrides,
            start,
            args.radius,
            args.settle,
            vel,
            args.duration,
            args.frame,
            args.threads,
            strength=args.strength,
        )
        ms, sp, ke = max(rows[1:], key=lambda r: r[2])
        peaks.append(ke)
        print(
            f"from {start} at {vel} m/s: peak {ke:8.2f} J at {ms:3g} ms, {int((sp > 1.0).sum()):4d} "
            f"above 1 m/s, the fastest {sp.max():.2f} m/s",
            flush=True,
        )
    print(
        f"peaks over {len(PATHS)} paths: median {np.median(peaks):.2f} J, worst {max(peaks):.2f} J, "
        f"{sum(k > 25.0 for k in peaks)} above 25 J"
    )


def _one(args, at, after, velocity) -> None:
    """One cursor, held still at ``at`` or dragged from it: the lines at ``after``."""
    if velocity is None:
        rows = burst(
            args.scene,
            args.overrides,
            at,
            args.radius,
            args.settle,
            after,
            args.threads,
            leave=args.leave,
            strength=args.strength,
        )
    else:
        rows = drag(
            args.scene,
            args.overrides,
            at,
            args.radius,
            args.settle,
            velocity,
            args.duration,
            args.frame,
            args.threads,
            strength=args.strength,
        )
    how = "a still cursor" if velocity is None else f"a cursor dragged at {tuple(velocity)} m/s from"
    print(
        f"{args.scene} {' '.join(args.overrides)}".rstrip() + f": {how} {tuple(at)}, "
        f"radius {args.radius} m, strength {args.strength:g} 1/s, after {args.settle} s"
    )
    if velocity is not None:
        peak = max(rows[1:], key=lambda r: r[2])
        median = float(np.median([ke for _, _, ke in rows[1:]]))
        rows = [rows[0]] + [r for r in rows[1:] if r[0] in after] + [peak]
        print(f"(the last line is the kinetic energy's peak; its median over the drag {median:.2f} J)")
    for ms, sp, ke in rows:
        label = "before" if ms == 0 else (f"{ms:g} ms" if ms > 0 else f"gone {-ms:g} ms")
        print(line(label, sp, ke))


if __name__ == "__main__":
    sys.exit(main())

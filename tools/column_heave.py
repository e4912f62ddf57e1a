"""How a deep column at rest moves, step by step: a heave of the whole column or noise.

    python3 tools/column_heave.py                                   # dfsph, the 80-deep 2D tank, 0.6 s
    python3 tools/column_heave.py --set fluid.artificial_viscosity_cap=0.15 --until 1.0
    python3 tools/column_heave.py --solver wcsph                    # the same column, at rest
    python3 tools/column_heave.py --scene tank_rest_3d --set particles.spacing=0.01

The scene is tools/validate.py's deep tank (scenes/tank_rest_2d: 0.4 m of water, 80 layers),
uniform. Every ``--every`` steps it prints the time, the step, the real particles' mean
vertical velocity and mean speed over √(gH), the share of the speed that is collective (the
mean velocity of cells four spacings wide) rather than particle to particle, the mean
pressure in the lowest 5 cm over ρ0 g times its depth (1 = hydrostatic), the density error
there, and the pressure solve's iterations. At the end: the column's heave (the RMS of its
mean vertical velocity), its period (from the sign changes of that velocity) and the range
of the floor's pressure. One thread; about 20 s for 0.6 s of the 2D tank under dfsph.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

G = 9.81
RHO0 = 1000.0
FLOOR = 0.05  # m: the band above the floor whose pressure is compared with hydrostatic


def heave(scene_name: str, solver: str, sets: list[str], until: float, every: int) -> dict:
    import numpy as np

    from mrsph.scene.config import load_scene
    from mrsph.simulation import Simulation

    scene = load_scene(scene_name, [f'fluid.solver="{solver}"', *sets])
    H = float(scene.data["fluid"]["blocks"][0]["max"][1])
    sim = Simulation(scene, arch="cpu", threads=1)
    U = math.sqrt(G * H)
    cell = 4.0 * float(sim.s0)
    t, vy, floor_p = [], [], []
    heads = (("t (s)", 7), ("dt (ms)", 7), ("vy/U", 8), ("|v|/U", 7), ("coll.", 6), ("p floor", 7), ("rho floor", 9))
    print(" ".join(f"{name:>{w}}" for name, w in heads), f"{'iter.':>6}")
    k = 0
    while sim.time < until - 1e-12:
        dt = sim.step()
        k += 1
        if k % every:
            continue
        p = sim.particles(virtual=False)
        x, v = p["x"].astype(np.float64), p["v"].astype(np.float64)
        speed = np.linalg.norm(v, axis=1)
        key = np.floor(x / cell).astype(np.int64) @ (1 << (20 * np.arange(x.shape[1])))
        _, inv = np.unique(key, return_inverse=True)
        cnt = np.bincount(inv)
        mean_v = np.stack([np.bincount(inv, v[:, d]) / cnt for d in range(x.shape[1])], 1)
        collective = float(np.linalg.norm(mean_v[inv], axis=1).mean() / max(speed.mean(), 1e-30))
        low = x[:, 1] < FLOOR
        depth = H - x[low, 1]
        ratio = float(np.mean(p["p"][low] / (RHO0 * G * depth)))
        err = float(p["rho"][low].mean() / RHO0 - 1.0)
        row = sim.stats()
        t.append(sim.time)
        vy.append(float(v[:, 1].mean() / U))
        floor_p.append(ratio)
        its = row.get("density_iterations") or 0.0
        print(
            f"{sim.time:7.4f} {dt * 1e3:7.3f} {vy[-1]:+8.4f} {speed.mean() / U:7.4f} {collective:6.2f} "
            f"{ratio:7.2f} {err * 100:+8.3f}% {its:6.1f}",
            flush=True,
        )
    vy_a = np.asarray(vy)
    flips = np.nonzero(np.diff(np.sign(vy_a)) != 0)[0]
    period = 2.0 * float(np.mean(np.diff(np.asarray(t)[flips]))) if len(flips) > 2 else float("nan")
    return {
        "heave": float(np.sqrt(np.mean(vy_a**2))),
        "period": period,
        "floor_min": float(np.min(floor_p)),
        "floor_max": float(np.max(floor_p)),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    ap.add_argument("--scene", default="tank_rest_2d", help="a deep tank at rest (one block from the floor)")
    ap.add_argument("--solver", choices=("dfsph", "wcsph", "pbf"), default="dfsph")
    ap.add_argument("--until", type=float, default=0.6, help="simulated seconds")
    ap.add_argument("--every", type=int, default=3, help="print every this many steps")
    ap.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", dest="sets", help="a scene key (repeatable)"
    )
    args = ap.parse_args(argv)
    from mrsph.scene.config import SceneError

    try:
        out = heave(args.scene, args.solver, args.sets, args.until, max(args.every, 1))
    except SceneError as e:
        for msg in e.problems:
            print(msg, file=sys.stderr)
        return 2
    print(
        f"heave (RMS of the mean vertical velocity) {out['heave']:.4f} sqrt(gH), period "
        + (f"{out['period'] * 1e3:.0f} ms, " if math.isfinite(out["period"]) else "- (it did not reverse twice), ")
        + f"floor pressure {out['floor_min']:.2f} .. {out['floor_max']:.2f} of hydrostatic"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())

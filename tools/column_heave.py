"""How a deep column at rest moves, step by step: a heave of the whole column or noise.

    python3 tools/column_heave.py                                   # dfsph, the 80-deep 2D tank, 0.6 s
    python3 tools/column_heave.py --set fluid.artificial_viscosity_cap=0.15 --until 1.0
    python3 tools/column_heave.py --solver wcsph                    # the same column, at rest
    python3 tools/column_heave.py --scene tank_rest_3d --set particles.spacing=0.01
    python3 tools/column_heave.py --until 0.5 --every 50 --predict 100  # the solve's prediction, checked

The scene is tools/validate.py's deep tank (scenes/tank_rest_2d: 0.4 m of water, 80 layers),
uniform. Every ``--every`` steps it prints the time, the step, the real particles' mean
vertical velocity and mean speed over √(gH), the share of the speed that is collective (the
mean velocity of cells four spacings wide) rather than particle to particle, the mean
pressure in the lowest 5 cm over ρ0 g times its depth (1 = hydrostatic), the density error
there, and the pressure solve's iterations. At the end: the column's heave (the RMS of its
mean vertical velocity), its period (from the sign changes of that velocity) and the range
of the floor's pressure. One thread; about 20 s for 0.6 s of the 2D tank under dfsph.

``--predict N`` then checks, over N more steps, what the pressure solves assume: that a step
changes the density by dt Σ m (u_i − u_j')·∇W_ij. It prints the change the density pass
sees (its poly6 sum, recomputed here with the walls mirrored) against that prediction with
poly6's own gradient and with the solves' spiky gradient, in the floor layer and the
interior (needs scipy; about 0.5 s a step at 3,200 particles).
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
FLOOR = 0.05  # m: the band above the floor whose pressure is compared with hydrostatic


def _images(x, v, lo, hi, h):
    """x and v with their mirror images across the domain's walls (and corners) within h."""
    import itertools

    import numpy as np

    xs, vs = [x], [v]
    for sides in itertools.product((None, 0, 1), repeat=x.shape[1]):
        if all(sd is None for sd in sides):
            continue
        xm, vm, near = x.copy(), v.copy(), np.ones(len(x), bool)
        for ax, sd in enumerate(sides):
            if sd is not None:
                wall = lo[ax] if sd == 0 else hi[ax]
                near &= np.abs(x[:, ax] - wall) < h
                xm[:, ax] = 2.0 * wall - xm[:, ax]
                vm[:, ax] = -vm[:, ax]
        xs.append(xm[near])
        vs.append(vm[near])
    return np.concatenate(xs), np.concatenate(vs)


def predicted_change(sim, scene, steps: int) -> dict:
    """Over ``steps`` more steps: each step's change of the density (the density pass's
    poly6 sum, walls mirrored, from the positions before the drift to those after) against
    the change its velocities predict, dt Σ m (u_i − u_j')·∇W_ij, with the density's own
    kernel (poly6) and with the solve's (spiky, calibrated to the lattice), in the floor
    layer (within a spacing of the floor) and the interior: each the mean over particles
    and steps, in % of ρ0, and each prediction's RMS error particle by particle. Uniform
    scenes, domain walls only."""
    import numpy as np
    from scipy.spatial import cKDTree

    from mrsph.sph.kernels import constants, lattice_gradient_factor, poly6_np, spiky_grad_np

    dim, rho0 = scene.dim, scene.params.fluid.rest_density
    h, m, s0 = float(sim.h0), float(sim.m0), float(sim.s0)
    lo = np.asarray(scene.data["domain"]["min"], float)
    hi = np.asarray(scene.data["domain"]["max"], float)
    c_poly6 = constants(h, dim)["poly6"]
    calibration = lattice_gradient_factor(s0, h, dim)  # the solves' spiky constant is divided by it

    def density(x):
        xa, _ = _images(x, x, lo, hi, h)
        near = cKDTree(xa).query_ball_point(x, h)
        return np.array(
            [m * poly6_np(np.linalg.norm(x[i] - xa[js], axis=1), h, dim).sum() for i, js in enumerate(near)]
        )

    names = [f"{b} {k}" for b in ("floor", "inner") for k in ("actual", "poly6", "spiky", "poly6 rms", "spiky rms")]
    sums = dict.fromkeys(names, 0.0)
    for _ in range(steps):
        dt = sim.step()
        p = sim.particles(virtual=False)
        x1, v = p["x"].astype(np.float64), p["v"].astype(np.float64)
        x0 = x1 - dt * v  # the drift moved each particle by dt v
        change = density(x1) - density(x0)
        xa, va = _images(x0, v, lo, hi, h)
        tree = cKDTree(xa)
        pred = {"poly6": np.zeros(len(x0)), "spiky": np.zeros(len(x0))}
        for i, js in enumerate(tree.query_ball_point(x0, h)):
            r = x0[i] - xa[js]
            ok = np.linalg.norm(r, axis=1) > 0.0
            du, r = v[i] - va[js][ok], r[ok]
            g6 = (-6.0 * c_poly6 * (h * h - np.sum(r * r, 1)) ** 2)[:, None] * r  # poly6's gradient
            gs = spiky_grad_np(r, h, dim) / calibration
            pred["poly6"][i] = dt * m * np.einsum("ij,ij->", du, g6)
            pred["spiky"][i] = dt * m * np.einsum("ij,ij->", du, gs)
        # the interior: beyond a support of every wall and below the top fifth of the column
        inner = np.all((x0 > lo + h) & (x0 < hi - h), axis=1) & (x0[:, 1] < 0.8 * x0[:, 1].max())
        for band, sel in (("floor", x0[:, 1] < lo[1] + s0), ("inner", inner)):
            if not sel.any():
                raise SystemExit(f"--predict: no particle in the {band} band of {scene.path}")
            sums[f"{band} actual"] += float(np.mean(change[sel]))
            for kern in ("poly6", "spiky"):
                sums[f"{band} {kern}"] += float(np.mean(pred[kern][sel]))
                sums[f"{band} {kern} rms"] += float(np.sqrt(np.mean((pred[kern][sel] - change[sel]) ** 2)))
    return {k: 100.0 * val / steps / rho0 for k, val in sums.items()}


def heave(scene_name: str, solver: str, sets: list[str], until: float, every: int, predict: int = 0) -> dict:
    import numpy as np

    from mrsph.scene.config import load_scene
    from mrsph.simulation import Simulation

    scene = load_scene(scene_name, [f'fluid.solver="{solver}"', *sets])
    H = float(scene.data["fluid"]["blocks"][0]["max"][1])
    sim = Simulation(scene, arch="cpu", threads=1)
    U = math.sqrt(G * H)
    rho0 = scene.params.fluid.rest_density
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
        ratio = float(np.mean(p["p"][low] / (rho0 * G * depth)))
        err = float(p["rho"][low].mean() / rho0 - 1.0)
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
    if not vy:
        raise SystemExit(f"no step printed before t = {until}: lower --every")
    vy_a = np.asarray(vy)
    flips = np.nonzero(np.diff(np.sign(vy_a)) != 0)[0]
    period = 2.0 * float(np.mean(np.diff(np.asarray(t)[flips]))) if len(flips) > 2 else float("nan")
    out = predicted_change(sim, scene, predict) if predict else {}
    return {
        **out,
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
    ap.add_argument(
        "--predict",
        type=int,
        default=0,
        metavar="STEPS",
        help="then, over this many steps, each step's density change against what its velocities predict",
    )
    args = ap.parse_args(argv)
    from mrsph.scene.config import SceneError

    try:
        out = heave(args.scene, args.solver, args.sets, args.until, max(args.every, 1), args.predict)
    except SceneError as e:
        for msg in e.problems:
            print(msg, file=sys.stderr)
        return 2
    print(
        f"heave (RMS of the mean vertical velocity) {out['heave']:.4f} sqrt(gH), period "
        + (f"{out['period'] * 1e3:.0f} ms, " if math.isfinite(out["period"]) else "- (it did not reverse twice), ")
        + f"floor pressure {out['floor_min']:.2f} .. {out['floor_max']:.2f} of hydrostatic"
    )
    if args.predict:
        for band in ("floor", "inner"):
            print(
                f"{band}: density change a step {out[band + ' actual']:+.4f} % of rho0; predicted with the density's "
                f"kernel (poly6) {out[band + ' poly6']:+.4f} % (off by {out[band + ' poly6 rms']:.4f} % RMS), with the "
                f"solve's (spiky) {out[band + ' spiky']:+.4f} % (off by {out[band + ' spiky rms']:.4f} % RMS)"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())

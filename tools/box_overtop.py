"""Which way the water reaches H1 in MARIN's box case: over the box or round it.

    python3 tools/box_overtop.py                          # wcsph, 27 layers (the scene), about 8 min
    python3 tools/box_overtop.py --quick                  # 14 layers, about 1 min
    python3 tools/box_overtop.py --solver pbf --set fluid.artificial_viscosity=0.05

The scene is tools/validate.py's box (scenes/dam_break_box_3d), uniform. Every 2 ms each real
particle above the box's top (over its footprint) is marked; the mark moves with the particle.
From ``--since`` on, every 20 ms it prints the time, the water above the box and its mean
velocity along the tank and upwards (m/s; towards the far wall is negative), the water in
the box's shadow (between x = 0.3 m and the box's back face, 5 cm inside its width) and the
part of it that was marked, the water within 5 cm of H1 (x = 0.496 m; 10 cm across) and its
marked part, all the marked water, all in litres, and H1's water height as validate.py reads
it. One thread.

The mark is the particle's ``lam``, the refinement criteria's slot, which a uniform run leaves
unused; hence no ``--adaptive``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
for p in (ROOT, ROOT / "tools"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

LAYERS_QUICK = 14


COLUMNS = ("t", "above", "ux", "uy", "shadow", "shadow_over", "near_h1", "near_h1_over", "marked", "h1")


def overtop(solver: str, quick: bool, sets: list[str], since: float, until: float) -> list[dict]:
    """The box run; a row (``COLUMNS``: litres, H1's height in m) every 20 ms from ``since``."""
    import numpy as np
    import taichi as ti
    import validate as V

    from mrsph.scene.config import load_scene
    from mrsph.simulation import Simulation

    spacing = 0.55 / LAYERS_QUICK if quick else V.scene_spacing("box", 3)
    over = [f'fluid.solver="{solver}"', "adaptivity.enabled=false", f"particles.spacing={spacing!r}", *sets]
    scene = load_scene(V.SCENES["box"], over)
    if scene.adaptivity.enabled:
        sys.exit("box_overtop.py: the mark is the criteria's slot, so the run must be uniform")
    sim = Simulation(scene, arch="cpu", threads=1)
    box = scene.data["obstacles"][0]  # the box, as the scene (and any --set) puts it
    (x0, _, z0), (x1, top, z1) = box["min"], box["max"]
    h1_x = V.PROBES[0]
    P, N = sim.pool.p, sim.pool.n

    @ti.kernel
    def mark():
        for i in range(N[None]):
            q = P[i].x
            if q[0] > x0 and q[0] < x1 and q[2] > z0 and q[2] < z1 and q[1] > top:
                P[i].lam = 1.0

    zc = 0.5 * float(scene.data["domain"]["max"][2])
    rows = []
    while sim.time < until - 1e-9:
        for _ in range(10):
            sim.advance(0.002)
            mark()
        if sim.time < since - 1e-9:
            continue
        r, marked = V._real(sim), sim.particles(virtual=False)["lam"] > 0.5
        x, vol = r["x"], r["vol"] * 1000.0  # litres
        above = (x[:, 0] > x0) & (x[:, 0] < x1) & (x[:, 2] > z0) & (x[:, 2] < z1) & (x[:, 1] > top)
        shadow = (x[:, 0] > 0.3) & (x[:, 0] < x0) & (x[:, 2] > z0 + 0.05) & (x[:, 2] < z1 - 0.05)
        near = (np.abs(x[:, 0] - h1_x) < 0.05) & (np.abs(x[:, 2] - zc) < 0.1)
        volumes = [float(vol[k].sum()) for k in (shadow, shadow & marked, near, near & marked, marked)]
        u = r["v"][above].mean(axis=0) if above.any() else np.zeros(3)
        h1 = V.water_level(x, r["vol"], r["h"], (h1_x, zc), 0.8)
        rows.append(dict(zip(COLUMNS, (sim.time, float(vol[above].sum()), u[0], u[1], *volumes, h1))))
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--solver", default="wcsph")
    ap.add_argument("--quick", action="store_true", help="14 layers instead of 27")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE", help="a scene override")
    ap.add_argument("--since", type=float, default=0.6, help="first time printed (s)")
    ap.add_argument("--until", type=float, default=1.2, help="end (s)")
    args = ap.parse_args(argv)
    from mrsph.scene.config import SceneError

    try:
        rows = overtop(args.solver, args.quick, args.sets, args.since, args.until)
    except SceneError as e:
        for msg in e.problems:
            print(msg, file=sys.stderr)
        return 2
    print("     t   above    u_x    u_y  shadow of_it_over near_H1 of_it_over  marked     H1")
    for row in rows:
        print(f"{row['t']:6.3f} " + " ".join(f"{row[k]:7.2f}" for k in COLUMNS[1:-1]) + f"  {row['h1']:6.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

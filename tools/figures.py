"""Make the README's pictures with the project's own renderer.

    python3 tools/figures.py            # assets/kinds.png and assets/demo.gif (--out DIR: elsewhere)

kinds.png: a zoom on a level interface of region_2d at t = 0 (two levels), coloured by
kind, virtual particles shown. demo.gif: the adaptive dam break hitting a block.
"""
import argparse
import sys
from dataclasses import replace
from pathlib import Path

import imageio.v3 as iio
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from mrsph.app.raster import Rasterizer  # noqa: E402
from mrsph.app.record import record  # noqa: E402
from mrsph.config import load_scene  # noqa: E402
from mrsph.solver import Simulation  # noqa: E402


def kinds_figure(path: Path) -> None:
    sim = Simulation(load_scene("region_2d", ["adaptivity.levels=2"]), arch="cpu")
    snap = sim.snapshot()
    lo, hi = np.array([0.13, 0.0]), np.array([0.43, 0.17])   # the refined box's sides and bottom
    keep = np.all((snap.x >= lo - 0.01) & (snap.x <= hi + 0.01), axis=1)
    zoom = replace(snap, x=snap.x[keep], v=snap.v[keep], m=snap.m[keep], rho=snap.rho[keep],
                   level=snap.level[keep], kind=snap.kind[keep], domain_min=lo, domain_max=hi)
    img = Rasterizer(1000, 566).render(zoom, color_mode="kind", show_virtual=True)
    iio.imwrite(path, img)


def demo_gif(path: Path) -> None:
    sim = Simulation(load_scene("dam_break_obstacle_2d"), arch="cpu")
    record(sim, path, frames=45, width=640, height=320, backend="auto", progress=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="Without --out it overwrites the README's assets/kinds.png and assets/demo.gif.")
    ap.add_argument("--out", type=Path, default=ROOT / "assets", help="folder for the two files "
                    "(default: assets/)")
    out = ap.parse_args().out
    out.mkdir(parents=True, exist_ok=True)
    kinds_figure(out / "kinds.png")
    demo_gif(out / "demo.gif")
    print("wrote", out / "kinds.png", out / "demo.gif")

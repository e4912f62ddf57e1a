"""Make the pictures of the README and docs/METHOD.md with the project's own renderer.

    python3 tools/figures.py            # assets/kinds.png and assets/demo.gif (--out DIR: elsewhere)

kinds.png: a zoom on a level interface of region_2d at t = 0 (two levels): real particles
coloured by kind, virtual ones as rings joined to the real particles they stand for.
demo.gif: the adaptive dam break hitting a block.
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
from mrsph.scene.config import load_scene  # noqa: E402
from mrsph.simulation import Simulation  # noqa: E402

#: kinds.png: the world window (m) around the lower-left corner of region_2d's refined
#: zone, where coarse fluid meets fine fluid along a side and along the floor.
KINDS_WINDOW = (np.array([0.14, 0.0]), np.array([0.26, 0.068]))
#: drawn radius of a particle, in spacings of its level (0.5 would touch)
KINDS_DISC = 0.36
KINDS_VIRTUAL_CHILD = np.array([0.85, 0.85, 0.85], np.float32)  # light grey ring
KINDS_VIRTUAL_PARENT = np.array([1.0, 1.0, 1.0], np.float32)  # white ring
KINDS_LINK = np.array([0.55, 0.55, 0.60], np.float32)  # thin line to the real particle(s)


def _ring(img, view, centres, r_world, colour, width_px=2.0):
    """Circle outlines (y-up image rows, as the rasteriser draws them)."""
    h, w, _ = img.shape
    r = float(view.radius_px(r_world))
    k = int(np.ceil(r + width_px))
    dy, dx = np.mgrid[-k : k + 1, -k : k + 1]
    on = np.abs(np.hypot(dx, dy) - r) <= width_px / 2
    dx, dy = dx[on], dy[on]
    for c in view.world_to_px(centres):
        x, y = np.floor(c[0]).astype(int) + dx, np.floor(c[1]).astype(int) + dy
        ok = (x >= 0) & (x < w) & (y >= 0) & (y < h)
        img[y[ok], x[ok]] = colour


def _segments(img, view, a, b, colour):
    """One-pixel lines from a[i] to b[i] (world)."""
    h, w, _ = img.shape
    pa, pb = view.world_to_px(a), view.world_to_px(b)
    for u, v in zip(pa, pb):
        n = int(np.ceil(np.linalg.norm(v - u) * 2)) + 2
        t = np.linspace(0.0, 1.0, n)[:, None]
        q = np.floor(u + (v - u) * t).astype(int)
        ok = (q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)
        img[q[ok, 1], q[ok, 0]] = colour


def kinds_figure(path: Path) -> None:
    """Every particle kind of METHOD.md §3 at a level interface, with its links: real
    particles as discs coloured by kind (small: fine level, large: coarse level), virtual
    children as light grey rings joined to the transient parent that carries them,
    virtual parents as white rings joined to the transient children they stand for."""
    from mrsph.app import palette
    from mrsph.app.view import View2D
    from mrsph.sph.particles import DEAD, TRANSIENT_BOTH, TRANSIENT_CHILD, VIRTUAL_CHILD, VIRTUAL_PARENT

    sim = Simulation(load_scene("region_2d", ["adaptivity.levels=2"]), arch="cpu")
    snap = sim.snapshot(stats=False)
    n, pool = sim.pool.count(), sim.pool.p
    # pool order (not particles(), which leaves out dead slots): parent links index it
    x, v, m, rho, kind, level, parent = (
        getattr(pool, a).to_numpy()[:n] for a in ("x", "v", "m", "rho", "kind", "level", "parent")
    )
    lo, hi = KINDS_WINDOW
    pad = 2 * sim.s0 * 2 ** (sim.levels - 1)
    near = np.all((x >= lo - pad) & (x <= hi + pad), axis=1) & (kind != DEAD)
    real = near & ~palette.is_virtual(kind)
    zoom = replace(
        snap,
        x=x[real],
        v=v[real],
        m=m[real],
        rho=rho[real],
        level=level[real],
        kind=kind[real],
        domain_min=lo,
        domain_max=hi,
    )
    width, height = 1040, 610
    img = Rasterizer(width, height).render(
        zoom, color_mode="kind", legend=False, style=palette.Style(point_scale=2 * KINDS_DISC)
    )
    img = np.ascontiguousarray(img[::-1]).astype(np.float32) / 255.0  # rows y-up while drawing
    view = View2D(lo, hi, width, height)
    linked = near & np.isin(kind, (VIRTUAL_CHILD, TRANSIENT_CHILD, TRANSIENT_BOTH)) & (parent >= 0)
    _segments(img, view, x[linked], x[parent[linked]], KINDS_LINK)
    for code, colour in ((VIRTUAL_CHILD, KINDS_VIRTUAL_CHILD), (VIRTUAL_PARENT, KINDS_VIRTUAL_PARENT)):
        for lvl in range(sim.levels):
            sel = near & (kind == code) & (level == lvl)
            _ring(img, view, x[sel], KINDS_DISC * sim.s0 * 2.0**lvl, colour)
    # the outline drawn around the window is no wall (but its bottom edge, the floor, is):
    # crop the other three edges and the margin away
    (x0, y0), (x1, y1) = view.world_to_px(np.array([lo, hi]))
    img = img[max(int(y0) - 3, 0) : int(y1) - 2, int(x0) + 3 : int(x1) - 2]
    iio.imwrite(path, np.clip(img[::-1] * 255.0 + 0.5, 0, 255).astype(np.uint8))


def demo_gif(path: Path) -> None:
    sim = Simulation(load_scene("dam_break_obstacle_2d"), arch="cpu")
    record(sim, path, frames=45, width=640, height=320, backend="auto", progress=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Without --out it overwrites assets/kinds.png and assets/demo.gif.",
    )
    ap.add_argument("--out", type=Path, default=ROOT / "assets", help="folder for the two files (default: assets/)")
    out = ap.parse_args().out
    out.mkdir(parents=True, exist_ok=True)
    kinds_figure(out / "kinds.png")
    demo_gif(out / "demo.gif")
    print("wrote", out / "kinds.png", out / "demo.gif")

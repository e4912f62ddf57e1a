#!/usr/bin/env python3
"""MARIN's dam break past a box (tools/validate.py's box case) in SPlisHSPlasH, a second SPH code,
at mrsph's spacing and read by mrsph's own wave gauge: whether another code's water reaches H1,
behind the box, on time.

SPlisHSPlasH (Bender et al., MIT licence; the PyPI wheel pysplishsplash 2.19.0) is no dependency of
mrsph, so a run takes a virtual environment of its own; the report runs in mrsph's:

    python3 -m venv /tmp/sph && /tmp/sph/bin/pip install pysplishsplash==2.19.0 numpy
    OMP_NUM_THREADS=2 /tmp/sph/bin/python tools/peer_box.py --layers 27   # 5 min; 40 layers: 33 min
    OMP_NUM_THREADS=2 /tmp/sph/bin/python tools/peer_box.py --layers 27 --viscosity 0.001
    python3 tools/peer_box.py --report     # the table and docs/validation/box_peer_3d.png

The set-up is mrsph's scene (scenes/dam_break_box_3d.toml) as closely as the two codes allow:
- SPlisHSPlasH's DFSPH (density error 0.01 %, divergence 0.1 %), its cubic spline kernel on a
  support of 2 spacings (mrsph's), its "standard" viscosity (kinematic, m²/s) and its volume-map
  walls (Bender et al. 2019); no artificial viscosity, which it does not have;
- a volume map holds a particle at rest 2.3 r from its mesh (r the particle radius; measured in a
  settled tank), mrsph's mirror images at r from the wall, so every mesh moves by 1.3 r (the
  tank's walls out, the box's faces in) and the water rests where mrsph's does;
- DFSPH removes a density error within one step, so a particle that starts inside a wall's layer
  is thrown off at tens of m/s: the reservoir's lattice starts 3 r from the meshes, as many
  particles as mrsph's to 0.1 % at 27 layers (1.1 % at 40), and settles behind a gate at
  x = 1.992 m for 0.6 s; the release starts from the settled particles, at rest.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import json
import math
import os
import sys
import tempfile
import textwrap
import time
import tomllib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import validate as V  # noqa: E402  (the gauge, the probes and the data: numpy only)

OUT = V.FIGURES / "peer"


def _box_scene() -> tuple[tuple, tuple, float, float]:
    """The box scene's tank, box, gate (where the reservoir's water ends, x) and depth, read from
    its file with the standard library: SPlisHSPlasH's environment has no mrsph to load it."""
    with open(V.ROOT / "scenes" / f"{V.SCENES['box']}.toml", "rb") as f:
        data = tomllib.load(f)
    block, box = data["fluid"]["blocks"][0], data["obstacles"][0]
    return tuple(data["domain"]["max"]), (tuple(box["min"]), tuple(box["max"])), block["min"][0], block["max"][1]


TANK, BOX, GATE, DEPTH = _box_scene()
REST = 2.3  # a volume map's particle at rest sits this many radii from its mesh
SETTLE_S, END_S, SAMPLE_S = 0.6, 1.3, 0.002
MIN_LAYERS = 8  # the box then stands 2 spacings high
GL_DISPATCH = Path("/lib/x86_64-linux-gnu/libGLdispatch.so.0")


def cube_obj(path: Path) -> None:
    """The unit cube centred at 0, each face two triangles wound outwards."""
    corners = [(x, y, z) for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]
    faces = []
    for k in range(3):
        for s in (-0.5, 0.5):
            quad = [i for i, c in enumerate(corners) if c[k] == s]
            centre = np.mean([corners[i] for i in quad], axis=0)
            a, b = [j for j in range(3) if j != k]
            quad.sort(key=lambda i: math.atan2(corners[i][b] - centre[b], corners[i][a] - centre[a]))
            p = [np.array(corners[i]) for i in quad]
            if np.dot(np.cross(p[1] - p[0], p[2] - p[0]), centre) < 0:
                quad.reverse()
            faces += [(quad[0], quad[1], quad[2]), (quad[0], quad[2], quad[3])]
    lines = [f"v {x} {y} {z}" for x, y, z in corners] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


def body(lo, hi, r, invert, cell):
    """A static rigid body: the cube scaled onto [lo, hi], its volume map at cells of ``cell``."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    size = hi - lo
    return {
        "geometryFile": "cube.obj",
        "translation": ((lo + hi) / 2).tolist(),
        "rotationAxis": [1, 0, 0],
        "rotationAngle": 0,
        "scale": size.tolist(),
        "isDynamic": False,
        "isWall": invert,
        "mapInvert": invert,
        "mapThickness": 0.0,
        "mapResolution": [int(math.ceil((s + 16 * 4 * r) / cell)) for s in size],
    }


def lattice(s: float) -> tuple[list, list, int]:
    """The reservoir's block: first and last particle centres 3 r from the meshes, and how many
    particles mrsph seeds there (its lattice from the walls at r)."""
    r = s / 2
    target = int(math.floor((TANK[0] - GATE) / s + 1e-6)) * round(DEPTH / s) * int(math.floor(TANK[2] / s + 1e-6))
    off = 3 * r - (REST - 1) * r  # from the true walls
    nx = int(math.floor((TANK[0] - GATE - 2 * off) / s)) + 1
    nz = int(math.floor((TANK[2] - 2 * off) / s)) + 1
    ny = round(target / (nx * nz))
    first = [GATE + off, off, off]
    last = [first[0] + (nx - 1) * s, first[1] + (ny - 1) * s, first[2] + (nz - 1) * s]
    return first, last, target


def scene(s: float, viscosity: float, gate: bool) -> dict:
    r = s / 2
    dl = (REST - 1) * r
    first, last, _ = lattice(s)
    bodies = [
        body([-dl] * 3, [TANK[0] + dl, TANK[1] + dl, TANK[2] + dl], r, True, 4 * r),
        body([BOX[0][0] + dl, -dl, BOX[0][2] + dl], [BOX[1][0] - dl, BOX[1][1] - dl, BOX[1][2] - dl], r, False, 2 * r),
    ]
    if gate:
        bodies.append(body([GATE - dl - 0.1, -0.1, -0.1], [GATE - dl, 1.1, 1.1], r, False, 4 * r))
    return {
        "Configuration": {
            "pause": False,
            "sim2D": False,
            "particleRadius": r,
            "simulationMethod": 4,  # DFSPH
            "gravitation": [0, -9.81, 0],
            "timeStepSize": 1e-4,
            "cflMethod": 1,
            "cflFactor": 0.5,
            "cflMaxTimeStepSize": 0.002,
            "boundaryHandlingMethod": 2,  # volume maps
            "enableZSort": True,
            "enablePartioExport": False,
            "enableVTKExport": False,
            "enableRigidBodyExport": False,
            "enableRigidBodyVTKExport": False,
            "enableStateExport": False,
            "enableAsyncExport": False,
            "DFSPH": {
                "minIterations": 2,
                "maxIterations": 100,
                "maxError": 0.01,  # %
                "maxIterationsV": 100,
                "maxErrorV": 0.1,  # %
                "enableDivergenceSolver": True,
            },
        },
        "Materials": [
            {
                "id": "Fluid",
                "density0": 1000,
                "viscosityMethod": 1 if viscosity > 0 else 0,
                "Standard viscosity": {"viscosity": viscosity},
                "vorticityMethod": 0,
                "surfaceTensionMethod": 0,
                "dragMethod": 0,
                "elasticityMethod": 0,
            }
        ],
        "RigidBodies": bodies,
        # SPlisHSPlasH's block puts its first particle 2 r inside its start and its last 2 r inside its end
        "FluidBlocks": [
            {
                "id": "Fluid",
                "denseMode": 0,
                "start": [f - s for f in first],
                "end": [e + s + 1e-6 for e in last],
                "translation": [0, 0, 0],
                "scale": [1, 1, 1],
            }
        ],
    }


def simulate(sph, path: Path, stop: float, start=None, sample=None):
    """Run the scene at ``path`` to ``stop`` s (from the positions ``start``, at rest); call
    ``sample(t, x)`` every ``SAMPLE_S``; the last positions and the largest speed at the end."""
    base = sph.Exec.SimulatorBase()
    out = str(path.parent / "out")
    base.init(sceneFile=str(path), useGui=False, initialPause=False, stopAt=stop, outputDir=out, useCache=True)
    base.initSimulation()
    tm, fm = sph.TimeManager.getCurrent(), sph.Simulation.getCurrent().getFluidModel(0)
    n = fm.numActiveParticles()
    if start is not None:
        np.asarray(fm.getFieldBuffer("position")).reshape(-1, 3)[:n] = start
    due = [0.0]

    def each_step():
        if sample is not None and tm.getTime() >= due[0] - 1e-9:
            sample(tm.getTime(), np.array(fm.getFieldBuffer("position"), copy=True).reshape(-1, 3)[:n].astype(float))
            due[0] += SAMPLE_S

    base.setTimeStepCB(each_step)
    base.runSimulation()
    x = np.array(fm.getFieldBuffer("position"), copy=True).reshape(-1, 3)[:n]
    v = np.array(fm.getFieldBuffer("velocity"), copy=True).reshape(-1, 3)[:n]
    base.cleanup()
    return x, float(np.linalg.norm(v, axis=1).max())


def run(layers: int, viscosity: float, work: Path) -> dict:
    import pysplishsplash as sph

    s = DEPTH / layers
    work.mkdir(parents=True, exist_ok=True)
    cube_obj(work / "cube.obj")
    wall = time.perf_counter()
    (work / "settle.json").write_text(json.dumps(scene(s, viscosity, gate=True), indent=1))
    settled, settle_vmax = simulate(sph, work / "settle.json", SETTLE_S)
    print(f"settled: {len(settled)} particles, largest speed {settle_vmax:.3f} m/s", flush=True)
    vol, h = np.full(len(settled), s**3), np.full(len(settled), 2 * s)
    t, levels, lee = [], [], []

    def gauge(now, x):
        t.append(now)
        levels.append([V.water_level(x, vol, h, (px, TANK[2] / 2), 0.8) for px in V.PROBES[:3]])
        lee.append([V.water_level(x, vol, h, at, 1.0) for at in V.LEE])

    (work / "release.json").write_text(json.dumps(scene(s, viscosity, gate=False), indent=1))
    simulate(sph, work / "release.json", END_S, start=settled, sample=gauge)
    return {
        "code": f"SPlisHSPlasH {importlib.metadata.version('pysplishsplash')} DFSPH, volume maps",
        "date": datetime.date.today().isoformat(),
        "commit": V._commit(),
        "layers": layers,
        "spacing": s,
        "viscosity": viscosity,
        "particles": len(settled),
        "mrsph_particles": lattice(s)[2],
        "settle_vmax": settle_vmax,
        "wall_s": round(time.perf_counter() - wall, 1),
        **measured(np.array(t), np.array(levels), np.array(lee)),
    }


def measured(t: np.ndarray, levels: np.ndarray, lee: np.ndarray) -> dict:
    """What a peer run stores of its gauges (``levels``: H1-H3 and more by column, ``lee``:
    ``validate.LEE``'s, against ``t``): the heights, H3's mean over its window, when each lee
    point is reached and when H1-H3 stand 2 and 6 cm, beside the data's."""
    exp = V.read_csv(V.DATA / "kleefsman_2005_heights.csv")
    window = (t >= V.H3_WINDOW[0]) & (t <= V.H3_WINDOW[1])
    return {
        "t": t.round(5).tolist(),
        "level": levels.T.round(5).tolist(),
        "h3_mean": float(levels[window, 2].mean()),
        "lee": [{"at": at, "arrival": V.first_crossing(t, lee[:, k], V.WET)} for k, at in enumerate(V.LEE)],
        "probes": [
            {
                "name": name,
                "arrival": V.first_crossing(t, levels[:, k], V.WET),
                "body": V.first_crossing(t, levels[:, k], V.BODY),
                "arrival_exp": V.first_crossing(exp["t"], exp[name], V.WET),
                "body_exp": V.first_crossing(exp["t"], exp[name], V.BODY),
            }
            for k, name in enumerate(("H1", "H2", "H3"))
        ],
    }


def summary(out: dict, cost: str) -> None:
    """A stored run in four lines: H1-H3's arrivals against the data's, H3's mean and ``cost``."""
    for p in out["probes"]:
        print(f"{p['name']}: 2 cm at {p['arrival']:.3f} s (data {p['arrival_exp']:.3f}), ", end="")
        print(f"6 cm at {p['body']:.3f} s (data {p['body_exp']:.3f})")
    print(f"H3 mean over 0.3-0.7 s: {out['h3_mean']:.3f} m; {cost}")


def name(layers: int, viscosity: float) -> str:
    return f"box-splishsplash-{layers}-nu{viscosity:g}"


HOLD_S = 0.03  # a level held this long is the water's, not a jet's tip or a splash passing


def held_crossing(t: np.ndarray, f: np.ndarray, level: float, hold: float = HOLD_S) -> float | None:
    """The first sample from which f stays at or above ``level`` for ``hold`` s; None if never."""
    t, f = np.asarray(t), np.asarray(f)
    for i in np.flatnonzero(f >= level):
        if t[i] + hold > t[-1]:
            return None
        if (f[(t >= t[i]) & (t <= t[i] + hold)] >= level).all():
            return float(t[i])
    return None


def _s(x: float | None) -> str:
    return "-" if x is None else f"{x:.3f}"


def row(label: str, t, levels) -> str:
    """A table row: when H1-H3 first stand 2 and 6 cm, when H1 first holds them, and H3's mean
    height over its window."""
    t = np.asarray(t)
    cells = []
    for lv in levels[:3]:
        wet, body = (V.first_crossing(t, np.asarray(lv), level) for level in (V.WET, V.BODY))
        cells.append(f"{_s(wet)} / {_s(body)} s")
    cells.insert(1, " / ".join(_s(held_crossing(t, levels[0], level)) for level in (V.WET, V.BODY)) + " s")
    window = (t >= V.H3_WINDOW[0]) & (t <= V.H3_WINDOW[1])
    return f"| {label} | {' | '.join(cells)} | {np.asarray(levels[2])[window].mean():.3f} m |"


def report() -> None:
    """The arrivals of every stored peer run beside mrsph's uniform runs at the scene's spacing,
    and the figure: H1-H3 against time, the data, mrsph's solvers and the peer's runs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sys.path.insert(0, str(V.ROOT))  # the scene's spacing, through mrsph's loader
    peers = [json.loads(p.read_text()) for p in sorted(OUT.glob("box-splishsplash-*.json"))]
    vofs = sorted((json.loads(p.read_text()) for p in OUT.glob("box-openfoam-*.json")), key=lambda r: r["layers"])
    spacing = V.scene_spacing("box", 3)
    ours, finer = {}, {}  # mrsph's uniform runs at the scene's spacing (drawn) and finer (tabled)
    for solver in ("wcsph", "dfsph", "pbf"):
        for path in sorted(V.CACHE.glob(f"box-3d-{solver}-uniform-s*.json")):
            run = json.loads(path.read_text())
            if run.get("sets") or run["spacing"] > spacing * 1.001:
                continue
            layers = round(DEPTH / run["spacing"])
            (ours if layers == round(DEPTH / spacing) else finer)[f"mrsph {solver}, {layers} layers"] = run
    exp = V.read_csv(V.DATA / "kleefsman_2005_heights.csv")
    head = ("run", "H1 2 cm / 6 cm", "H1 held 30 ms: 2 cm / 6 cm", "H2 2 cm / 6 cm", "H3 2 cm / 6 cm")
    print(f"| {' | '.join(head)} | H3 mean 0.3-0.7 s | run on |")
    print("|---|---|---|---|---|---|---|")
    print(row("MARIN's data", exp["t"], [exp[k] for k in ("H1", "H2", "H3")]) + " Kleefsman et al. 2005 |")
    for label, r in {**ours, **finer}.items():
        print(row(label, r["t"], r["level"]) + f" {r['date']}, {r['commit']} |")
    for r in peers:
        label = f"SPlisHSPlasH DFSPH, {r['layers']} layers, ν = {r['viscosity']:g} m²/s"
        print(row(label, r["t"], r["level"]) + f" {r['date']}, {r['commit']} |")
    for r in vofs:
        label = f"OpenFOAM interFoam (VOF), {r['layers']} cells deep, {r['walls']} walls"
        print(row(label, r["t"], r["level"]) + f" {r['date']}, {r['commit']} |")
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6), sharey=True)
    for k, (ax, probe) in enumerate(zip(axes, ("H1", "H2", "H3"))):
        ax.plot(exp["t"], exp[probe], "k", lw=1.6, label="MARIN (Kleefsman et al. 2005)")
        for (label, r), c in zip(ours.items(), ("tab:blue", "tab:orange", "tab:green")):
            ax.plot(r["t"], r["level"][k], color=c, lw=1, label=label)
        for r, ls in zip(peers, ("--", ":", "-.")):
            label = f"SPlisHSPlasH, {r['layers']} layers, ν {r['viscosity']:g}"
            ax.plot(r["t"], r["level"][k], "m", ls=ls, lw=1.2, label=label)
        no_slip = [r for r in vofs if r["walls"] == "no slip"][::-1]  # the finest darkest; slip in the table
        for r, c in zip(no_slip, ("0.2", "0.45", "0.65", "0.8")):
            ax.plot(r["t"], r["level"][k], color=c, ls="--", lw=1.1, label=f"OpenFOAM VOF, {r['layers']} cells deep")
        ax.set_title(f"{probe} (x = {V.PROBES[k]} m)")
        ax.set_xlim(0, 1.3)
        ax.set_ylim(-0.01, 0.45)  # the VOF runs' splashes at H1 reach 0.7 m
        ax.set_xlabel("t (s)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("water height (m)")
    axes[0].legend(fontsize=7, loc="upper left")
    title = "MARIN's box: mrsph, a second SPH code at the same spacing and a VOF code (tools/peer_box.py --report)"
    fig.suptitle(title, fontsize=10)
    stamps = sorted({f"{r['date']}, {r['commit']}" for r in ours.values()})
    theirs = [f"{r['date']}, {r['commit']} (--layers {r['layers']} --viscosity {r['viscosity']:g})" for r in peers]
    foot = f"mrsph: {'; '.join(stamps)} (python3 tools/validate.py --case box). "
    foot += f"SPlisHSPlasH: {'; '.join(theirs)} (tools/peer_box.py). "
    vof_stamps = sorted({f"{r['date']}, {r['commit']}" for r in vofs})
    foot += f"OpenFOAM: {'; '.join(vof_stamps)} (tools/peer_vof.py --layers N)"
    fig.text(0.99, 0.005, "\n".join(textwrap.wrap(foot, 200)), ha="right", va="bottom", fontsize=7, color="0.4")
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(V.FIGURES / "box_peer_3d.png", dpi=110)
    print(f"wrote {V.FIGURES / 'box_peer_3d.png'}")


def fail(message: str) -> None:
    """A bad argument, a missing peer code or its failed run: one line, exit status 2."""
    print(message, file=sys.stderr)
    sys.exit(2)


def preload() -> None:
    """Run again with the system's libGLdispatch preloaded: the wheel bundles half of libglvnd,
    and its import crashes in the other half's initialiser unless one copy serves both."""
    if GL_DISPATCH.exists() and str(GL_DISPATCH) not in os.environ.get("LD_PRELOAD", ""):
        env = {**os.environ, "LD_PRELOAD": f"{GL_DISPATCH} {os.environ.get('LD_PRELOAD', '')}".strip()}
        os.execve(sys.executable, [sys.executable, *sys.argv], env)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--layers", type=int, default=27, help="particles over the water's depth (27: the scene's)")
    ap.add_argument("--viscosity", type=float, default=0.01, help="SPlisHSPlasH's standard viscosity, m²/s (0: none)")
    ap.add_argument("--work", type=Path, default=None, help="scratch folder for the scenes and volume maps")
    ap.add_argument("--report", action="store_true", help="the table and figure from the stored runs")
    args = ap.parse_args()
    if args.report:
        report()
        return
    if args.layers < MIN_LAYERS:
        fail(f"--layers {args.layers}: expected at least {MIN_LAYERS} (the box is 161 mm high, the water 550 mm deep)")
    if not args.viscosity >= 0:
        fail(f"--viscosity {args.viscosity:g}: expected a kinematic viscosity >= 0 (m²/s)")
    preload()
    try:
        import pysplishsplash  # noqa: F401
    except ImportError:
        fail("pysplishsplash is not installed here: run this tool in its own environment (see its docstring)")
    work = args.work or Path(tempfile.gettempdir()) / f"peer_box_{args.layers}"
    out = run(args.layers, args.viscosity, work)
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / f"{name(args.layers, args.viscosity)}.json").write_text(json.dumps(out))
    summary(out, f"{out['wall_s']} s")


if __name__ == "__main__":
    main()

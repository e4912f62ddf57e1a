"""Every pressure solver against published experiments, in 2D and 3D, uniform and adaptive.

    python3 tools/validate.py                    # every full run not yet cached, then every figure and the table
    python3 tools/validate.py --quick            # the coarse runs tests/test_validation.py makes
    python3 tools/validate.py --case pressure --dim 2 --solver dfsph --mode uniform --force
    python3 tools/validate.py --case box --spacing 0.04 --solver wcsph --mode uniform   # a resolution study point
    python3 tools/validate.py --report           # figures and table from the cache alone

The cases (docs/validation.md says what each measures and why):

- ``tank``: water 80 particles deep at rest (scenes/tank_rest_*, settled 1 s before t = 0), against the
  hydrostatic profile;
- ``front``: Martin & Moyce's (1952) column a x 2a (scenes/dam_break_front_*): surge front and the
  residual height at the wall;
- ``pressure``: Lobovsky et al.'s (2014) H = 0.3 m column onto a wall (scenes/dam_break_pressure_*):
  the pressure at the wall's four sensors;
- ``box``: MARIN's 3D dam break past a box (Kleefsman et al. 2005, scenes/dam_break_box_3d): the
  water height at the four probes, the pressure at the box's eight sensors, and when the water
  reaches six points between the box and the far wall (``LEE``).

A run is one case, dimension, solver (``fluid.solver``) and mode (``uniform``, or ``adaptive``:
``adaptivity.enabled = true``, the same finest spacing, coarse where the scene's criteria do not ask
for it). Each runs in its own process on one thread, ``--jobs`` at a time, and writes what it measured
to docs/validation/runs/KEY.json (the key names the spacing, so quick and full runs sit side by side),
which the figures and the table (tools/validate_report.py, into docs/validation/) read, each run at
the finest spacing cached for it, so that they are remade without running anything again. The data
(validation/*.csv) name their source in their header.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "validation"
FIGURES = ROOT / "docs" / "validation"
CACHE = FIGURES / "runs"
G, RHO0 = 9.81, 1000.0
SOLVERS = ("wcsph", "dfsph", "pbf")
MODES = ("uniform", "adaptive")
CASES = {"tank": (2, 3), "front": (2, 3), "pressure": (2, 3), "box": (3,)}
SCENES = {
    "tank": "tank_rest_{d}d",
    "front": "dam_break_front_{d}d",
    "pressure": "dam_break_pressure_{d}d",
    "box": "dam_break_box_3d",
}
#: keys a case sets before the run's own ``--set`` (which may override them): the deep tank starts
#: settled, 1 s damped before t = 0 (``fluid.settle``), for a seeded lattice is not the discrete
#: equilibrium: a 3D cubic lattice under 80 layers rearranges, a level interface relaxes, and the
#: energy set free rings on in the column's first acoustic mode (docs/validation.md)
CASE_SETS = {"tank": ["fluid.settle=1.0"]}
#: the quick runs' spacing, a multiple of the scene's (pbf.dt stays the scene's: scaled with the spacing,
#: the 2D tank at rest moved at 0.011 sqrt(gH) for 0.0017 at the scene's dt)
QUICK = {"tank": 2.0, "front": 2.0, "pressure": 2.0, "box": 27 / 14}  # box: 0.55 m / 14, whole layers


def read_csv(path: Path) -> dict[str, np.ndarray]:
    """A data file: '#' lines (its source), a header, then numbers."""
    rows = [ln for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]
    names = rows[0].split(",")
    table = np.array([[float(v) for v in r.split(",")] for r in rows[1:]])
    return {n: table[:, i] for i, n in enumerate(names)}


# ================================================================== measures (numpy only)
def poly6(r: np.ndarray, h: np.ndarray, dim: int) -> np.ndarray:
    """The poly6 kernel W(r, h), normalised, zero beyond h."""
    c = 4.0 / (math.pi * h**8) if dim == 2 else 315.0 / (64.0 * math.pi * h**9)
    return np.where(r < h, c * np.clip(h * h - r * r, 0.0, None) ** 3, 0.0)


def ritter_depth(x: np.ndarray, t: np.ndarray, depth: float) -> np.ndarray:
    """Ritter's dam break on a dry bed (1892), the shallow-water solution for an ideal fluid: the
    water's depth ``x`` m downstream of the gate at ``t`` s after ``depth`` m of water was
    released at once, (2 c0 - x/t)^2 / 9g with c0 = sqrt(g depth), dry past the front x = 2 c0 t."""
    c0 = math.sqrt(G * depth)
    speed = np.asarray(x, float) / np.asarray(t, float)
    return np.where(speed < 2.0 * c0, np.minimum((2.0 * c0 - speed) ** 2 / (9.0 * G), depth), 0.0)


def shepard(points: np.ndarray, x: np.ndarray, vol: np.ndarray, h: np.ndarray, f: np.ndarray) -> np.ndarray:
    """f interpolated at ``points`` as sum V W f / sum V W over the particles (each with its own
    level's support h): at a wall the sum covers the fluid side only, which the mirror images
    would mirror, so this is the wall's value; 0 where no particle reaches."""
    out = np.zeros(len(points))
    for i, q in enumerate(points):
        r = np.linalg.norm(x - q, axis=1)
        near = r < h
        w = vol[near] * poly6(r[near], h[near], x.shape[1])
        out[i] = float((w * f[near]).sum() / w.sum()) if w.sum() > 0 else 0.0
    return out


def volume_fraction(points: np.ndarray, x: np.ndarray, vol: np.ndarray, h: np.ndarray) -> np.ndarray:
    """sum_j V_j W(|q - x_j|, h_j) at each point: 1 inside the water, 0 outside."""
    out = np.zeros(len(points))
    for i, q in enumerate(points):
        r = np.linalg.norm(x - q, axis=1)
        near = r < h
        out[i] = float((vol[near] * poly6(r[near], h[near], x.shape[1])).sum())
    return out


def water_level(x: np.ndarray, vol: np.ndarray, h: np.ndarray, at: tuple, top: float, wall: bool = False) -> float:
    """The water's height on the vertical through ``at`` (x, or x and z), as a wave gauge reads it:
    from the floor up, the first height where the volume fraction falls below 1/2, the particles
    mirrored across the floor as the solvers mirror them (so a film one particle thick reads its
    thickness), and across the wall x = 0 too with ``wall``; spray passing above does not count. 0
    where the floor is dry."""
    horizontal = [0] if x.shape[1] == 2 else [0, 2]
    near = np.ones(len(x), bool)
    for k, c in zip(horizontal, at):
        near &= np.abs(x[:, k] - c) < h
    if not near.any():
        return 0.0
    xs, vs, hs = x[near], vol[near], h[near]
    for axis in (1, 0) if wall else (1,):
        mirrored = xs.copy()
        mirrored[:, axis] *= -1.0
        xs, vs, hs = np.concatenate([xs, mirrored]), np.concatenate([vs, vs]), np.concatenate([hs, hs])
    step = 0.25 * float(hs.min())
    ys = np.arange(0.0, top + step, step)
    pts = np.zeros((len(ys), x.shape[1]))
    for k, c in zip(horizontal, at):
        pts[:, k] = c
    pts[:, 1] = ys
    return surface_height(ys, volume_fraction(pts, xs, vs, hs))


def surface_height(ys: np.ndarray, vf: np.ndarray) -> float:
    """The gauge's rule on the water's fraction ``vf`` at heights ``ys`` (rising from the floor):
    the first height where it falls below 1/2, interpolated between samples; 0 where the lowest
    is dry, the top where none is. Spray above the first dry sample does not count."""
    dry = np.flatnonzero(vf < 0.5)
    if not len(dry):
        return float(ys[-1])
    k = int(dry[0])
    if k == 0:
        return 0.0
    return float(ys[k - 1] + (vf[k - 1] - 0.5) / (vf[k - 1] - vf[k]) * (ys[k] - ys[k - 1]))


def front_position(x: np.ndarray, s: np.ndarray) -> float:
    """The surge front: the largest x of a particle with at least two others within 1.5 of its
    spacings (spray ahead of the surge is not the front), plus half its spacing."""
    from scipy.spatial import cKDTree

    tree = cKDTree(x)
    for i in np.argsort(-x[:, 0]):
        if len(tree.query_ball_point(x[i], 1.5 * s[i])) >= 3:
            return float(x[i, 0] + 0.5 * s[i])
    return 0.0


def first_crossing(t: np.ndarray, f: np.ndarray, level: float) -> float | None:
    """The first time f reaches ``level``, interpolated between samples; None if it never does."""
    k = np.flatnonzero(f >= level)
    if not len(k):
        return None
    k = int(k[0])
    if k == 0:
        return float(t[0])
    return float(t[k - 1] + (level - f[k - 1]) / (f[k] - f[k - 1]) * (t[k] - t[k - 1]))


def impact(T: np.ndarray, P: np.ndarray, arrive: float = 0.1, length: float = 3.0) -> dict:
    """A sensor's first impact: arrival (P first at ``arrive``), peak and mean of P over ``length``
    from its own arrival (so a front late by a gate's opening reads the same impact)."""
    t0 = first_crossing(T, P, arrive)
    if t0 is None:
        return {"arrival": None, "peak": float(P.max()), "mean": 0.0}
    win = (T >= t0) & (T <= t0 + length)
    return {"arrival": t0, "peak": float(P[win].max()), "mean": float(P[win].mean())}


def shifted_rms(T: np.ndarray, Z: np.ndarray, T_exp: np.ndarray, Z_exp: np.ndarray) -> tuple[float, float, float]:
    """The relative RMS of Z against the data, unshifted, and after the one time shift that makes it
    least: (rms, rms shifted, shift). The shift stands for the experiment's gate opening, which can
    only make the experiment late, so the run may be shifted later (dT <= 0, at most 0.5), never
    earlier: a front that lags is not shifted onto the data."""

    def rms(dT: float) -> float:
        return float(np.sqrt(np.mean(((np.interp(T_exp + dT, T, Z) - Z_exp) / Z_exp) ** 2)))

    shifts = np.linspace(-0.5, 0.0, 101)
    errs = [rms(d) for d in shifts]
    k = int(np.argmin(errs))
    return rms(0.0), errs[k], float(shifts[k])


def _real(sim) -> dict:
    """The real particles: x (float64), spacing s and support h of each one's level, volume m / rho."""
    p = sim.particles(virtual=False)
    lv = p["level"].astype(int)
    return {
        "x": p["x"].astype(np.float64),
        "v": p["v"].astype(np.float64),
        "p": p["p"].astype(np.float64),
        "vol": (p["m"] / p["rho"]).astype(np.float64),
        "s": float(sim.s0) * 2.0**lv,
        "h": float(sim.h0) * 2.0**lv,
    }


def _each_step(sim, seconds: float):
    """``sim.advance(seconds)`` a step at a time, yielding each step's dt (advance has no hook
    between its steps; its counters are collected by the next advance or stats row)."""
    end = sim.time + seconds
    while sim.time < end - 1e-12:
        yield sim.step(max_dt=end - sim.time)
    sim.time = max(sim.time, end)


# ================================================================== the cases
def run_tank(sim, scene) -> dict:
    """From the settled start (``CASE_SETS``), 2 s, then 0.2 s sampled every 10 ms: the mean
    speed over sqrt(g H) and the pressure's RMS deviation from rho0 g (H - y), over every
    particle and sample, over rho0 g H; and the pressure by depth, 20 layers, each the mean over
    its particles and every step of the 0.2 s (weighted by dt)."""
    dim = scene.dim
    H = float(scene.data["fluid"]["blocks"][0]["max"][1])
    lo = np.asarray(scene.data["domain"]["min"], float)
    out = {"H": H, "t": [], "speed": []}
    while sim.time < 2.0 - 1e-9:
        sim.advance(0.05)
        r = _real(sim)
        out["t"].append(sim.time)
        out["speed"].append(float(np.linalg.norm(r["v"], axis=1).mean() / math.sqrt(G * H)))
    speeds, errs, bins = [], [], np.zeros((2, 20))
    edges = np.linspace(0.0, H, 21)
    for _ in range(20):
        for dt in _each_step(sim, 0.01):
            # the layers' pressure at every step, weighted by its dt: dfsph's pressure swings from
            # step to step (a layer's by a few %, at times 20 %), so a mean over 20 samples moved
            # with the samples' phase (the 2D tank's read 0.9 to 5.6 % off for the same code)
            p = sim.particles(virtual=False)
            k = np.clip(np.digitize(p["x"][:, 1], edges) - 1, 0, 19)
            bins[0] += dt * np.bincount(k, p["p"], 20) / np.maximum(np.bincount(k, None, 20), 1)
            bins[1] += dt
        r = _real(sim)
        x, s = r["x"], r["s"]
        cols = np.floor((x[:, 0] - lo[0]) / (2 * sim.s0)).astype(int)
        if dim == 3:
            cols = cols * 100000 + np.floor((x[:, 2] - lo[2]) / (2 * sim.s0)).astype(int)
        tops = [np.max(x[cols == c, 1] + 0.5 * s[cols == c]) for c in np.unique(cols)]
        surface = float(np.mean(tops))
        exact = RHO0 * G * np.clip(surface - x[:, 1], 0.0, None)
        speeds.append(float(np.linalg.norm(r["v"], axis=1).mean()))
        errs.append(np.mean((r["p"] - exact) ** 2))
        out["surface"] = surface
    out["speed_ratio"] = float(np.mean(speeds) / math.sqrt(G * H))
    out["pressure_rms"] = float(math.sqrt(np.mean(errs)) / (RHO0 * G * H))
    out["profile_y"] = (0.5 * (edges[1:] + edges[:-1])).tolist()
    out["profile_p"] = (bins[0] / bins[1] / (RHO0 * G * H)).tolist()
    return out


def run_front(sim, scene) -> dict:
    """The surge front Z = x/a and the column's height at the wall over 2a (a gauge half a spacing
    from the wall), against T = t sqrt(2g/a), sampled every 2 ms to T = 3.2, against Martin & Moyce."""
    a = float(scene.data["fluid"]["blocks"][0]["max"][0])
    scale = math.sqrt(2 * G / a)
    T, Z, eta = [0.0], [1.0], [1.0]
    while T[-1] < 3.2:
        sim.advance(0.002)
        r = _real(sim)
        x, s = r["x"], r["s"]
        T.append(sim.time * scale)
        Z.append(front_position(x, s) / a)
        at = (0.5 * sim.s0,) + ((0.5 * float(scene.data["domain"]["max"][2]),) if scene.dim == 3 else ())
        eta.append(water_level(x, r["vol"], r["h"], at, 2.5 * a, wall=True) / (2 * a))
    exp = read_csv(DATA / "martin_moyce_1952_front.csv")
    keep = exp["T"] > 0
    rms, rms_shifted, shift = shifted_rms(np.array(T), np.array(Z), exp["T"][keep], exp["Z"][keep])
    return {"a": a, "T": T, "Z": Z, "eta": eta, "rms": rms, "rms_shifted": rms_shifted, "shift": shift}


#: Lobovsky et al.'s sensors on the far wall: heights (m) of sensors 1-4 (the 3D ones on the centre line)
SENSOR_HEIGHTS = (0.003, 0.015, 0.03, 0.08)


def run_pressure(sim, scene) -> dict:
    """The wall pressure at the four sensors every 1 ms to t = 1.2 s (T = t sqrt(g/H) = 6.9), as
    P = p / (rho0 g H), and each one's first impact against the data's."""
    H = float(scene.data["fluid"]["blocks"][0]["max"][1])
    top = np.asarray(scene.data["domain"]["max"], float)
    pts = np.array([[top[0], y] + ([0.5 * top[2]] if scene.dim == 3 else []) for y in SENSOR_HEIGHTS])
    T, P = [], []
    while sim.time < 1.2 - 1e-9:
        sim.advance(0.001)
        r = _real(sim)
        near = r["x"][:, 0] > top[0] - r["h"]
        T.append(sim.time * math.sqrt(G / H))
        P.append((shepard(pts, r["x"][near], r["vol"][near], r["h"][near], r["p"][near]) / (RHO0 * G * H)).tolist())
    T, P = np.array(T), np.array(P)
    exp = read_csv(DATA / "lobovsky_2014_h300_pressure.csv")
    out = {"H": H, "T": T.tolist(), "P": P.T.tolist(), "sensors": []}
    for k, name in enumerate(("P1", "P2", "P3", "P4")):
        out["sensors"].append({"sim": impact(T, P[:, k]), "exp": impact(exp["T"], exp[name])})
    return out


#: MARIN's probes H1-H4: x (m), on the tank's centre line z = 0.5 m
PROBES = (0.496, 0.992, 1.488, 2.638)
WET = 0.02  # m: a probe is reached when its water first stands this high
#: m: a probe's body of water has come when it first stands this high: above the thin film that
#: leads the experiment's front (at H3 2 mm to 2 cm in about 0.03 s), which a run's front, a particle
#: thick, cannot carry
BODY = 0.06
#: s: H3's water after the front has passed and before the water piled against the box comes back
#: to it, over which its mean height is read against the data's and Ritter's
H3_WINDOW = (0.3, 0.7)
#: where the water that reaches H1 comes from, (x, z) in m: the far wall x = 0 in the stream that
#: passes beside the box (z = 0.15 m); 1.5 mm inside the box's shadow (its side at z = 0.2985),
#: which a stream spreading sideways into the lee wets first; the centre line at the far wall and
#: between it and H1
LEE = ((0.05, 0.15), (0.2, 0.3), (0.35, 0.3), (0.05, 0.5), (0.2, 0.5), (0.35, 0.5))


#: MARIN's pressure sensors on the box, (x, y, z) in m (validation/kleefsman_2005_pressure.csv): P1-P4
#: on the face towards the reservoir, P5-P8 on the top, each a few cm off the centre line z = 0.5
BOX_SENSORS = (
    *[(0.8245, y, 0.5325) for y in (0.021, 0.061, 0.101, 0.141)],
    *[(x, 0.161, 0.4745) for x in (0.8035, 0.7635, 0.7235, 0.6835)],
)
RISE = 1000.0  # Pa: the water has reached a sensor when its pressure first stands this high (0.1 m of head)
IMPACT_S = 0.1  # s: a sensor's first impact, from its arrival, over which its peak and mean are taken


def run_box(sim, scene) -> dict:
    """The water height at H1-H4 every 2 ms to 1.5 s, against MARIN's; each probe's arrival; the
    pressure at the box's sensors (``BOX_SENSORS``) and each one's first impact against the data's;
    and when the water reaches each point of ``LEE`` (the way it comes to H1)."""
    zc = 0.5 * float(scene.data["domain"]["max"][2])
    t, levels, tips = [0.0], [[0.0, 0.0, 0.0, 0.55]], [float(scene.data["fluid"]["blocks"][0]["min"][0])]
    lee = [[0.0] * len(LEE)]
    sensors, pressures = np.array(BOX_SENSORS), [[0.0] * len(BOX_SENSORS)]
    while t[-1] < 1.5 - 1e-9:
        sim.advance(0.002)
        r = _real(sim)
        t.append(sim.time)
        levels.append([water_level(r["x"], r["vol"], r["h"], (px, zc), 0.8) for px in PROBES])
        lee.append([water_level(r["x"], r["vol"], r["h"], at, 1.0) for at in LEE])
        near = np.linalg.norm(r["x"] - sensors.mean(axis=0), axis=1) < 0.2 + r["h"]  # every sensor's support
        pressures.append(shepard(sensors, r["x"][near], r["vol"][near], r["h"][near], r["p"][near]).tolist())
        # the front's tip along the centre line (within a coarse support of it), x reversed
        lane = np.abs(r["x"][:, 2] - zc) < 2 * sim.h0
        flipped = r["x"][lane] * np.array([-1.0, 1.0, 1.0])
        tips.append(-front_position(flipped, r["s"][lane]) if lane.any() else 0.0)
    t, levels = np.array(t), np.array(levels)
    exp = read_csv(DATA / "kleefsman_2005_heights.csv")
    out = {"t": t.tolist(), "level": levels.T.tolist(), "tip": tips, "probes": []}
    out["lee"] = [{"at": at, "arrival": first_crossing(t, np.array(f), WET)} for at, f in zip(LEE, zip(*lee))]
    pressures = np.array(pressures)
    out["pressure"] = np.round(pressures.T, 1).tolist()
    box = read_csv(DATA / "kleefsman_2005_pressure.csv")
    out["sensors"] = [
        {"sim": impact(t, pressures[:, k], RISE, IMPACT_S), "exp": impact(box["t"], box[f"P{k + 1}"], RISE, IMPACT_S)}
        for k in range(len(BOX_SENSORS))
    ]
    for k, name in enumerate(("H1", "H2", "H3")):
        te = exp["t"] <= 1.5
        diff = np.interp(exp["t"][te], t, levels[:, k]) - exp[name][te]
        out["probes"].append(
            {
                "arrival": first_crossing(t, levels[:, k], WET),
                "arrival_exp": first_crossing(exp["t"], exp[name], WET),
                "tip": first_crossing(t, -np.array(tips), -PROBES[k]),  # when the tip passes it
                "rms": float(np.sqrt(np.mean(diff**2))),
            }
        )
    return out


MEASURES = {"tank": run_tank, "front": run_front, "pressure": run_pressure, "box": run_box}


# ================================================================== runs
def run_key(case: str, dim: int, solver: str, mode: str, spacing: float, sets: list[str] = ()) -> str:
    """A run's cache name; a run with overrides gets their digest, so that it never replaces the plain run."""
    key = f"{case}-{dim}d-{solver}-{mode}-s{spacing:.5g}"
    if sets:
        import hashlib

        key += "-" + hashlib.sha1("\n".join(sets).encode()).hexdigest()[:8]
    return key


def scene_spacing(case: str, dim: int) -> float:
    from mrsph.scene.config import load_scene

    return float(load_scene(SCENES[case].format(d=dim)).particles.spacing)


def box_reservoir() -> tuple[float, float]:
    """MARIN's reservoir as its scene sets it: where its water ends towards the box (the gate, x in
    m) and how deep it stands."""
    from mrsph.scene.config import load_scene

    block = load_scene(SCENES["box"]).fluid.blocks[0]
    return float(block.min[0]), float(block.max[1])


def run_one(case: str, dim: int, solver: str, mode: str, spacing: float, sets: list[str]) -> dict:
    """One run in this process: the scene with the solver, mode and spacing set; what it measured."""
    sys.path.insert(0, str(ROOT))
    from mrsph.scene.config import load_scene
    from mrsph.simulation import Simulation

    name = SCENES[case].format(d=dim)
    over = [
        f'fluid.solver="{solver}"',
        f"adaptivity.enabled={'true' if mode == 'adaptive' else 'false'}",
        f"particles.spacing={spacing!r}",
        *CASE_SETS.get(case, []),
        *sets,
    ]
    commit = _commit()  # the code this run loads, read now: HEAD may move while it runs
    scene = load_scene(name, over)
    sim = Simulation(scene, arch="cpu", threads=1)
    start = time.perf_counter()
    out = MEASURES[case](sim, scene)
    stats = sim.stats()
    out.update(
        key=run_key(case, dim, solver, mode, spacing, sets),
        case=case,
        dim=dim,
        solver=solver,
        mode=mode,
        spacing=spacing,
        sets=sets,
        scene=name,
        n_real=stats["n_real"],
        # the pressure solve over the whole run: mean iterations a step, solves stopped at their maximum
        solve={k: stats[k] for k in ("density_iterations", "divergence_iterations", "unconverged", "clamped")},
        steps=sim.steps,
        wall_s=time.perf_counter() - start,
        date=datetime.date.today().isoformat(),
        commit=commit,
    )
    return out


def _commit() -> str:
    """HEAD's short hash, "+dirty" when the code, tools or scenes differ from it (the runs
    and figures this command writes do not count)."""
    try:
        git = ["git", "-C", str(ROOT)]
        head = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True)
        dirty = subprocess.run(
            [*git, "status", "--porcelain", "--", "mrsph", "tools", "scenes", "main.py"],
            capture_output=True,
            text=True,
            check=True,
        )
        return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def load_runs(cache: Path) -> dict[str, dict]:
    """Every cached run, by key."""
    return {p.stem: json.loads(p.read_text()) for p in sorted(cache.glob("*.json"))}


def plan(args) -> list[dict]:
    jobs = []
    for case in args.case:
        for dim in CASES[case]:
            if dim not in args.dim:
                continue
            base = scene_spacing(case, dim)
            spacing = args.spacing or (base * QUICK[case] if args.quick else base)
            for solver in args.solver:
                for mode in args.mode:
                    jobs.append(dict(case=case, dim=dim, solver=solver, mode=mode, spacing=spacing, sets=args.sets))
    return jobs


def execute(jobs: list[dict], cache: Path, workers: int, force: bool) -> list[str]:
    """Run the jobs not in the cache (all with ``force``), each in its own process; returns the
    errors, one line each."""
    cache.mkdir(parents=True, exist_ok=True)
    todo = [j for j in jobs if force or not (cache / f"{run_key(**_key_args(j))}.json").exists()]
    errors, running = [], []
    while todo or running:
        while todo and len(running) < max(1, workers):
            job = todo.pop(0)
            cmd = [sys.executable, __file__, "--one", json.dumps(job)]
            running.append((job, subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)))
            print(f"running {run_key(**_key_args(job))}", flush=True)
        job, proc = running.pop(0)
        stdout, stderr = proc.communicate()
        key = run_key(**_key_args(job))
        if proc.returncode != 0:
            errors.append(f"{key}: {(stderr.strip().splitlines() or ['no output'])[-1]}")
            print(f"error: {errors[-1]}", file=sys.stderr, flush=True)
            continue
        result = json.loads(stdout.strip().splitlines()[-1])
        (cache / f"{key}.json").write_text(json.dumps(rounded(result)))
        print(f"done {key}: {result['wall_s']:.0f} s", flush=True)
    return errors


def rounded(value, digits: int = 5):
    """A run's record with its floats to ``digits`` significant digits: the cache is committed, and
    the measures are not read past that."""
    if isinstance(value, float):
        return float(f"{value:.{digits}g}")
    if isinstance(value, list):
        return [rounded(v, digits) for v in value]
    if isinstance(value, dict):
        return {k: rounded(v, digits) for k, v in value.items()}
    return value


def _key_args(job: dict) -> dict:
    return {k: job[k] for k in ("case", "dim", "solver", "mode", "spacing", "sets")}


def _list(kind, choices):
    def parse(text: str):
        items = [kind(v) for v in text.split(",")]
        bad = [v for v in items if v not in choices]
        if bad:
            raise argparse.ArgumentTypeError(f"got {bad}; expected some of {list(choices)}, comma-separated")
        return items

    return parse


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--case", type=_list(str, CASES), default=list(CASES), help="tank, front, pressure, box")
    ap.add_argument("--dim", type=_list(int, (2, 3)), default=[2, 3])
    ap.add_argument("--solver", type=_list(str, SOLVERS), default=list(SOLVERS))
    ap.add_argument("--mode", type=_list(str, MODES), default=list(MODES))
    ap.add_argument("--quick", action="store_true", help="the coarse runs (spacing x2, the box 14 layers deep)")
    ap.add_argument("--spacing", type=float, help="this finest spacing instead of the scene's (a resolution study)")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE", help="a scene override")
    ap.add_argument("--force", action="store_true", help="run again what is cached")
    ap.add_argument("--report", action="store_true", help="figures and table from the cache, nothing run")
    ap.add_argument("--jobs", type=int, default=1, help="runs at a time, one thread each (default 1)")
    ap.add_argument("--one", help=argparse.SUPPRESS)  # a worker: JSON arguments
    args = ap.parse_args(argv)

    if args.one:
        sys.path.insert(0, str(ROOT))
        from mrsph.scene.config import SceneError

        try:
            print(json.dumps(run_one(**json.loads(args.one))), flush=True)
        except SceneError as e:
            print(e, file=sys.stderr)
            return 2
        return 0

    sys.path.insert(0, str(ROOT))
    errors = [] if args.report else execute(plan(args), CACHE, args.jobs, args.force)
    sys.path.insert(0, str(ROOT / "tools"))
    import validate_report

    validate_report.report(load_runs(CACHE), out=FIGURES)
    return 1 if errors else 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())

"""Record a few scenes' particle state after N steps, or compare two such records.

A refactor of the solver must not change what it computes: record the scenes before
the change, record them after, and compare. One thread, so that the order of atomic
additions (the reactions handed to owners) is the same in both runs.

    python3 tools/compare_runs.py record OUT_DIR [--steps 150]
    python3 tools/compare_runs.py compare OLD_DIR NEW_DIR

``record`` writes OUT_DIR/<name>.npz, every attribute of the pool (``save_state``);
``compare`` prints, per scene and attribute, the largest absolute difference (0 means
bit-identical) and exits 1 if any scene differs.
"""

import argparse
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

# (name, scene file, overrides): 2D and 3D, uniform and adaptive, both couplings, an
# emitter and a stirrer among them
RUNS = [
    ("dam_break_2d", "scenes/dam_break_2d.toml", {}),
    ("dam_break_3d", "scenes/dam_break_3d.toml", {"particles.spacing": 0.02}),
    ("demo_2d_wcsph", "scenes/demo_2d.toml", {"fluid.solver": "wcsph"}),
    ("pour_3d", "scenes/pour_3d.toml", {}),
    ("obstacle_3d", "scenes/dam_break_obstacle_3d.toml", {}),
    ("region_2d_symmetric", "scenes/region_2d.toml", {"adaptivity.coupling": "symmetric"}),
    # the implicit solver: uniform, and adaptive with an obstacle and the opening stir
    ("dam_break_2d_dfsph", "scenes/dam_break_2d.toml", {"fluid.solver": "dfsph"}),
    ("demo_2d_dfsph", "scenes/demo_2d.toml", {"fluid.solver": "dfsph"}),
    ("obstacle_3d_dfsph", "scenes/dam_break_obstacle_3d.toml", {"fluid.solver": "dfsph"}),
]


def record(out: pathlib.Path, steps: int, only: str | None = None) -> None:
    from mrsph import runtime
    from mrsph.scene.config import load_scene
    from mrsph.simulation import Simulation

    root = pathlib.Path(__file__).resolve().parents[1]
    out.mkdir(parents=True, exist_ok=True)
    for name, path, overrides in RUNS:
        if only and name not in only.split(","):
            continue
        runtime.reset()
        scene = load_scene(root / path)
        if overrides:
            scene = scene.with_overrides(overrides)
        sim = Simulation(scene, threads=1)
        for _ in range(steps):
            sim.step()
        st = sim.save_state()
        n = st["n"]
        arrays = {k: v[:n] for k, v in st["attributes"].items()}
        arrays["children"] = st["children"][:n]
        arrays["clock"] = np.array(st["clock"], np.float64)
        np.savez(out / f"{name}.npz", **arrays)
        print(f"{name}: {n} slots, t = {sim.time:.6f} s after {steps} steps", flush=True)


def compare(old: pathlib.Path, new: pathlib.Path) -> int:
    bad = 0
    for name, _path, _o in RUNS:
        if not (old / f"{name}.npz").exists() or not (new / f"{name}.npz").exists():
            continue
        a, b = np.load(old / f"{name}.npz"), np.load(new / f"{name}.npz")
        diffs = []
        for k in a.files:
            if a[k].shape != b[k].shape:
                diffs.append(f"{k}: shape {a[k].shape} != {b[k].shape}")
                continue
            d = float(np.max(np.abs(a[k].astype(np.float64) - b[k].astype(np.float64)))) if a[k].size else 0.0
            if d != 0.0:
                diffs.append(f"{k}: max |diff| {d:.3g}")
        bad += bool(diffs)
        print(f"{name}: " + ("bit-identical" if not diffs else "; ".join(diffs)))
    return 1 if bad else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("out", type=pathlib.Path)
    r.add_argument("--steps", type=int, default=150)
    r.add_argument("--only", help="comma-separated names of RUNS to record")
    c = sub.add_parser("compare")
    c.add_argument("old", type=pathlib.Path)
    c.add_argument("new", type=pathlib.Path)
    a = ap.parse_args()
    if a.cmd == "record":
        record(a.out, a.steps, a.only)
        return 0
    return compare(a.old, a.new)


if __name__ == "__main__":
    sys.exit(main())

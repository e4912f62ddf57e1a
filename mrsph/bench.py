"""``python main.py bench``: how fast mrsph runs, and where the time goes.

Each case builds a scene, runs a warm-up (which also compiles every kernel; the compile
time is reported on its own), then times a fixed simulated interval ``repeats`` times
and reports medians: steps per second, particle-steps per second (real particles × steps
/ wall seconds), simulated seconds per wall second, the share of step time per phase
(measured with a device sync around each phase, in one extra profiled run, so that the
timed runs carry no sync overhead), and the peak resident memory of the process.
"""
import argparse
import json
import resource
import statistics
import sys
import time


def _cases(full: bool):
    """(name, scene, overrides, warm-up s, timed s). Dam breaks are timed while the
    column collapses, not on the initial lattice (which is 1.3–2x cheaper)."""
    quick = [
        ("dam_break_2d uniform ~10k", "dam_break_2d", ["particles.spacing=0.0035"], 0.25, 0.05),
        ("dam_break_3d uniform ~25k", "dam_break_3d", [], 0.1, 0.01),
    ]
    if not full:
        return quick
    return quick + [
        ("dam_break_2d uniform ~50k", "dam_break_2d", ["particles.spacing=0.0016"], 0.25, 0.02),
        ("dam_break_3d uniform ~100k", "dam_break_3d", ["particles.spacing=0.0063"], 0.2, 0.01),
    ]


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_case(name, scene_name, overrides, warm, interval, repeats, arch):
    from .config import load_scene
    from .solver import PHASES, Simulation

    scene = load_scene(scene_name, overrides)
    t0 = time.perf_counter()
    sim = Simulation(scene, arch=arch)
    sim.advance(min(warm, 0.01))          # compiles every kernel of the step
    compile_s = time.perf_counter() - t0
    sim.advance(warm)
    state = sim.particles()
    walls, steps_l, reals = [], [], []
    for _ in range(repeats):
        t = time.perf_counter()
        steps = sim.advance(interval)
        walls.append(time.perf_counter() - t)
        steps_l.append(steps)
        reals.append(sim.stats()["n_real"])
    # one profiled run for the phase shares
    sim.profile = True
    sim.timers = {k: 0.0 for k in PHASES}
    sim.advance(interval)
    total = sum(sim.timers.values()) or 1.0
    wall = statistics.median(walls)
    steps = statistics.median(steps_l)
    n_real = statistics.median(reals)
    st = sim.stats()
    return {
        "case": name, "scene": scene_name, "overrides": overrides,
        "n_real": int(n_real), "n_virtual": st["n_virtual"],
        "per_level": [st[f"n_level_{l}"] for l in range(sim.levels)],
        "steps": int(steps), "wall_s": wall,
        "steps_per_s": steps / wall, "particle_steps_per_s": n_real * steps / wall,
        "sim_s_per_wall_s": interval / wall, "compile_s": compile_s,
        "phase_share": {k: v / total for k, v in sim.timers.items() if v > 0},
        "peak_mb": _peak_mb(), "repeats": repeats, "walls": walls,
        "initial_particles": int(len(state["x"])),
    }


def _table(rows) -> str:
    head = f"{'case':34s} {'real':>8s} {'steps/s':>8s} {'Mpart-steps/s':>14s} {'sim s/wall s':>12s} {'compile s':>9s}"
    out = [head, "-" * len(head)]
    for r in rows:
        out.append(f"{r['case']:34s} {r['n_real']:8d} {r['steps_per_s']:8.1f} "
                   f"{r['particle_steps_per_s'] / 1e6:14.2f} {r['sim_s_per_wall_s']:12.3f} {r['compile_s']:9.1f}")
        shares = ", ".join(f"{k} {100 * v:.0f}%" for k, v in sorted(r["phase_share"].items(), key=lambda kv: -kv[1]))
        out.append(f"    phases: {shares}")
    out.append(f"peak memory: {max(r['peak_mb'] for r in rows):.0f} MB")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="main.py bench", description=__doc__.splitlines()[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--full", action="store_true", help="the long set (50k 2D, 100k 3D)")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per case (median)")
    ap.add_argument("--arch", default="cpu", choices=("auto", "cpu", "gpu"))
    ap.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    ap.add_argument("--case", action="append", default=None,
                    help="run only cases whose name contains this text (repeatable)")
    args = ap.parse_args(argv)
    rows = []
    for case in _cases(args.full):
        if args.case and not any(c in case[0] for c in args.case):
            continue
        print(f"running {case[0]} ...", file=sys.stderr, flush=True)
        rows.append(run_case(*case, repeats=args.repeats, arch=args.arch))
    print(_table(rows))
    if args.json:
        import platform
        with open(args.json, "w") as fh:
            json.dump({"machine": platform.processor() or platform.machine(),
                       "cpus": __import__("os").cpu_count(), "cases": rows}, fh, indent=2)
    return 0

"""Plot adaptive against uniform: wall time per simulated second against the finest
resolution, one panel per dimension, written to assets/bench.png.

    python3 tools/plot_bench.py results.json          # from `python3 main.py bench --json results.json`
    python3 tools/plot_bench.py --sweep               # run the pair sweep below first, then plot
    python3 tools/plot_bench.py --sweep --save out/sweep.json --threads 2

The x axis is the finest resolution as the number of particles a uniform run at the
finest spacing holds (each point is labelled with that spacing); the y axis is wall
seconds per simulated second (lower is faster). Only the pair rows of a bench JSON are
plotted (the adaptive and the uniform run of one scene at one finest spacing); a bench
JSON has one pair per dimension (two with --full), so a curve needs the sweep: the
pairs of ``dam_break_obstacle_2d`` and ``_3d`` at three spacings each, with the warm-up
and timed interval of the benchmark's pair cases (the front has reached the block).

Needs matplotlib (requirements-test.txt).
"""

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

DEFAULT_OUT = ROOT / "assets" / "bench.png"
#: Finest spacings of the sweep (m): uniform runs of 6k, 12k and 25k particles in 2D,
#: 2.6k, 6k and 12k in 3D (dam_break_obstacle_*d, two levels).
SWEEP = {2: ("dam_break_obstacle_2d", (0.005, 0.0035, 0.0025)), 3: ("dam_break_obstacle_3d", (0.02, 0.015, 0.012))}
#: Warm-up and timed interval (simulated s) of the sweep: those of the bench's pairs.
SWEEP_TIMES = {2: (0.24, 0.01), 3: (0.2, 0.01)}
STYLE = {
    True: dict(color="tab:orange", marker="o", label="adaptive (2 levels)"),
    False: dict(color="tab:blue", marker="s", label="uniform at the finest spacing"),
}


def sweep(repeats: int, arch: str, threads, scale: float, dims=(2, 3)) -> dict:
    """Run the pair sweep; returns a bench-shaped result ({"cases": rows, "pairs": ...})."""
    from mrsph.cli.bench import run_pair

    rows, pairs = [], []
    for dim in dims:
        scene, spacings = SWEEP[dim]
        warm, interval = SWEEP_TIMES[dim]
        for s in spacings:
            name = f"{scene} s={1e3 * s:g}mm"
            print(f"running {name} ...", file=sys.stderr, flush=True)
            pair_rows, summary = run_pair(
                name, scene, (f"particles.spacing={s}",), warm, interval * scale, repeats, arch, threads
            )
            rows += pair_rows
            pairs.append(summary)
            print(
                f"    adaptive {pair_rows[0]['wall_s']:.3g} s, uniform {pair_rows[1]['wall_s']:.3g} s"
                f" per {interval * scale:g} simulated s: {summary['speedup']:.2f}x",
                file=sys.stderr,
                flush=True,
            )
    return {"cases": rows, "pairs": pairs, "repeats": repeats, "arch": arch, "threads": threads}


def curves(result: dict) -> dict:
    """{dim: {adaptive: [(uniform-equivalent particles, wall s per simulated s, spacing)]}}
    from the pair rows of a bench result, sorted by resolution."""
    out: dict = {}
    for r in result["cases"]:
        if r.get("kind") != "pair":
            continue
        point = (r["uniform_equivalent"], r["wall_s"] / r["interval"], r["finest_spacing"])
        out.setdefault(r["dim"], {}).setdefault(bool(r["adaptive"]), []).append(point)
    for per_dim in out.values():
        for pts in per_dim.values():
            pts.sort()
    return out


def plot(result: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = curves(result)
    if not data:
        raise SystemExit("plot_bench: no pair rows in the results (run the bench's pair cases, or --sweep)")
    dims = sorted(data)
    fig, axes = plt.subplots(1, len(dims), figsize=(5.2 * len(dims), 4.2), squeeze=False)
    for ax, dim in zip(axes[0], dims):
        for adaptive in (False, True):
            pts = data[dim].get(adaptive, [])
            if not pts:
                continue
            n, y, s = zip(*pts)
            ax.plot(n, y, linewidth=1.8, markersize=6, **STYLE[adaptive])
            if not adaptive:
                for xi, yi, si in pts:
                    ax.annotate(
                        f"{1e3 * si:g} mm",
                        (xi, yi),
                        textcoords="offset points",
                        xytext=(4, 6),
                        fontsize=8,
                        color="0.35",
                    )
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{dim}D: dam break onto a block")
        ax.set_xlabel("finest resolution: particles of a uniform run at the finest spacing")
        ax.set_ylabel("wall seconds per simulated second")
        ax.margins(x=0.08, y=0.12)  # room for the spacing labels
        ax.grid(True, which="both", linewidth=0.4, alpha=0.5)
        ax.legend(fontsize=8, loc="upper left")
    machine = f"{result.get('arch', 'cpu')}"
    threads = result.get("threads")
    if threads == "auto":
        machine += ", threads as the app picks them"
    elif threads:
        machine += f", {threads} thread{'s' if threads > 1 else ''}"
    fig.suptitle(f"mrsph: adaptive vs uniform ({machine}; median of {result.get('repeats', '?')})", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    from mrsph.cli.options import threads_arg

    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    ap.add_argument("json", nargs="?", help="a bench result (python3 main.py bench --json FILE)")
    ap.add_argument("--sweep", action="store_true", help="run the pair sweep instead of reading JSON")
    ap.add_argument("--save", metavar="FILE", help="with --sweep: also write its results as JSON")
    ap.add_argument("--repeats", type=int, default=1, help="with --sweep: timed runs per point")
    ap.add_argument(
        "--interval-scale", type=float, default=1.0, help="with --sweep: multiply the timed interval (not the warm-up)"
    )
    ap.add_argument("--dims", type=int, nargs="+", default=[2, 3], choices=(2, 3))
    ap.add_argument("--arch", default="cpu", choices=("auto", "cpu", "gpu"))
    ap.add_argument(
        "--threads",
        type=threads_arg,
        default="auto",
        help="CPU threads: a count, or auto (as the app: one pinned thread for small scenes)",
    )
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="the picture to write")
    args = ap.parse_args(argv)
    if args.sweep == bool(args.json):
        ap.error("give a bench JSON file or --sweep (one of them)")
    if args.sweep:
        result = sweep(args.repeats, args.arch, args.threads, args.interval_scale, tuple(args.dims))
        if args.save:
            Path(args.save).parent.mkdir(parents=True, exist_ok=True)
            Path(args.save).write_text(json.dumps(result, indent=2))
    else:
        result = json.loads(Path(args.json).read_text())
    print(plot(result, args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())

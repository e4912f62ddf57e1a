"""How far MARIN's arrivals move between runs that differ by round-off alone, and whether an
adaptive run's H1 is off its uniform twin's by more than that.

    python3 tools/box_spread.py --jobs 2            # the members not yet cached, then the table and figure
    python3 tools/box_spread.py --solver wcsph --members 3
    python3 tools/box_spread.py --report            # the table and docs/validation/box_spread_3d.png, nothing run

The box (tools/validate.py's ``box`` case, full spacing, 27 layers) is a chaotic flow: the water
reaches H1 after 0.4 s of splashing past the box, and a run whose last bits differ reads H1 up
to 0.03 s apart. So one run of each mode cannot show whether an adaptive run's H1 is 0.02 s of
its uniform twin's. Each member here is the same run with gravity changed in its sixth or
seventh digit (``GRAVITY``; the plain run is the first): it moves a step's bits, not the flow
(an arrival scales as g^-1/2, by under a microsecond). The members are validate.py's runs, kept
in its cache under their override's key; the table gives each probe's arrival over the members
(mean, least and most) and the adaptive runs' mean off the uniform runs', with twice its
standard error.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parent.parent)]
import validate as V  # noqa: E402  (the runs, their cache and the data; mrsph loads the scene)

#: each member's gravity (m/s², downwards); the first is the scene's, whose run is the plain one
GRAVITY = (9.81, 9.81001, 9.80999, 9.81002, 9.80998, 9.81003)
#: what the table reads of a run: H1-H3 first standing 2 cm (the issue's arrival) and H1 6 cm (its body)
MEASURES = (("H1", 0, V.WET), ("H1 6 cm", 0, V.BODY), ("H2", 1, V.WET), ("H3", 2, V.WET))


def member_sets(k: int) -> list[str]:
    """The overrides of member ``k``: none for the first (the plain run), else its gravity."""
    return [] if k == 0 else [f"physics.gravity=[0.0, {-GRAVITY[k]}, 0.0]"]


def jobs(solvers: list[str], modes: list[str], members: int) -> list[dict]:
    """validate.py's jobs: every member of each solver and mode at the scene's spacing."""
    spacing = V.scene_spacing("box", 3)
    return [
        dict(case="box", dim=3, solver=s, mode=m, spacing=spacing, sets=member_sets(k))
        for k in range(members)
        for s in solvers
        for m in modes
    ]


def arrivals(run: dict) -> list[float | None]:
    """When the run's water first stands at each of ``MEASURES``."""
    t = np.asarray(run["t"])
    return [V.first_crossing(t, np.asarray(run["level"][k]), h) for _, k, h in MEASURES]


def members(runs: dict[str, dict], solvers, modes, count: int) -> list[dict]:
    """The members of each solver and mode found in ``runs`` (by validate.py's key)."""
    keys = (V.run_key(**V._key_args(j)) for j in jobs(solvers, modes, count))
    return [runs[k] for k in keys if k in runs]


def gathered(found: list[dict]) -> dict:
    """Each (solver, mode)'s members' arrivals: an array of members by ``MEASURES`` (NaN where a
    probe was never reached)."""
    out = {}
    for run in found:
        row = [math.nan if a is None else a for a in arrivals(run)]
        out.setdefault((run["solver"], run["mode"]), []).append(row)
    return {k: np.array(v) for k, v in out.items()}


def stamp(found: list[dict]) -> str:
    """The members' dates and commits, and the command that makes them."""
    dates, commits = sorted({r["date"] for r in found}), sorted({r["commit"] for r in found})
    return f"{', '.join(dates)}, {', '.join(commits)}: python3 tools/box_spread.py"


def offset(adaptive: np.ndarray, uniform: np.ndarray) -> tuple[float, float]:
    """The adaptive members' mean off the uniform members' and twice its standard error (the
    members' sample spread; NaN with fewer than two of either)."""
    if len(adaptive) < 2 or len(uniform) < 2:
        return float(adaptive.mean() - uniform.mean()), math.nan
    se = math.sqrt(adaptive.var(ddof=1) / len(adaptive) + uniform.var(ddof=1) / len(uniform))
    return float(adaptive.mean() - uniform.mean()), 2.0 * se


def ordered(got: dict) -> list[tuple[str, str]]:
    """The (solver, mode) keys of ``got`` in validate.py's order: wcsph, dfsph, pbf; uniform first."""
    return sorted(got, key=lambda k: (V.SOLVERS.index(k[0]), V.MODES.index(k[1])))


def table(got: dict) -> str:
    """The members' arrivals, one line a solver and mode, then each solver's adaptive offset."""
    exp = V.read_csv(V.DATA / "kleefsman_2005_heights.csv")
    data = [V.first_crossing(exp["t"], exp[f"H{k + 1}"], h) for _, k, h in MEASURES]
    head = "| run | members | " + " | ".join(f"{n} (data {d:.3f} s)" for (n, _, _), d in zip(MEASURES, data)) + " |"
    lines = [head, "|" + "---|" * (2 + len(MEASURES))]
    for solver, mode in ordered(got):
        a = got[solver, mode]
        cells = [f"{np.nanmean(c):.3f} ({np.nanmin(c):.3f}–{np.nanmax(c):.3f})" for c in a.T]
        lines.append(f"| {solver} {mode} | {len(a)} | " + " | ".join(cells) + " |")
    for solver in dict.fromkeys(s for s, _ in ordered(got)):
        if {(solver, "uniform"), (solver, "adaptive")} <= got.keys():
            cells = []
            for k in range(len(MEASURES)):
                d, two_se = offset(got[solver, "adaptive"][:, k], got[solver, "uniform"][:, k])
                cells.append(f"{d:+.3f}" + ("" if math.isnan(two_se) else f" ± {two_se:.3f}"))
            lines.append(f"| {solver}: adaptive off uniform | | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def figure(got: dict, stamp: str, path: Path) -> Path:
    """Each member's H1 arrival (2 cm, 6 cm) by solver and mode, the data's and its ± 0.05 s;
    ``stamp`` at its foot."""
    import validate_report as R  # the solvers' colours and the plotting back end of every validation figure

    plt = R._plt()
    exp = R.marin()
    keys = ordered(got)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6), sharey=False)
    for ax, (col, level) in zip(axes, ((0, V.WET), (1, V.BODY))):
        ref = V.first_crossing(exp["t"], exp["H1"], level)
        ax.axhspan(ref - 0.05, ref + 0.05, color="0.9")
        ax.axhline(ref, color="k", lw=1, label="MARIN (± 0.05 s)")
        for x, key in enumerate(keys):
            ys = got[key][:, col]
            marker = "o" if key[1] == "uniform" else "s"
            ax.plot(
                np.full(len(ys), x), ys, marker, color=R.COLOURS[key[0]], mfc="none" if key[1] == "adaptive" else None
            )
        ax.set_xticks(range(len(keys)), [f"{s}\n{m}" for s, m in keys], fontsize=8)
        ax.set_ylabel(f"H1 first at {level * 100:.0f} cm (s)")
        ax.legend(loc="lower right", fontsize=8)
    fig.suptitle("MARIN's H1 over runs that differ by round-off (gravity's 6th-7th digit), 27 layers", fontsize=9)
    fig.text(0.99, 0.01, stamp, ha="right", va="bottom", fontsize=7, color="0.4")
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--solver", type=V._list(str, V.SOLVERS), default=list(V.SOLVERS))
    ap.add_argument("--mode", type=V._list(str, V.MODES), default=list(V.MODES))
    ap.add_argument("--members", type=int, default=4, help=f"runs of each solver and mode, 2 to {len(GRAVITY)}")
    ap.add_argument("--jobs", type=int, default=1, help="runs at a time, one thread each")
    ap.add_argument("--report", action="store_true", help="the table and figure from the cache, nothing run")
    args = ap.parse_args(argv)
    if not 2 <= args.members <= len(GRAVITY):
        print(f"box_spread.py: --members {args.members}: expected 2 to {len(GRAVITY)}", file=sys.stderr)
        return 2
    errors = [] if args.report else V.execute(jobs(args.solver, args.mode, args.members), V.CACHE, args.jobs, False)
    found = members(V.load_runs(V.CACHE), args.solver, args.mode, args.members)
    if not found:
        print("box_spread.py: no member is cached; run without --report", file=sys.stderr)
        return 2
    got = gathered(found)
    print(table(got))
    print(f"wrote {figure(got, stamp(found), V.FIGURES / 'box_spread_3d.png')}")
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())

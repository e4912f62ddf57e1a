"""The figures and the table of tools/validate.py, from its cached runs (docs/validation/runs/*.json).

    python3 tools/validate.py --report      # every figure (docs/validation/*.png) and the table

Each figure draws the experiment in black and each run in its solver's colour, solid for the
uniform run and dashed for the adaptive one. The table holds every run against its targets
(``TARGETS``; docs/validation.md says where each comes from) and is written to
docs/validation/table.md as well as printed.
"""

from __future__ import annotations

import functools
import math
import textwrap
from pathlib import Path

import numpy as np
from validate import BODY, DATA, H3_WINDOW, MODES, PROBES, SOLVERS, WET, first_crossing, read_csv, ritter_depth

COLOURS = {"wcsph": "C0", "dfsph": "C3", "pbf": "C2"}
STYLES = {"uniform": "-", "adaptive": "--"}
#: the targets: at rest, the mean speed over sqrt(gH) and the pressure's RMS over rho0 g H; the
#: front's relative RMS after one time shift (a position-based solver's apart) and that shift; the first impact's
#: mean pressure at the lowest sensor, relative to the data's; a probe's arrival (s); and how far
#: the adaptive run may be from the uniform one
TARGETS = {
    "speed": 0.005,
    "pressure_rms": 0.05,
    "front": {"wcsph": 0.05, "dfsph": 0.05, "pbf": 0.10},
    "gate_shift": 0.25,  # T: a larger shift would absorb a front 10 % too fast (measured: -0.01 ... -0.18)
    "impact": {"wcsph": 0.15, "dfsph": 0.15},
    "arrival": {"wcsph": 0.05, "dfsph": 0.05},
    "adaptive_front": 0.03,
    "adaptive_arrival": 0.02,
}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _runs(runs: dict, case: str, dim: int):
    """The case's runs in this dimension, by (solver, mode), each at the finest spacing cached for
    it (a full run where one was made, else the quick one); runs with overrides and runs finer
    than the scene's (``--spacing``) are studies, left out (the latter drawn against the spacing)."""
    out: dict = {}
    scene = full_spacing(case, dim)
    for r in runs.values():
        if r["case"] == case and r["dim"] == dim and not r["sets"] and r["spacing"] >= 0.9999 * scene:
            best = out.get((r["solver"], r["mode"]))
            if best is None or r["spacing"] < best["spacing"]:
                out[(r["solver"], r["mode"])] = r
    return out


def twin(runs: dict, r: dict) -> dict | None:
    """An adaptive run's uniform twin: the same case, solver and spacing, uniform."""
    for u in runs.values():
        same = all(u[k] == r[k] for k in ("case", "dim", "solver")) and not u["sets"]
        if same and u["mode"] == "uniform" and math.isclose(u["spacing"], r["spacing"], rel_tol=1e-6):
            return u
    return None


@functools.cache
def full_spacing(case: str, dim: int) -> float:
    """The scene's own spacing: a run at it is a full run, one coarser a quick run."""
    from validate import scene_spacing

    return scene_spacing(case, dim)


def _resolution(r: dict) -> str:
    return "full" if r["spacing"] <= 1.0001 * full_spacing(r["case"], r["dim"]) else "quick"


def _label(r: dict) -> str:
    return f"{r['solver']} {r['mode']}" + (" (full)" if _resolution(r) == "full" else "")


def _save(fig, runs: dict, path: Path) -> Path:
    """The figure stamped (``_stamp``), written to ``path`` and closed."""
    _stamp(fig, runs)
    fig.savefig(path, dpi=90)
    _plt().close(fig)
    return path


def _stamp(fig, runs: dict) -> None:
    """The runs' dates, commits and command at the figure's foot, and the axes laid out above it."""
    plain = [r for r in runs.values() if not r["sets"]]
    dates = sorted({r["date"] for r in plain})
    commits = sorted({r["commit"] for r in plain})
    kinds = sorted({_resolution(r) for r in plain})
    command = " and ".join("python3 tools/validate.py" + (" --quick" if k == "quick" else "") for k in kinds)
    text = f"{', '.join(dates)}, {', '.join(commits)}: {command}"
    # wrapped to the figure's width (about 0.6 em a character at 7 pt, with room), so no line is cut off
    lines = textwrap.wrap(text, max(40, int(fig.get_figwidth() * 72 / (0.65 * 7))))
    fig.text(0.99, 0.005, "\n".join(lines), ha="right", va="bottom", fontsize=7, color="0.4")
    fig.tight_layout(rect=(0, 0.005 + len(lines) * 9.0 / (72 * fig.get_figheight()), 1, 1))


def plot_tank(runs: dict, out: Path) -> Path | None:
    plt = _plt()
    dims = [d for d in (2, 3) if _runs(runs, "tank", d)]
    if not dims:
        return None
    fig, axes = plt.subplots(len(dims), 2, figsize=(11, 3.6 * len(dims)), squeeze=False)
    for row, dim in zip(axes, dims):
        sel = _runs(runs, "tank", dim)
        for (solver, mode), r in sorted(sel.items()):
            kw = dict(color=COLOURS[solver], ls=STYLES[mode], label=_label(r))
            row[0].semilogy(r["t"], np.maximum(r["speed"], 1e-6), **kw)
            row[1].plot(r["profile_p"], np.array(r["profile_y"]) / r["H"], **kw)
        row[0].axhline(TARGETS["speed"], color="k", lw=0.8, ls=":")
        layers = sorted({round(r["H"] / r["spacing"]) for r in sel.values()})
        deep = " or ".join(str(n) for n in layers)
        row[0].set(xlabel="t (s)", ylabel="mean speed / sqrt(gH)", title=f"{dim}D tank {deep} layers deep: settling")
        y = np.linspace(0, 1, 20)
        row[1].plot(1 - y, y, color="k", lw=2.5, alpha=0.35, label="rho0 g (H - y)")
        row[1].set(xlabel="p / (rho0 g H)", ylabel="y / H", title=f"{dim}D: pressure by depth, t = 2-2.2 s")
        row[1].legend(fontsize=7)
    return _save(fig, runs, out / "tank_rest.png")


def plot_front(runs: dict, out: Path) -> Path | None:
    plt = _plt()
    dims = [d for d in (2, 3) if _runs(runs, "front", d)]
    if not dims:
        return None
    exp = read_csv(DATA / "martin_moyce_1952_front.csv")
    fig, axes = plt.subplots(2, len(dims), figsize=(5.8 * len(dims), 7.5), squeeze=False)
    for k, dim in enumerate(dims):
        sel = _runs(runs, "front", dim)
        for (solver, mode), r in sorted(sel.items()):
            kw = dict(color=COLOURS[solver], ls=STYLES[mode], label=f"{_label(r)} (shift {r['shift']:+.2f})")
            axes[0, k].plot(np.array(r["T"]) - r["shift"], r["Z"], **kw)
            axes[1, k].plot(r["T"], r["eta"], color=COLOURS[solver], ls=STYLES[mode], label=_label(r))
        axes[0, k].plot(exp["T"], exp["Z"], "ko", ms=5, label="Martin & Moyce 1952")
        axes[0, k].set(xlabel="T = t sqrt(2g/a) - shift", ylabel="Z = x / a", xlim=(0, 3.2), ylim=(1, 4.2))
        axes[0, k].set_title(f"{dim}D surge front, each run shifted in time by its best gate shift", fontsize=9)
        axes[0, k].legend(fontsize=7)
        axes[1, k].set(xlabel="T = t sqrt(2g/a)", ylabel="height at the wall / 2a", xlim=(0, 3.2), ylim=(0, 1.05))
        axes[1, k].set_title(f"{dim}D residual column (no experimental series shipped)", fontsize=9)
    return _save(fig, runs, out / "front.png")


def running_mean(T: np.ndarray, P: np.ndarray, width: float) -> np.ndarray:
    """P averaged over a window ``width`` wide in T, centred (the acoustic ringing of a weakly
    compressible or an iterated solve averaged out, as a sensor of finite bandwidth would)."""
    n = max(1, int(round(width / float(np.median(np.diff(T))))))
    return np.convolve(P, np.ones(n) / n, mode="same")


def plot_pressure(runs: dict, out: Path, dim: int) -> Path | None:
    plt = _plt()
    sel = _runs(runs, "pressure", dim)
    if not sel:
        return None
    exp = read_csv(DATA / "lobovsky_2014_h300_pressure.csv")
    fig, axes = plt.subplots(4, 1, figsize=(10, 11), sharex=True)
    for k, ax in enumerate(axes):
        ax.plot(exp["T"], exp[f"P{k + 1}"], color="k", lw=1.2, label="Lobovsky et al. 2014 (one event)")
        for (solver, mode), r in sorted(sel.items()):
            T, P = np.asarray(r["T"]), np.asarray(r["P"][k])
            ax.plot(T, P, color=COLOURS[solver], ls=STYLES[mode], lw=0.4, alpha=0.3)
            ax.plot(T, running_mean(T, P, 0.1), color=COLOURS[solver], ls=STYLES[mode], lw=1.3, label=_label(r))
        height = (3, 15, 30, 80)[k]
        ax.set(ylabel="p / (rho0 g H)", xlim=(2, 7), ylim=(-0.1, 3.3))
        ax.set_title(
            f"{dim}D, sensor {k + 1}, {height} mm above the floor (faint: every 1 ms; bold: mean over dT = 0.1)",
            fontsize=9,
        )
    axes[0].legend(fontsize=7, ncol=2)
    axes[-1].set_xlabel("T = t sqrt(g/H)")
    return _save(fig, runs, out / f"pressure_{dim}d.png")


def plot_box(runs: dict, out: Path) -> Path | None:
    plt = _plt()
    sel = _runs(runs, "box", 3)
    if not sel:
        return None
    exp = read_csv(DATA / "kleefsman_2005_heights.csv")
    fig, axes = plt.subplots(4, 1, figsize=(10, 11), sharex=True)
    where = ("x = 0.496 m, behind the box", "x = 0.992 m", "x = 1.488 m", "x = 2.638 m, in the reservoir")
    for k, ax in enumerate(axes):
        ax.plot(exp["t"], exp[f"H{k + 1}"], color="k", lw=1.2, label="MARIN (Kleefsman et al. 2005)")
        for (solver, mode), r in sorted(sel.items()):
            ax.plot(r["t"], r["level"][k], color=COLOURS[solver], ls=STYLES[mode], lw=0.9, label=_label(r))
        ax.set(ylabel="water height (m)", xlim=(0, 1.5))
        ax.set_title(f"probe H{k + 1}, {where[k]}", fontsize=9)
    axes[0].legend(fontsize=7, ncol=2)
    axes[-1].set_xlabel("t (s)")
    return _save(fig, runs, out / "box_3d.png")


#: heights (m) at which the rise figure reads when each probe's water first stands so high
LEVELS = np.round(np.arange(0.005, 0.15001, 0.005), 3)


def rise(t, level, heights=LEVELS) -> list[float | None]:
    """When a probe's water first stands at each of ``heights`` (None: never)."""
    return [first_crossing(np.asarray(t), np.asarray(level), h) for h in heights]


def bodies(t, levels) -> list[float | None]:
    """When the water at H1, H2 and H3 (``levels[0:3]``) first stands ``BODY`` high."""
    return [rise(t, levels[k], (BODY,))[0] for k in range(3)]


@functools.cache
def marin() -> dict[str, np.ndarray]:
    """MARIN's heights: t and H1-H4."""
    return read_csv(DATA / "kleefsman_2005_heights.csv")


def h3_depth(t, level) -> float:
    """H3's mean height over ``H3_WINDOW``, sampled every 10 ms."""
    ts = np.arange(H3_WINDOW[0], H3_WINDOW[1] + 1e-9, 0.01)
    return float(np.interp(ts, np.asarray(t), np.asarray(level)).mean())


@functools.cache
def h3_ritter() -> float:
    """Ritter's depth at H3 (``validate.ritter_depth``) over ``H3_WINDOW`` as ``h3_depth`` reads it."""
    from validate import box_reservoir

    gate, depth = box_reservoir()
    ts = np.arange(H3_WINDOW[0], H3_WINDOW[1] + 1e-9, 0.01)
    return h3_depth(ts, ritter_depth(gate - PROBES[2], ts, depth))


def plot_box_rise(runs: dict, out: Path) -> Path | None:
    """When the water at H1-H3 first stands at each height: a thin leading film shows as a
    flat start, a body that comes late as a curve shifted up."""
    plt = _plt()
    sel = _runs(runs, "box", 3)
    if not sel:
        return None
    exp = marin()
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.6))
    for k, ax in enumerate(axes):
        cm = 100 * LEVELS
        ax.plot(cm, rise(exp["t"], exp[f"H{k + 1}"]), color="k", lw=1.2, label="MARIN (Kleefsman et al. 2005)")
        for (solver, mode), r in sorted(sel.items()):
            ts = [np.nan if v is None else v for v in rise(r["t"], r["level"][k])]
            ax.plot(cm, ts, color=COLOURS[solver], ls=STYLES[mode], lw=0.9, label=_label(r))
        ax.axvline(100 * BODY, color="0.6", lw=0.8, ls=":")
        ax.set(xlabel="water height at the probe (cm)", ylabel="first at that height (s)")
        ax.set_title(f"H{k + 1}, x = {PROBES[k]} m" + (", behind the box" if k == 0 else ""), fontsize=9)
    axes[0].legend(fontsize=7)
    return _save(fig, runs, out / "box_rise_3d.png")


def plot_box_pressure(runs: dict, out: Path) -> Path | None:
    """The pressure at the box's sensors: P1-P4 up its face (left), P5-P8 back along its top (right)."""
    plt = _plt()
    sel = {k: r for k, r in _runs(runs, "box", 3).items() if "pressure" in r}
    if not sel:
        return None
    exp = read_csv(DATA / "kleefsman_2005_pressure.csv")
    fig, axes = plt.subplots(4, 2, figsize=(12, 10), sharex=True)
    for k in range(8):
        ax = axes[k % 4, k // 4]
        ax.plot(exp["t"], exp[f"P{k + 1}"] / 1000.0, color="k", lw=1.0, label="MARIN (Kleefsman et al. 2005)")
        for (solver, mode), r in sorted(sel.items()):
            ax.plot(
                r["t"],
                np.array(r["pressure"][k]) / 1000.0,
                color=COLOURS[solver],
                ls=STYLES[mode],
                lw=0.7,
                label=_label(r),
            )
        where = f"{0.021 + 0.04 * (k % 4):.3f} m " + ("up the face" if k < 4 else "back along the top")
        ax.set(xlim=(0.3, 1.5), ylabel="p (kPa)")
        ax.set_title(f"sensor P{k + 1}, {where}", fontsize=9)
    axes[0, 0].legend(fontsize=7, ncol=2)
    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
    return _save(fig, runs, out / "box_pressure_3d.png")


def _metric(r: dict) -> list[tuple[str, float | None]]:
    """What a resolution study follows of a run: (name, value) pairs."""
    if r["case"] == "tank":
        return [("mean speed / sqrt(gH)", r["speed_ratio"])]
    if r["case"] == "front":
        return [("front RMS after a gate shift", r["rms_shifted"])]
    if r["case"] == "pressure":
        s = r["sensors"][0]
        return [("sensor 1 mean impact / data - 1", s["sim"]["mean"] / s["exp"]["mean"] - 1.0)]
    return [
        (f"H{k + 1} arrival - data (s)", None if p["arrival"] is None else p["arrival"] - p["arrival_exp"])
        for k, p in enumerate(r["probes"])
    ]


def plot_resolution(runs: dict, out: Path) -> Path | None:
    """Each measure against the spacing, for every case run at two spacings or more."""
    plt = _plt()
    groups: dict = {}
    for r in runs.values():
        if not r["sets"]:
            groups.setdefault((r["case"], r["dim"]), {}).setdefault((r["solver"], r["mode"]), []).append(r)
    studies = {k: v for k, v in groups.items() if any(len({r["spacing"] for r in rs}) > 1 for rs in v.values())}
    if not studies:
        return None
    fig, axes = plt.subplots(1, len(studies), figsize=(5.5 * len(studies), 4.2), squeeze=False)
    for ax, ((case, dim), by_run) in zip(axes[0], sorted(studies.items())):
        for (solver, mode), rs in sorted(by_run.items()):
            rs = sorted(rs, key=lambda r: r["spacing"])
            for k, (name, _) in enumerate(_metric(rs[0])):
                ys = [_metric(r)[k][1] for r in rs]
                ax.plot(
                    [r["spacing"] for r in rs],
                    [np.nan if y is None else y for y in ys],
                    color=COLOURS[solver],
                    ls=STYLES[mode],
                    marker="os^v"[k % 4],
                    label=f"{solver} {mode}: {name}",
                )
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set(xlabel="finest spacing (m)", title=f"{dim}D {case}: against the spacing")
        ax.legend(fontsize=6)
    return _save(fig, runs, out / "resolution.png")


# ================================================================== the table
def _mark(ok: bool | None) -> str:
    return "" if ok is None else (" ✓" if ok else " ✗")


def _cell(runs: dict, case: str, dim: int, solver: str, mode: str, what: str) -> str:
    sel = _runs(runs, case, dim)
    r = sel.get((solver, mode))
    if r is None:
        return "—"
    uni = twin(runs, r) if mode == "adaptive" else None
    if what == "speed":
        return f"{r['speed_ratio']:.4f}{_mark(r['speed_ratio'] <= TARGETS['speed'])}"
    if what == "pressure_rms":
        rms = profile_rms(r)
        return f"{100 * rms:.1f} % ({100 * r['pressure_rms']:.0f} %){_mark(rms <= TARGETS['pressure_rms'])}"
    if what == "front":
        ok = r["rms_shifted"] <= TARGETS["front"][solver] and abs(r["shift"]) <= TARGETS["gate_shift"]
        text = f"{100 * r['rms_shifted']:.1f} % ({r['shift']:+.2f}){_mark(ok)}"
        if mode == "adaptive" and uni is not None:
            gap = _front_gap(r, uni)
            text += f", {100 * gap:.1f} % off uniform{_mark(gap <= TARGETS['adaptive_front'])}"
        return text
    if what == "impact":
        s = r["sensors"][0]
        err = s["sim"]["mean"] / s["exp"]["mean"] - 1.0
        tol = TARGETS["impact"].get(solver)
        return f"{s['sim']['mean']:.2f} ({100 * err:+.0f} %){_mark(None if tol is None else abs(err) <= tol)}"
    if what == "peak":
        s = r["sensors"][0]
        return f"{s['sim']['peak']:.2f}, T = {_num(s['sim']['arrival'])}"
    if what == "P1":
        if "sensors" not in r:
            return "—"
        sim, exp = r["sensors"][0]["sim"], r["sensors"][0]["exp"]
        if sim["arrival"] is None:
            return "dry"
        err = 100 * (sim["mean"] / exp["mean"] - 1)
        late = sim["arrival"] - exp["arrival"]
        return f"{sim['arrival']:.3f} s ({late:+.3f}), {sim['mean'] / 1000:.1f} kPa ({err:+.0f} %)"
    if what == "body":
        sim, ref = bodies(r["t"], r["level"]), bodies(marin()["t"], [marin()[f"H{k + 1}"] for k in range(3)])
        # rounded first, so that a few ms early reads +0.00, not -0.00
        late = " / ".join("—" if s is None else f"{round(s - e, 2) + 0.0:+.2f}" for s, e in zip(sim, ref))
        return " / ".join("dry" if s is None else f"{s:.2f}" for s in sim) + f" s ({late})"
    if what == "H3_depth":
        d = h3_depth(r["t"], r["level"][2])
        return f"{d:.3f} m ({100 * (d / h3_depth(marin()['t'], marin()['H3']) - 1):+.0f} %)"
    if what.startswith("H"):
        k = int(what[1]) - 1
        p = r["probes"][k]
        if p["arrival"] is None:
            return "dry ✗" if solver in TARGETS["arrival"] else "dry"
        d = p["arrival"] - p["arrival_exp"]
        tol = TARGETS["arrival"].get(solver)
        text = f"{p['arrival']:.2f} s ({d:+.2f}){_mark(None if tol is None else abs(d) <= tol)}"
        if mode == "adaptive" and uni is not None and uni["probes"][k]["arrival"] is not None:
            gap, two_se, over = _arrival_gap(runs, r, uni, k)
            ok = _mark(abs(gap) <= TARGETS["adaptive_arrival"])
            if math.isnan(two_se):
                text += f", {gap:+.2f} off uniform{ok}"
            else:
                text += f", {round(gap, 3) + 0.0:+.3f} ± {two_se:.3f} off uniform ({over}){ok}"  # no -0.000
        return text
    raise ValueError(what)


def _arrival_gap(runs: dict, r: dict, uni: dict, k: int) -> tuple[float, float, str]:
    """An adaptive box run's arrival at probe ``k`` off its uniform twin's, twice that offset's
    standard error and the runs it is over ("4 runs each"): where tools/box_spread.py's members of
    both modes are cached (two or more each), their means' offset, since one run's arrival behind
    the box moves by up to 0.03 s with its last bits; else the one pair's (NaN, "")."""
    import box_spread as B  # here, not at the top: box_spread draws with this module

    col = next(c for c, (_, probe, level) in enumerate(B.MEASURES) if probe == k and level == WET)
    if math.isclose(r["spacing"], full_spacing("box", 3), rel_tol=1e-4):  # the cache keeps 5 digits
        count = len(B.GRAVITY)
        got = B.gathered(B.members(runs, [r["solver"]], list(MODES), count))
        ada, uni_m = got.get((r["solver"], "adaptive")), got.get((r["solver"], "uniform"))
        if ada is not None and uni_m is not None and min(len(ada), len(uni_m)) >= 2:
            gap, two_se = B.offset(ada[:, col], uni_m[:, col])
            over = f"{len(ada)} runs each" if len(ada) == len(uni_m) else f"{len(ada)} and {len(uni_m)} runs"
            return gap, two_se, over
    return r["probes"][k]["arrival"] - uni["probes"][k]["arrival"], math.nan, ""


def profile_rms(r: dict) -> float:
    """A tank's pressure by depth (20 layers, each the mean over its particles and every step of
    the window) against rho0 g (H - y), H the measured surface: the RMS over the layers, over
    rho0 g H."""
    y = np.array(r["profile_y"])
    exact = np.clip(r["surface"] - y, 0.0, None) / r["H"]
    return float(np.sqrt(np.mean((np.array(r["profile_p"]) - exact) ** 2)))


def checks(r: dict, uni: dict | None = None) -> list[tuple[str, float | None, bool]]:
    """The targets that apply to run ``r`` (``uni``: its uniform twin, for an adaptive run), each
    as (what, measured, whether it holds); what the tests assert and the table marks."""
    solver, out = r["solver"], []
    if r["case"] == "tank":
        out.append(("mean speed / sqrt(gH)", r["speed_ratio"], r["speed_ratio"] <= TARGETS["speed"]))
        rms = profile_rms(r)
        out.append(("pressure profile RMS / rho0 g H", rms, rms <= TARGETS["pressure_rms"]))
    elif r["case"] == "front":
        out.append(("front RMS after a gate shift", r["rms_shifted"], r["rms_shifted"] <= TARGETS["front"][solver]))
        out.append(("gate shift (T)", r["shift"], abs(r["shift"]) <= TARGETS["gate_shift"]))
        if uni is not None:
            gap = _front_gap(r, uni)
            out.append(("front off the uniform run's", gap, gap <= TARGETS["adaptive_front"]))
    elif r["case"] == "pressure" and solver in TARGETS["impact"]:
        s = r["sensors"][0]
        err = s["sim"]["mean"] / s["exp"]["mean"] - 1.0
        out.append(("sensor 1 mean impact pressure off the data's", err, abs(err) <= TARGETS["impact"][solver]))
    elif r["case"] == "box" and solver in TARGETS["arrival"]:
        for k, p in enumerate(r["probes"]):
            d = None if p["arrival"] is None else p["arrival"] - p["arrival_exp"]
            out.append(
                (f"H{k + 1} arrival off the data's (s)", d, d is not None and abs(d) <= TARGETS["arrival"][solver])
            )
            u = None if uni is None else uni["probes"][k]["arrival"]
            if uni is not None and p["arrival"] is not None and u is not None:
                gap = p["arrival"] - u
                out.append(
                    (f"H{k + 1} arrival off the uniform run's (s)", gap, abs(gap) <= TARGETS["adaptive_arrival"])
                )
    return out


def _num(v) -> str:
    return "—" if v is None else f"{v:.2f}"


def _front_gap(r: dict, uni: dict) -> float:
    """The largest relative gap between two runs' fronts over the data's times."""
    exp = read_csv(DATA / "martin_moyce_1952_front.csv")
    T = exp["T"][exp["T"] > 0]
    return float(np.max(np.abs(np.interp(T, r["T"], r["Z"]) / np.interp(T, uni["T"], uni["Z"]) - 1.0)))


ROWS = [
    ("tank", 2, "speed", "2D tank at rest: mean speed / sqrt(gH) after 2 s (≤ 0.005)"),
    (
        "tank",
        2,
        "pressure_rms",
        "2D tank: RMS of the pressure by depth off rho0 g (H - y), of rho0 g H (≤ 5 %; particle by particle)",
    ),
    ("tank", 3, "speed", "3D tank at rest: mean speed / sqrt(gH) (≤ 0.005)"),
    ("tank", 3, "pressure_rms", "3D tank: RMS of the pressure by depth (≤ 5 %; particle by particle)"),
    ("front", 2, "front", "2D Martin & Moyce front: RMS after a gate shift (≤ 5 %, pbf 10 %; the shift ≤ 0.25)"),
    ("front", 3, "front", "3D Martin & Moyce front (≤ 5 %, pbf 10 %)"),
    ("pressure", 2, "impact", "2D Lobovsky sensor 1: mean P over the first impact (data {exp}; ± 15 %)"),
    ("pressure", 2, "peak", "2D sensor 1: peak P and arrival T (data {peak})"),
    ("pressure", 3, "impact", "3D Lobovsky sensor 1: mean P over the first impact (data {exp}; ± 15 %)"),
    ("pressure", 3, "peak", "3D sensor 1: peak P and arrival T (data {peak})"),
    ("box", 3, "H1", "MARIN H1, behind the box: arrival (data {H1}; ± 0.05 s)"),
    ("box", 3, "H2", "MARIN H2: arrival (data {H2})"),
    ("box", 3, "H3", "MARIN H3: arrival (data {H3})"),
    ("box", 3, "body", f"MARIN H1 / H2 / H3: first at {100 * BODY:.0f} cm (data {{body}}; no target)"),
    (
        "box",
        3,
        "H3_depth",
        f"MARIN H3: mean height over {H3_WINDOW[0]:g}–{H3_WINDOW[1]:g} s "
        "(data {depth}, Ritter {ritter}; no target)",
    ),
    (
        "box",
        3,
        "P1",
        "MARIN P1, the box's face 21 mm up: first at 1 kPa, mean over 0.1 s from it (data {P1}; no target)",
    ),
]


def table(runs: dict) -> str:
    heads = [f"{s} {m}" for s in SOLVERS for m in MODES]
    lines = ["| experiment, measure (target) | " + " | ".join(heads) + " |", "|---" * (1 + len(heads)) + "|"]
    for case, dim, what, text in ROWS:
        sel = _runs(runs, case, dim)
        if not sel:
            continue
        any_run = next(iter(sel.values()))
        fill = {}
        if case == "pressure":
            s = any_run["sensors"][0]["exp"]
            fill = {"exp": f"{s['mean']:.2f}", "peak": f"{s['peak']:.2f} at T = {s['arrival']:.2f}"}
        if case == "box":
            fill = {f"H{k + 1}": f"{p['arrival_exp']:.2f} s" for k, p in enumerate(any_run["probes"])}
            with_p = [r for r in sel.values() if "sensors" in r]
            e = with_p[0]["sensors"][0]["exp"] if with_p else None
            fill["P1"] = "—" if e is None else f"{e['arrival']:.3f} s, {e['mean'] / 1000:.1f} kPa"
            exp = marin()
            fill["body"] = " / ".join(f"{b:.2f}" for b in bodies(exp["t"], [exp[f"H{k + 1}"] for k in range(3)])) + " s"
            fill["depth"], fill["ritter"] = f"{h3_depth(exp['t'], exp['H3']):.3f} m", f"{h3_ritter():.3f} m"
        kinds = sorted({(_resolution(r), r["spacing"]) for r in sel.values()}, key=lambda k: k[1])
        label = text.format(**fill) + ", " + ", ".join(f"{kind} s = {sp:.4g} m" for kind, sp in kinds)
        cells = [_cell(runs, case, dim, s, m, what) for s in SOLVERS for m in MODES]
        if len(kinds) > 1:  # mixed: say which cells are the full runs
            for k, (s, m) in enumerate((s, m) for s in SOLVERS for m in MODES):
                if (s, m) in sel and _resolution(sel[(s, m)]) == "full":
                    cells[k] += " (full)"
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def report(runs: dict, out: Path) -> list[Path]:
    """Every figure the cached runs allow, and the table (printed, and written to table.md)."""
    out.mkdir(parents=True, exist_ok=True)
    made = [plot_tank(runs, out), plot_front(runs, out), plot_pressure(runs, out, 2)]
    made += [plot_pressure(runs, out, 3), plot_box(runs, out), plot_box_pressure(runs, out)]
    made += [plot_box_rise(runs, out), plot_resolution(runs, out)]
    text = table(runs)
    (out / "table.md").write_text(text)
    print(text)
    for p in made:
        if p is not None:
            print(f"wrote {p.relative_to(out.parent.parent) if out.parent.parent in p.parents else p}")
    return [p for p in made if p is not None]

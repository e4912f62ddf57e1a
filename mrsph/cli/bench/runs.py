"""Timing a scene (a run) and an adaptive scene against its uniform twin (a pair)."""

from __future__ import annotations

import math
import os
import resource
import statistics
import sys
import time

from .cases import MULTIRES_PHASES, UNIFORM_OVERRIDE


# ----------------------------------------------------------------------------- helpers
def _peak_mb() -> float:
    """Peak resident memory of this process so far (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _rss_mb() -> float:
    """Resident memory now (Linux /proc; the peak where that is missing)."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return _peak_mb()


def fluid_volume(scene) -> float:
    """Volume (area in 2D) of the scene's fluid blocks (they may not overlap obstacles)."""
    return math.fsum(math.prod(hi - lo for lo, hi in zip(b["min"], b["max"])) for b in scene.data["fluid"]["blocks"])


def _fresh_sim(scene, arch, threads):
    """A Simulation in a fresh Taichi program, stepped once: (sim, seconds taken)."""
    from mrsph import runtime
    from mrsph.simulation import Simulation

    runtime.reset()  # frees the previous case's fields; each case starts like a new run
    t0 = time.perf_counter()
    sim = Simulation(scene, arch=arch, threads=runtime.auto_threads(scene, threads))
    notice = runtime.notice()
    if notice and notice not in _NOTICES_SHOWN:  # e.g. --arch gpu on a CPU-only machine
        _NOTICES_SHOWN.add(notice)
        print(f"mrsph: {notice}", file=sys.stderr, flush=True)
    sim.step()  # compiles every kernel of the step (adapt runs on step 0)
    return sim, time.perf_counter() - t0


_NOTICES_SHOWN: set[str] = set()


def _row(
    case_name,
    scene_name,
    overrides,
    scene,
    sim,
    kind,
    warm,
    interval,
    walls,
    steps_l,
    reals,
    compile_s,
    timers,
    repeats,
    solve=None,
) -> dict:
    """The result row shared by every kind of case; ``solve``, where given, replaces the
    implicit solver's iterations that ``sim.stats()`` holds since its last call."""
    wall = statistics.median(walls)
    steps = statistics.median(steps_l)
    n_real = statistics.median(reals)
    st = {**sim.stats(), **(solve or {})}
    total = sum(timers.values()) or 1.0
    passes = sim.neighbour_passes(st)  # neighbour loops a step
    return {
        "case": case_name,
        "kind": kind,
        "scene": scene_name,
        "overrides": list(overrides),
        "dim": sim.dim,
        "adaptive": sim.adaptive,
        "levels": sim.levels,
        "arch": sim.arch_name,
        "finest_spacing": sim.s0,
        "uniform_equivalent": scene.estimate_particles(),
        "threads": sim.threads or "all",
        "warm": warm,
        "interval": interval,
        "n_real": int(n_real),
        "n_virtual": st["n_virtual"],
        "per_level": [st[f"n_level_{l}"] for l in range(sim.levels)],
        "per_level_virtual": [st[f"n_virtual_level_{l}"] for l in range(sim.levels)],
        "steps": int(steps),
        "wall_s": wall,
        "mean_dt": interval / max(steps, 1),
        "solver": st.get("solver"),
        # an implicit solver's mean iterations a step over the profiled interval
        **({k: st[k] for k in ("density_iterations", "divergence_iterations")} if st["density_iterations"] else {}),
        "density_error": st["density_error"],
        "clamped": st["clamped"],
        "steps_per_s": steps / wall,
        "neighbour_passes_per_step": passes,
        "neighbour_passes_per_sim_s": passes * steps / interval,
        "neighbour_passes_per_wall_s": passes * steps / wall,
        "particle_steps_per_s": n_real * steps / wall,
        "sim_s_per_wall_s": interval / wall,
        "compile_s": compile_s,
        "phase_share": {k: v / total for k, v in timers.items() if v > 0},
        "rss_mb": _rss_mb(),
        "peak_mb": _peak_mb(),
        "repeats": repeats,
        "walls": walls,
    }


# ----------------------------------------------------------------------------- cases
def run_case(name, scene_name, overrides, warm, interval, repeats, arch, threads="auto", kind="run") -> dict:
    """Time one scene: ``repeats`` consecutive intervals of ``interval`` simulated
    seconds after simulating up to ``warm`` seconds; then one profiled interval."""
    from mrsph.scene.config import load_scene

    scene = load_scene(scene_name, list(overrides))
    sim, compile_s = _fresh_sim(scene, arch, threads)
    sim.advance(max(warm - sim.time, 0.0))
    walls, steps_l, reals = [], [], []
    for _ in range(repeats):
        t = time.perf_counter()
        steps = sim.advance(interval)
        walls.append(time.perf_counter() - t)
        steps_l.append(steps)
        reals.append(sim.stats()["n_real"])
    _start_profile(sim)
    sim.advance(interval)
    return _row(
        name,
        scene_name,
        overrides,
        scene,
        sim,
        kind,
        warm,
        interval,
        walls,
        steps_l,
        reals,
        compile_s,
        sim.timers,
        repeats,
    )


def solve_iterations(solves) -> dict:
    """Mean iterations a step of each solve over frames given as (steps, snapshot stats)."""
    steps = sum(n for n, _ in solves)
    keys = ("density_iterations", "divergence_iterations")
    if not steps or any(st.get(k) is None for _, st in solves for k in keys):
        return {}
    return {k: sum(n * st[k] for n, st in solves) / steps for k in keys}


def _start_profile(sim) -> None:
    """Time each phase from now on. A profiled step calls each phase of the fused kernels
    apart; the first one compiles those variants (seconds), so it is taken untimed."""
    sim.profile = True
    sim.step()
    sim.timers = dict.fromkeys(sim.timers, 0.0)


def pair_summary(adaptive: dict, uniform: dict) -> dict:
    """The comparison of a pair's two rows (see the module docstring for each ratio).

    Both must cover the same simulated interval after the same warm-up at the same
    finest spacing and dimension, the first adaptive, the second uniform; otherwise
    the ratios would mean nothing and this raises ValueError.
    """
    problems = [
        f"{key} differs (adaptive {adaptive[key]!r}, uniform {uniform[key]!r})"
        for key in ("dim", "finest_spacing", "warm", "interval")
        if adaptive[key] != uniform[key]
    ]
    if not adaptive["adaptive"] or uniform["adaptive"]:
        problems.append("expected an adaptive row and a uniform row, in that order")
    if problems:
        raise ValueError(f"pair {adaptive['case']!r} / {uniform['case']!r}: " + "; ".join(problems))
    return {
        "pair": adaptive.get("pair", adaptive["case"]),
        "adaptive_case": adaptive["case"],
        "uniform_case": uniform["case"],
        "dim": adaptive["dim"],
        "finest_spacing": adaptive["finest_spacing"],
        "levels": adaptive["levels"],
        "warm": adaptive["warm"],
        "interval": adaptive["interval"],
        "speedup": uniform["wall_s"] / adaptive["wall_s"],
        "particle_ratio": uniform["n_real"] / adaptive["n_real"],
        "step_ratio": adaptive["steps"] / uniform["steps"],
        "multires_share": math.fsum(adaptive["phase_share"].get(k, 0.0) for k in MULTIRES_PHASES),
    }


def _restored_sim(scene, arch, threads, state):
    """A Simulation in a fresh Taichi program, its kernels compiled (one step, undone),
    at ``state``."""
    sim, _ = _fresh_sim(scene, arch, threads)
    sim.restore_state(state)
    return sim


def run_pair(name, scene_name, overrides, warm, interval, repeats, arch, threads="auto"):
    """The adaptive and the uniform run of one scene: ([adaptive row, uniform row], summary).

    Each run is warmed up once and its state saved; then the two are timed turn about,
    adaptive, uniform, adaptive, ..., each repeat from its warm state. So every repeat
    times the same simulated interval, and a slow or fast spell of the machine (this
    2-core VM has them, minutes long) falls on both runs of the pair alike instead of on
    whichever ran then. The profiled interval comes last, also from the warm state."""
    from mrsph.scene.config import load_scene

    variants = (("adaptive", ()), ("uniform", (UNIFORM_OVERRIDE,)))
    setup = {}
    for variant, extra in variants:
        scene = load_scene(scene_name, list(overrides) + list(extra))
        sim, compile_s = _fresh_sim(scene, arch, threads)
        sim.advance(max(warm - sim.time, 0.0))
        setup[variant] = (tuple(overrides) + extra, scene, compile_s, sim.save_state())
    timed = {variant: ([], [], []) for variant, _ in variants}
    for _ in range(repeats):
        for variant, _ in variants:
            _, scene, _, state = setup[variant]
            sim = _restored_sim(scene, arch, threads, state)
            walls, steps_l, reals = timed[variant]
            t = time.perf_counter()
            steps_l.append(sim.advance(interval))
            walls.append(time.perf_counter() - t)
            reals.append(sim.stats()["n_real"])
    rows = []
    for variant, _ in variants:
        case_overrides, scene, compile_s, state = setup[variant]
        sim = _restored_sim(scene, arch, threads, state)
        _start_profile(sim)
        sim.advance(interval)
        row = _row(
            f"{name} {variant}",
            scene_name,
            case_overrides,
            scene,
            sim,
            "pair",
            warm,
            interval,
            *timed[variant],
            compile_s,
            sim.timers,
            repeats,
        )
        row["pair"] = name
        rows.append(row)
    return rows, pair_summary(*rows)

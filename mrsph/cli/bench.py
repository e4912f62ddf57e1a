"""``python3 main.py bench``: how fast mrsph runs, and where the time goes.

Every case builds its scene in a fresh Taichi program and takes one step, which
compiles every kernel of the step (kernels come from Taichi's offline cache when an
earlier run compiled them); that is the compile time, reported on its own. It then runs
a warm-up, times a fixed simulated interval ``repeats`` times in a row and reports
medians: real, virtual and per-level particles, steps per second, particle-steps per
second (real particles × steps / wall seconds), simulated seconds per wall second, the
share of step time per phase (measured with a device sync around each phase, in one
extra profiled interval, so that the timed runs carry no sync overhead), the resident
memory at the end of the case and the peak resident memory of the process.

Three kinds of case:

- **run**: one scene (the uniform dam breaks).
- **pair**: an adaptive scene run twice at the same finest spacing, once adaptive and
  once uniform (``adaptivity.enabled = false`` puts every particle at
  ``particles.spacing``, the finest level's spacing), each timed on the same simulated
  intervals after the same warm-up, turn about from their saved warm states (so that the
  machine's slow spells fall on both). The pair line gives the speed-up (uniform wall time /
  adaptive wall time), the particle ratio (uniform real particles / adaptive real
  particles), the step ratio (adaptive steps / uniform steps: the time step follows the
  finest level, but the flows differ) and the share of the adaptive run's step time taken
  by the multiresolution phases (adapt, virtual_coupling, virtual_advect).
- **demo**: the default demo scene recorded offscreen by the app's frame source (GGUI
  when Vulkan works, else the numpy rasteriser, chosen as ``mrsph.app.record`` chooses).
  A frame is one ``advance_frame()`` plus a snapshot and its rendering; it reports
  rendered frames per second, simulated seconds per wall second, and the finest spacing
  next to the spacing of a 10k-particle uniform run of the same fluid volume. Then the
  water view's cost as the interactive window pays it: frames advanced by the window's
  default frame budget and drawn with the water view, the surface's own time and its
  share of such a frame (issue 32 asks for at most 25 %).
"""

from __future__ import annotations

import json
import math
import os
import resource
import statistics
import sys
import time
from pathlib import Path
from typing import NamedTuple

#: The phases that exist only because of the multiresolution scheme.
MULTIRES_PHASES = ("adapt", "virtual_coupling", "virtual_advect")
#: Turns an adaptive scene into the uniform run of a pair.
UNIFORM_OVERRIDE = "adaptivity.enabled=false"
#: The demo's finest spacing is compared with a uniform run of this many particles.
DEMO_REFERENCE_PARTICLES = 10_000
KINDS = ("run", "pair", "demo")


class Case(NamedTuple):
    """One benchmark case; ``warm`` and ``interval`` are simulated seconds."""

    name: str
    scene: str
    overrides: tuple
    warm: float
    interval: float
    kind: str = "run"


def _cases(full: bool) -> list[Case]:
    """The quick set (about 3 minutes on 2 free cores), or the full set (quick + long).

    Dam breaks are timed while the column collapses, not on the initial lattice (which
    is 1.3-2x cheaper). Pairs are timed once the front has reached the obstacle and the
    adaptive run has refined next to it (t = 0.24 s in 2D, 0.2 s in 3D); spacings give
    uniform runs of ~12k and ~38k particles in 2D, ~6k and ~21k in 3D.
    """
    quick = [
        Case("dam_break_2d uniform ~10k", "dam_break_2d", ("particles.spacing=0.0035",), 0.1, 0.02),
        Case("dam_break_3d uniform ~30k", "dam_break_3d", ("particles.spacing=0.0092",), 0.2, 0.005),
        Case(
            "dam_break_obstacle_2d s=3.5mm", "dam_break_obstacle_2d", ("particles.spacing=0.0035",), 0.24, 0.01, "pair"
        ),
        Case("dam_break_obstacle_3d s=15mm", "dam_break_obstacle_3d", ("particles.spacing=0.015",), 0.2, 0.01, "pair"),
        Case(
            "dam_break_2d dfsph ~10k", "dam_break_2d", ("particles.spacing=0.0035", "fluid.solver=\"dfsph\""), 0.1, 0.05
        ),
        Case("demo_2d rendered", "demo_2d", (), 1.0 / 30.0, 0.1, "demo"),
        Case("demo_3d rendered", "demo_3d", (), 1.0 / 30.0, 0.1, "demo"),
        Case("pool_3d rendered", "pool_3d", (), 1.0 / 30.0, 0.1, "demo"),
    ]
    if not full:
        return quick
    return quick + [
        Case("dam_break_2d uniform ~50k", "dam_break_2d", ("particles.spacing=0.0016",), 0.25, 0.02),
        Case("dam_break_3d uniform ~100k", "dam_break_3d", ("particles.spacing=0.0063",), 0.2, 0.01),
        # the same flows with the divergence-free solver: its steps are ~10x longer, so the
        # interval is longer too (a handful of steps would time the launches, not the flow)
        Case(
            "dam_break_2d dfsph ~50k",
            "dam_break_2d",
            ("particles.spacing=0.0016", "fluid.solver=\"dfsph\""),
            0.25,
            0.05,
        ),
        Case(
            "dam_break_3d dfsph ~100k",
            "dam_break_3d",
            ("particles.spacing=0.0063", "fluid.solver=\"dfsph\""),
            0.2,
            0.03,
        ),
        Case("dam_break_obstacle_2d s=2mm", "dam_break_obstacle_2d", ("particles.spacing=0.002",), 0.24, 0.01, "pair"),
        Case("dam_break_obstacle_3d s=10mm", "dam_break_obstacle_3d", ("particles.spacing=0.01",), 0.2, 0.01, "pair"),
        Case(
            "dam_break_obstacle_2d s=2mm L=3",
            "dam_break_obstacle_2d",
            ("particles.spacing=0.002", "adaptivity.levels=3"),
            0.24,
            0.01,
            "pair",
        ),
        Case(
            "dam_break_obstacle_3d s=6mm L=3",
            "dam_break_obstacle_3d",
            ("particles.spacing=0.006", "adaptivity.levels=3"),
            0.2,
            0.01,
            "pair",
        ),
        # the finest pair: the uniform twin has 166k particles (~6 minutes, most of it
        # the uniform run's warm-up)
        Case(
            "dam_break_obstacle_3d s=5mm L=3",
            "dam_break_obstacle_3d",
            ("particles.spacing=0.005", "adaptivity.levels=3"),
            0.2,
            0.01,
            "pair",
        ),
    ]


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
        "steps_per_s": steps / wall,
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


def run_demo(name, scene_name, overrides, warm, interval, repeats, arch, threads="auto") -> dict:
    """Record the scene offscreen as the app does: whole frames (``interval`` rounded to
    frames, at least one), each advanced, snapshotted and rendered."""
    from mrsph.app.palette import Style
    from mrsph.app.record import DEFAULT_SIZE, _open_frames
    from mrsph.app.view import scene_setting
    from mrsph.scene.config import load_scene

    scene = load_scene(scene_name, list(overrides))
    sim, compile_s = _fresh_sim(scene, arch, threads)
    fps = float(scene.get("run.fps"))
    n_frames = max(1, round(interval * fps))
    width = int(scene_setting(scene, "render.width", DEFAULT_SIZE[0]))
    height = int(scene_setting(scene, "render.height", DEFAULT_SIZE[1]))
    t0 = time.perf_counter()
    source = _open_frames("auto", width, height, Style.from_scene(scene), scene)

    solves = []  # (steps, the snapshot's stats): a snapshot takes the solver's counters

    def frame() -> tuple[int, float]:
        steps = sim.advance_frame()
        t = time.perf_counter()
        snap = sim.snapshot()
        solves.append((steps, snap.stats))
        source.render(snap, "level", False, sim.rest_density)
        return steps, time.perf_counter() - t

    try:
        source.render(sim.snapshot(), "level", False, sim.rest_density)  # compiles the renderer
        render_compile_s = time.perf_counter() - t0  # Vulkan probe, window, first frame
        while sim.time < warm - 1e-12:
            frame()
        walls, steps_l, reals, renders = [], [], [], []
        for _ in range(repeats):
            t = time.perf_counter()
            done = [frame() for _ in range(n_frames)]
            walls.append(time.perf_counter() - t)
            steps_l.append(sum(s for s, _ in done))
            renders.append(sum(r for _, r in done))
            reals.append(sim.stats()["n_real"])
        surface_s, window_frame_s, surface_net_s = _surface_cost(source, sim, repeats)
        _start_profile(sim)
        del solves[:]
        render = sum(frame()[1] for _ in range(n_frames))
        timers = {**sim.timers, "render": render}
    finally:
        source.close()
    row = _row(
        name,
        scene_name,
        overrides,
        scene,
        sim,
        "demo",
        warm,
        n_frames / fps,
        walls,
        steps_l,
        reals,
        compile_s,
        timers,
        repeats,
        solve_iterations(solves),
    )
    volume = fluid_volume(scene)
    reference = (volume / DEMO_REFERENCE_PARTICLES) ** (1.0 / sim.dim)
    wall = row["wall_s"]
    row.update(
        {
            "renderer": source.name,
            "width": width,
            "height": height,
            "frames": n_frames,
            "frames_per_s": n_frames / wall,
            "render_ms": 1e3 * statistics.median(renders) / n_frames,
            "render_share": statistics.median(renders) / wall,
            "render_compile_s": render_compile_s,
            "surface_ms": 1e3 * surface_s,
            "window_frame_ms": 1e3 * window_frame_s,
            "surface_share": surface_s / window_frame_s,
            "surface_net_ms": 1e3 * surface_net_s,
            "fluid_volume": volume,
            "reference_particles": DEMO_REFERENCE_PARTICLES,
            "reference_spacing": reference,
            "spacing_ratio": reference / sim.s0,
        }
    )
    return row


def _surface_cost(source, sim, repeats) -> tuple[float, float, float]:
    """The water view's cost, wall seconds (medians): (computing the surface
    (``mrsph.app.geometry.water``) on a frame of the interactive window, that window
    frame with the water view on, what drawing a frame with the surface costs beyond
    drawing it with particles: in 3D, where the mesh replaces the spheres, it can save).

    A window frame is what the window does (mrsph.app.window): the simulation advanced
    for the window's default frame budget (``--frame-budget``, slow motion where a whole
    frame takes longer), a snapshot, and the frame drawn with the water view; the
    surface is computed again on the same snapshot apart, for its own time. The
    renderer reuses a surface for the same snapshot, so each drawing below gets a copy."""
    import dataclasses

    from mrsph.app import palette
    from mrsph.app.geometry import water

    from .options import WINDOW_FRAME_BUDGET_MS, frame_budget_arg

    budget = frame_budget_arg(WINDOW_FRAME_BUDGET_MS)
    snap = sim.snapshot()
    source.render(snap, "level", False, sim.rest_density, (), True)  # first use: allocations
    compute, frames, net = [], [], []
    for _ in range(max(repeats, 3) * 3):
        t0 = time.perf_counter()
        sim.advance_frame(budget)
        snap = sim.snapshot()
        source.render(snap, "level", False, sim.rest_density, (), True)
        t1 = time.perf_counter()
        rgb = palette.colours(snap, "level", rest_density=sim.rest_density)
        water(snap, rgb)
        t2 = time.perf_counter()
        source.render(dataclasses.replace(snap), "level", False, sim.rest_density, (), False)
        t3 = time.perf_counter()
        source.render(dataclasses.replace(snap), "level", False, sim.rest_density, (), True)
        frames.append(t1 - t0)
        compute.append(t2 - t1)
        net.append(time.perf_counter() - t3 - (t3 - t2))
    return statistics.median(compute), statistics.median(frames), statistics.median(net)


# ----------------------------------------------------------------------------- report
def _mm(x: float) -> str:
    return f"{1e3 * x:.3g} mm"


def _table(rows, pairs=()) -> str:
    """One line per case and a line under it (levels, memory, phases); a pair gets a
    third line after its uniform run, the demo a line with its frame rate."""
    head = (
        f"{'case':40s} {'real':>8s} {'virtual':>8s} {'steps/s':>8s} {'Mpart-steps/s':>14s} "
        f"{'sim s/wall s':>12s} {'compile s':>9s}"
    )
    out = [head, "-" * len(head)]
    by_uniform = {p["uniform_case"]: p for p in pairs}
    for r in rows:
        out.append(
            f"{r['case']:40s} {r['n_real']:8d} {r['n_virtual']:8d} {r['steps_per_s']:8.1f} "
            f"{r['particle_steps_per_s'] / 1e6:14.2f} {r['sim_s_per_wall_s']:12.4f} "
            f"{r['compile_s']:9.1f}"
        )
        shares = ", ".join(
            f"{k} {100 * v:.0f}%" for k, v in sorted(r["phase_share"].items(), key=lambda kv: -kv[1]) if v >= 0.005
        )
        levels = f"levels {r['per_level']}, " if r["levels"] > 1 else ""
        steps = f"{r['solver']} mean dt {r['mean_dt']:.3g} s" if "mean_dt" in r else ""
        if r.get("density_iterations") is not None:
            steps += (
                f", iterations a step: density {r['density_iterations']:.2f}, divergence "
                f"{r['divergence_iterations']:.2f}"
            )
        out.append(f"    {levels}{r['rss_mb']:.0f} MB; {steps + '; ' if steps else ''}phases: {shares}")
        if r["kind"] == "demo":
            out.append(
                f"    => {r['frames_per_s']:.2f} rendered frames/s ({r['renderer']}, "
                f"{r['width']}x{r['height']}, {r['render_ms']:.0f} ms a frame, "
                f"{100 * r['render_share']:.0f}% of it); finest spacing "
                f"{_mm(r['finest_spacing'])} vs {_mm(r['reference_spacing'])} for "
                f"{r['reference_particles'] // 1000}k uniform particles "
                f"({r['spacing_ratio']:.2f}x finer; uniform at the finest spacing: "
                f"{r['uniform_equivalent']} particles)"
            )
            out.append(
                f"    => water view (w): surface {r['surface_ms']:.1f} ms, "
                f"{100 * r['surface_share']:.0f}% of a window frame with it "
                f"({r['window_frame_ms']:.0f} ms); drawn with it instead of particles: "
                f"{r['surface_net_ms']:+.0f} ms"
            )
        p = by_uniform.get(r["case"])
        if p:
            out.append(
                f"    => adaptive vs uniform: {p['speedup']:.2f}x faster, "
                f"{p['particle_ratio']:.2f}x fewer real particles, {p['step_ratio']:.2f}x "
                f"the steps; multires phases {100 * p['multires_share']:.0f}% of the "
                f"adaptive step"
            )
    if rows:
        out.append(f"peak memory: {max(r['peak_mb'] for r in rows):.0f} MB")
    return "\n".join(out)


def advanced_optimization() -> bool:
    """Whether Taichi compiles with its advanced optimisation passes: off only where
    ``TI_ADVANCED_OPTIMIZATION`` is an integer that reads 0, as ``ti.init`` reads it
    (``bool(int(value))``; unset or empty: on; not an integer: ``ti.init`` refuses it)."""
    flag = os.environ.get("TI_ADVANCED_OPTIMIZATION", "")
    try:
        return not flag or bool(int(flag))
    except ValueError:
        return True


def gpu_name(arches) -> str | None:
    """The CUDA card's name as ``nvidia-smi`` gives it, where a case ran on CUDA (None
    on the CPU, and where the name cannot be had)."""
    if "cuda" not in arches:
        return None
    import subprocess

    try:
        out = subprocess.run(
            ["nvidia-smi", "--query-gpu=name,memory.total,driver_version", "--format=csv,noheader"],
            capture_output=True,
            text=True,
            timeout=20,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    lines = out.stdout.strip().splitlines()
    return lines[0].strip() if out.returncode == 0 and lines else None


def _scene_problems(cases) -> list[str]:
    """Every problem of the cases' scenes with their overrides, once each (none: [])."""
    from mrsph.scene.config import SceneError, load_scene

    problems = []
    for c in cases:
        try:
            load_scene(c.scene, list(c.overrides))
        except SceneError as e:  # a bad --set is the same problem in every case
            problems += [line for line in e.problems if line not in problems]
    return problems


def run_cases(cases, repeats, arch, threads="auto", log=None) -> tuple[list, list]:
    """Run cases in order: (rows, pair summaries)."""
    rows, pairs = [], []
    for c in cases:
        if log:
            log(f"running {c.name} ({c.kind}) ...")
        args = (c.name, c.scene, c.overrides, c.warm, c.interval, repeats, arch, threads)
        if c.kind == "pair":
            pair_rows, summary = run_pair(*args)
            rows += pair_rows
            pairs.append(summary)
        elif c.kind == "demo":
            rows.append(run_demo(*args))
        else:
            rows.append(run_case(*args))
    return rows, pairs


def main(argv=None) -> int:
    from .options import HelpFormatter, Parser, file_problem, positive_float, positive_int, threads_arg

    ap = Parser(prog="python3 main.py bench", description=__doc__.splitlines()[0], formatter_class=HelpFormatter)
    ap.add_argument(
        "--full", action="store_true", help="the long set: adds 50k 2D and 100k 3D dam breaks and finer pairs"
    )
    ap.add_argument("--repeats", type=positive_int, default=3, help="timed runs per case (median)")
    ap.add_argument("--arch", default="cpu", choices=("auto", "cpu", "gpu"), help="Taichi backend")
    ap.add_argument(
        "--threads",
        type=threads_arg,
        default="auto",
        help="CPU threads for the cpu backend (default auto: as the app, one pinned "
        "thread for scenes that start under 12k particles in 2D, 4k in 3D, else all cores)",
    )
    ap.add_argument(
        "--interval-scale",
        type=positive_float,
        default=1.0,
        metavar="F",
        help="multiply every warm-up and timed interval by F (0.05: a smoke run)",
    )
    ap.add_argument("--json", metavar="FILE", help="also write the results as JSON (default: no file)")
    ap.add_argument(
        "--case",
        action="append",
        default=None,
        help="run only cases whose name contains this text (repeatable; default: all)",
    )
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        dest="overrides",
        help="a scene override added to every chosen case, after the case's own "
        "(repeatable), e.g. --set 'fluid.solver=\"dfsph\"' (default: none)",
    )
    ap.add_argument("--list", action="store_true", help="list the cases and exit")
    args = ap.parse_args(argv)
    cases = [c for c in _cases(args.full) if not args.case or any(t in c.name for t in args.case)]
    if args.list:
        for c in _cases(args.full):
            print(f"{c.name:40s} {c.kind:5s} {c.scene} {' '.join(c.overrides)}")
        return 0
    if not cases:
        print(
            f"python3 main.py bench: no case matches {args.case} (see --list{'' if args.full else ' and --full'})",
            file=sys.stderr,
        )
        return 2
    problem = file_problem("--json", Path(args.json)) if args.json else None
    if problem:  # before the cases run, not after
        print(f"python3 main.py bench: {problem}", file=sys.stderr)
        return 2
    scale = args.interval_scale
    cases = [
        c._replace(warm=c.warm * scale, interval=c.interval * scale, overrides=c.overrides + tuple(args.overrides))
        for c in cases
    ]
    problems = _scene_problems(cases)
    if problems:  # a bad --set, found before the first case compiles
        for line in problems:
            print(f"python3 main.py bench: {line}", file=sys.stderr)
        return 2
    optimised = advanced_optimization()
    if not optimised:  # the default test run sets it (tests/conftest.py)
        print(
            "python3 main.py bench: warning: TI_ADVANCED_OPTIMIZATION=0: Taichi compiles "
            "without its optimisation passes, so these timings are not the program's",
            file=sys.stderr,
        )
    rows, pairs = run_cases(
        cases, args.repeats, args.arch, args.threads, log=lambda m: print(m, file=sys.stderr, flush=True)
    )
    print(_table(rows, pairs))
    if args.json:
        import platform

        with open(args.json, "w") as fh:
            json.dump(
                {
                    "machine": platform.processor() or platform.machine(),
                    "cpus": os.cpu_count(),
                    "gpu": gpu_name({r["arch"] for r in rows}),
                    "arch": args.arch,
                    "threads": args.threads,
                    "repeats": args.repeats,
                    "interval_scale": scale,
                    "overrides": args.overrides,
                    "advanced_optimization": optimised,
                    "cases": rows,
                    "pairs": pairs,
                },
                fh,
                indent=2,
            )
    return 0

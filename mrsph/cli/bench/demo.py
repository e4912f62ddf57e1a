"""Timing a demo: the simulation alone from its start, and rendered offscreen in real time,
as a window keeping up with the clock runs it; the water view's cost."""

from __future__ import annotations

import statistics
import time

from ...app.window import REAL_TIME_CAP_S  # the window's pace, which a rendered demo times
from .cases import DEMO_REFERENCE_PARTICLES
from .runs import _fresh_sim, _row, _start_profile, fluid_volume, solve_iterations


def _real_time(sim, source, seconds: float, budget: float, fps: float) -> tuple[int, float, float]:
    """From t = 0 to ``seconds`` simulated: each frame advances by the wall time the last
    one took (1/fps for the first, at most REAL_TIME_CAP_S), stopping after the first
    step past ``budget`` seconds of simulating, then is snapshotted and drawn. Returns
    (frames, wall seconds, wall seconds spent drawing)."""
    frames, drawing, last = 0, 0.0, 1.0 / fps
    t_start = time.perf_counter()
    while sim.time < seconds - 1e-9:
        t0 = time.perf_counter()
        sim.advance(min(last, REAL_TIME_CAP_S, seconds - sim.time), budget)
        t1 = time.perf_counter()
        source.render(sim.snapshot(stats=False), "level", False, sim.rest_density)
        t2 = time.perf_counter()
        drawing += t2 - t1
        last = t2 - t0
        frames += 1
    return frames, time.perf_counter() - t_start, drawing


def run_demo(name, scene_name, overrides, warm, interval, repeats, arch, threads="auto") -> dict:
    """A demo from its start over ``interval`` simulated seconds (``warm`` is unused: a
    demo is timed from t = 0, its opening stir included), each repeat from a reset: the
    simulation alone, frame after frame; then rendered in real time (``_real_time``)."""
    from mrsph.app.palette import Style
    from mrsph.app.record import _open_frames
    from mrsph.app.view import scene_setting
    from mrsph.scene.config import load_scene

    from ..options import WINDOW_FRAME_BUDGET_MS, frame_budget_arg

    scene = load_scene(scene_name, list(overrides))
    sim, compile_s = _fresh_sim(scene, arch, threads)
    fps = float(scene.get("run.fps"))
    n_frames = max(1, round(interval * fps))
    seconds = n_frames / fps
    budget = frame_budget_arg(WINDOW_FRAME_BUDGET_MS)
    width = int(scene_setting(scene, "render.width"))
    height = int(scene_setting(scene, "render.height"))
    t0 = time.perf_counter()
    source = _open_frames("auto", width, height, Style.from_scene(scene), scene)
    try:
        source.render(sim.snapshot(), "level", False, sim.rest_density)  # compiles the renderer
        render_compile_s = time.perf_counter() - t0  # Vulkan probe, window, first frame
        walls, steps_l, reals, solves = [], [], [], []
        for _ in range(repeats):
            sim.reset()
            t = time.perf_counter()
            steps = sum(sim.advance_frame() for _ in range(n_frames))
            walls.append(time.perf_counter() - t)
            steps_l.append(steps)
            st = sim.stats()
            reals.append(st["n_real"])
            solves.append((steps, st))
        rendered = []
        for _ in range(repeats):
            sim.reset()
            rendered.append(_real_time(sim, source, seconds, budget, fps))
        surface_s, window_frame_s, surface_net_s = _surface_cost(source, sim, repeats)
        sim.reset()
        _start_profile(sim)
        t = time.perf_counter()
        for _ in range(n_frames):
            sim.advance_frame()
            t1 = time.perf_counter()
            source.render(sim.snapshot(stats=False), "level", False, sim.rest_density)
            sim.timers["render"] = sim.timers.get("render", 0.0) + time.perf_counter() - t1
    finally:
        source.close()
    row = _row(
        name,
        scene_name,
        overrides,
        scene,
        sim,
        "demo",
        0.0,
        seconds,
        walls,
        steps_l,
        reals,
        compile_s,
        sim.timers,
        repeats,
        solve_iterations(solves),
    )
    volume = fluid_volume(scene)
    reference = (volume / DEMO_REFERENCE_PARTICLES) ** (1.0 / sim.dim)
    frames = statistics.median(f for f, _, _ in rendered)
    wall = statistics.median(w for _, w, _ in rendered)
    drawing = statistics.median(d for _, _, d in rendered)
    row.update(
        {
            "renderer": source.name,
            "width": width,
            "height": height,
            "frames": n_frames,
            "frames_per_s": statistics.median(f / w for f, w, _ in rendered),
            "rendered_sim_s_per_wall_s": statistics.median(seconds / w for _, w, _ in rendered),
            "render_ms": 1e3 * drawing / frames,
            "render_share": drawing / wall,
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

    from ..options import WINDOW_FRAME_BUDGET_MS, frame_budget_arg

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

"""The benchmark's table, and what it says of the machine."""

from __future__ import annotations

import os


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
        if "neighbour_passes_per_step" in r:  # (rows of older JSON files lack them)
            out.append(
                f"    neighbour passes: {r['neighbour_passes_per_step']:.1f} a step, "
                f"{r['neighbour_passes_per_sim_s']:.0f} a simulated second, "
                f"{r['neighbour_passes_per_wall_s']:.0f} a wall second; density error "
                f"{100 * r['density_error']:.2f} %" + (f", {r['clamped']} clamped" if r.get("clamped") else "")
            )
        if r["kind"] == "demo":
            out.append(
                f"    => rendered in real time: {r['frames_per_s']:.2f} frames/s at "
                f"{r.get('rendered_sim_s_per_wall_s', float('nan')):.3f} simulated s per wall s ({r['renderer']}, "
                f"{r['width']}x{r['height']}, {r['render_ms']:.0f} ms a frame, "
                f"{100 * r['render_share']:.0f}% of the time); finest spacing "
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

"""The window's hooks for tests and users: per-frame stats lines and screenshots.

``MRSPH_WINDOW_STATS=path``: append one JSON line per frame: frame, time,
kinetic_energy, n_real, n_virtual, disturbance_active, disturbance_speed (the mouse's
target speed, m/s: the hand's speed in wall-clock time, capped; 0 without a push),
paused, scene (the one drawn), wall_s (since the window's start), unix_s (the wall
clock), fps, speed (simulated seconds per wall second), camera_distance (3D, else null),
surface, tint, color_mode, surface_ms (what computing the water view took this frame; 0
when off or reused), loading (the frame shows the loading panel), opening (what it
opens, else null), ahead_ready (how many simulations built ahead of a switch are ready:
mrsph.app.ahead), s_ready (what s opens is ready: the HUD's "s: next ..., ready"),
solver (the pressure solver; null for the stand-in and before the first scene runs) with
density_iterations, divergence_iterations, density_error, unconverged and clamped of the
simulation's stats row (null where the row has none),
message (the HUD's message line as shown, "" when none).
``MRSPH_WINDOW_SCREENSHOT=path``: write the screenshot there (the AUTO_SCREENSHOT_FRAME-th
frame of a running scene, and on ``p``), and every frame that shows the loading panel
beside it, as ``<stem>_loading_<scene>_<n><suffix>`` (``scene`` the one it opens, n
counts them from 0); without it ``p`` writes into SCREENSHOT_DIR.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

STATS_ENV = "MRSPH_WINDOW_STATS"
#: The solver's figures of the simulation's stats row that each line repeats.
SOLVER_KEYS = ("density_iterations", "divergence_iterations", "density_error", "unconverged", "shortened", "clamped")
SCREENSHOT_ENV = "MRSPH_WINDOW_SCREENSHOT"
#: Frame at which the automatic screenshot of MRSPH_WINDOW_SCREENSHOT is taken: late
#: enough that ImGui has laid out its windows (they appear from the second frame).
AUTO_SCREENSHOT_FRAME = 10
#: Where ``p`` writes screenshots, relative to the working directory (.gitignore covers
#: /out/ at the repository root).
SCREENSHOT_DIR = Path("out") / "screenshots"


def loading_shot_path(screenshot_path: str | None, scene: str, n: int) -> Path | None:
    """Where the n-th loading frame's screenshot goes, or None without the hook."""
    if not screenshot_path:
        return None
    p = Path(screenshot_path)
    return p.with_name(f"{p.stem}_loading_{scene}_{n:03d}{p.suffix}")


def stats_row(app, snap, disturbance) -> dict:
    """The stats line of one frame of the window ``app`` (an ``_App``); ``snap`` None
    before the first scene runs."""
    st = (snap.stats if snap is not None else None) or {}
    camera = app.renderer.camera
    dim = snap.dim if snap is not None else None
    return {
        "frame": int(snap.frame) if snap is not None else 0,
        "time": float(snap.time) if snap is not None else 0.0,
        "kinetic_energy": float(st.get("kinetic_energy", 0.0)),
        "n_real": int(st.get("n_real", 0)),
        "n_virtual": int(st.get("n_virtual", 0)),
        "disturbance_active": disturbance is not None,
        "disturbance_speed": (
            round(math.hypot(*disturbance.velocity), 6) if disturbance is not None and disturbance.velocity else 0.0
        ),
        "paused": app.paused,
        "scene": app.scene_name,
        "wall_s": round(time.perf_counter() - app.start, 4),
        "unix_s": round(time.time(), 4),
        "fps": round(app.fps, 2),
        "speed": round(app.speed.value() or 0.0, 4),
        "camera_distance": (round(float(camera.distance), 6) if dim == 3 and camera is not None else None),
        "surface": app.surface,
        "tint": app.tint,
        "color_mode": app.color_mode,
        "surface_ms": round(1e3 * app.renderer.surface_s, 3),
        "loading": app.loading is not None,
        "opening": app.opening.label if app.opening is not None else None,
        "ahead_ready": app.sims.ahead.ready(),
        "s_ready": app.next_ready(),
        "solver": st.get("solver", getattr(app, "solver", None)) if snap is not None else None,
        **{k: st.get(k) for k in SOLVER_KEYS},
        "message": app.message.shown(),
    }


def write_screenshot(window, path: str | None) -> str:
    """Save the frame in the window's image buffer (call between drawing and show());
    ``path`` None: a time-stamped file in SCREENSHOT_DIR. Returns the HUD's message."""
    import imageio.v3 as iio

    from .render import image_from_window

    out = Path(path or SCREENSHOT_DIR / time.strftime("mrsph_%Y%m%d_%H%M%S.png"))
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        iio.imwrite(out, image_from_window(window))
        return f"screenshot {out}"
    except Exception as e:
        return f"screenshot failed: {e}"

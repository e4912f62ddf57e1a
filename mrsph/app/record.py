"""Headless recording: advance a simulation and write its frames as mp4, gif or PNGs.

Frames come from the same renderer as the window (GGUI drawing into an offscreen
``ti.ui.Window``) when Vulkan works, else from the numpy rasteriser, which draws the
same palette, framing and furniture. Whether Vulkan works is found out in a child
process, because creating a GGUI window on a broken driver can kill the process
(segfault) instead of raising.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from .geometry import stirrer_marks
from .palette import Style
from .probe import run_probe
from .view import camera_for_scene, scene_setting

BACKENDS = ("auto", "ggui", "raster")
#: The probe imports Taichi and opens a 64x64 offscreen window: ~3 s when it works; a
#: hung driver must not hang a recording, hence the limit.
PROBE_TIMEOUT_S = 90.0
#: Set this environment variable to skip GGUI and always use the rasteriser.
NO_VULKAN_ENV = "MRSPH_NO_VULKAN"

_PROBE_SCRIPT = r"""
w = ti.ui.Window("mrsph vulkan probe", (64, 48), show_window=False)
w.get_canvas().set_background_color((1.0, 0.0, 0.0))
img = w.get_image_buffer_as_numpy()
assert img.shape[:2] == (64, 48), img.shape
assert img[..., 0].mean() > 0.5 and img[..., 1].mean() < 0.5, "wrong colour read back"
print("MRSPH_VULKAN_OK", flush=True)
"""
_probe_cache: dict = {}


def vulkan_available() -> tuple[bool, str]:
    """(True, description) when GGUI can render offscreen here, else (False, why).

    Probed once per process in a subprocess with a timeout; the result is cached.
    """
    if os.environ.get(NO_VULKAN_ENV):
        return False, f"{NO_VULKAN_ENV} is set"
    if "result" in _probe_cache:
        return _probe_cache["result"]
    ok, why = run_probe(_PROBE_SCRIPT, "MRSPH_VULKAN_OK", "the GGUI/Vulkan probe", PROBE_TIMEOUT_S)
    result = (True, "GGUI offscreen rendering works") if ok else (False, why)
    _probe_cache["result"] = result
    return result


def _taichi_ready() -> bool:
    from taichi.lang import impl

    return impl.get_runtime().prog is not None


# ----------------------------------------------------------------------------- frames
class _GguiFrames:
    """Frames from the shared GGUI renderer in an offscreen window."""

    name = "ggui"

    def __init__(self, width, height, style, scene):
        import taichi as ti

        from .render import ImguiIniGuard, Renderer

        self._ti = ti
        self._ini = ImguiIniGuard()
        # Keep Taichi's per-frame "Dumping image buffer" info lines off the terminal.
        self._restore_info = ti._logging.is_logging_effective(ti._logging.INFO)
        ti.set_logging_level(ti.WARN)
        self.window = ti.ui.Window("mrsph record", (width, height), show_window=False)
        self.renderer = Renderer(self.window, style, scene)
        self._first = True

    def render(self, snap, color_mode, show_virtual, rest_density, marks=(), surface=False) -> np.ndarray:
        from .render import image_from_window

        if self._first:
            # ImGui sizes its windows on their first frame and draws them from the
            # second: draw a throw-away frame so frame 0 already has its legend.
            self.renderer.draw(snap, color_mode, show_virtual, rest_density=rest_density)
            image_from_window(self.window)
            self._first = False
        self.renderer.draw(snap, color_mode, show_virtual, rest_density=rest_density, marks=marks, surface=surface)
        return image_from_window(self.window)

    def close(self):
        # Never window.show() an offscreen window: it segfaults on lavapipe.
        self.window.destroy()
        self._ini.cleanup()
        if self._restore_info:
            self._ti.set_logging_level(self._ti.INFO)


class _RasterFrames:
    """Frames from the numpy rasteriser."""

    name = "raster"

    def __init__(self, width, height, style, scene):
        from .raster import Rasterizer

        self.raster = Rasterizer(width, height)
        self.style, self.scene = style, scene
        self.camera = None

    def render(self, snap, color_mode, show_virtual, rest_density, marks=(), surface=False) -> np.ndarray:
        if snap.dim == 3 and self.camera is None:
            self.camera = camera_for_scene(
                self.scene, snap.domain_min, snap.domain_max, self.raster.width / self.raster.height
            )
        return self.raster.render(
            snap, color_mode, show_virtual, self.camera, True, self.style, rest_density, marks, surface
        )

    def close(self):
        pass


def _open_frames(backend, width, height, style, scene):
    """The frame source for ``backend``; "auto" falls back to the rasteriser with a
    one-line notice on stderr saying why."""
    if backend not in BACKENDS:
        raise ValueError(f"backend: expected one of {', '.join(BACKENDS)} (got {backend!r})")
    if backend == "raster":
        return _RasterFrames(width, height, style, scene)
    ok, why = vulkan_available()
    if ok and not _taichi_ready():
        ok, why = False, "Taichi is not initialised in this process (no simulation built yet)"
    if ok:
        try:
            return _GguiFrames(width, height, style, scene)
        except Exception as e:  # a driver that passed the probe but fails here
            ok, why = False, f"GGUI offscreen window failed: {type(e).__name__}: {e}"
    if backend == "ggui":
        raise RuntimeError(f"backend 'ggui' is not available: {why} (use backend='raster' or 'auto')")
    print(f"mrsph: recording with the software rasteriser ({why})", file=sys.stderr)
    return _RasterFrames(width, height, style, scene)


# ----------------------------------------------------------------------------- sinks
class _Mp4Sink:
    def __init__(self, path: Path, fps: float):
        import imageio.v2 as imageio

        # libx264 + yuv420p plays everywhere; macro_block_size=1 stops imageio from
        # silently resizing to a multiple of 16 (the caller already made dims even).
        self.writer = imageio.get_writer(
            str(path),
            format="FFMPEG",
            mode="I",
            fps=fps,
            codec="libx264",
            pixelformat="yuv420p",
            quality=8,
            macro_block_size=1,
            ffmpeg_log_level="error",
        )

    def append(self, img):
        self.writer.append_data(img)

    def close(self):
        self.writer.close()


class _GifSink:
    def __init__(self, path: Path, fps: float):
        self.path, self.fps, self.frames = path, fps, []

    def append(self, img):
        self.frames.append(img)

    def close(self):
        import imageio.v3 as iio

        if self.frames:
            # duration per frame in ms (Pillow); loop=0 means loop forever.
            iio.imwrite(self.path, np.stack(self.frames), extension=".gif", duration=1000.0 / self.fps, loop=0)
        self.frames = []


class _PngSink:
    def __init__(self, path: Path, fps: float):
        from mrsph.io.output import clear_frames

        self.path, self.i = path, 0
        path.mkdir(parents=True, exist_ok=True)
        clear_frames(path, ("png",))

    def append(self, img):
        import imageio.v3 as iio

        iio.imwrite(self.path / f"frame_{self.i:05d}.png", img)
        self.i += 1

    def close(self):
        pass


def _sink_kind(out: Path) -> str:
    suffix = out.suffix.lower()
    if suffix in (".mp4", ".gif"):
        return suffix[1:]
    if suffix == "" or out.is_dir():
        return "png"
    raise ValueError(
        f"{out}: cannot tell what to write (expected a path ending in .mp4 or .gif, or a directory for a PNG sequence)"
    )


# ----------------------------------------------------------------------------- record
def record(
    sim,
    out,
    frames: int,
    width: int | None = None,
    height: int | None = None,
    fps: float | None = None,
    backend: str = "auto",
    progress: bool = True,
    color_mode: str = "level",
    show_virtual: bool = False,
    surface: bool | None = None,
) -> Path:
    """Advance ``sim`` and write ``frames`` frames to ``out``; returns the path written.

    out: ``*.mp4`` (H.264, yuv420p), ``*.gif`` (loops forever), or a directory
    (``frame_00000.png``, ...). Frame 0 is the current state; the simulation advances
    one frame (``sim.advance_frame()``) between frames, so ``frames - 1`` advances.
    width, height, fps default to the scene's ``render.width``, ``render.height`` and
    ``run.fps`` (else 960x540 at 30 fps); mp4 dimensions are rounded up to even numbers.
    backend: "ggui" (shared GGUI renderer, offscreen), "raster" (numpy), or "auto"
    (GGUI when :func:`vulkan_available`, else raster with a notice on stderr).
    surface: the water view (default: the scene's ``render.surface``). The scene's
    stirrers are drawn as circles where they act.
    """
    out = Path(out)
    if int(frames) < 1:
        raise ValueError(
            f"frames: expected a positive number of frames to record (got {frames}); a recording needs an end"
        )
    frames = int(frames)
    kind = _sink_kind(out)
    scene = getattr(sim, "scene", None)
    width = int(width or scene_setting(scene, "render.width"))
    height = int(height or scene_setting(scene, "render.height"))
    fps = float(fps or scene_setting(scene, "run.fps"))
    if surface is None:
        surface = bool(scene_setting(scene, "render.surface"))
    if kind == "mp4" and (width % 2 or height % 2):
        even = (width + width % 2, height + height % 2)
        print(
            f"mrsph: H.264 (yuv420p) needs even dimensions: recording {even[0]}x{even[1]} instead of {width}x{height}",
            file=sys.stderr,
        )
        width, height = even
    if kind != "png":
        out.parent.mkdir(parents=True, exist_ok=True)

    from tqdm import tqdm

    style = Style.from_scene(scene)
    rest_density = getattr(sim, "rest_density", None)
    source = _open_frames(backend, width, height, style, scene)
    sink = {"mp4": _Mp4Sink, "gif": _GifSink, "png": _PngSink}[kind](out, fps)
    bar = tqdm(
        total=frames,
        file=sys.stderr,
        disable=not progress,
        unit="frame",
        desc=f"{out.name} [{source.name}]",
        dynamic_ncols=True,
    )
    try:
        for i in range(frames):
            snap = sim.snapshot()
            img = source.render(
                snap, color_mode, show_virtual, rest_density, stirrer_marks(scene, float(snap.time), snap), surface
            )
            sink.append(img)
            bar.update(1)
            if i + 1 < frames:
                sim.advance_frame()
    finally:
        bar.close()
        source.close()
        sink.close()
    if kind != "png" and not (out.is_file() and out.stat().st_size > 0):
        # the encoder may fail on its own and say so only on its stderr
        raise OSError(f"{out}: the {kind} writer wrote nothing")
    return out

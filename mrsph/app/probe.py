"""Try a GGUI feature in a child process: a broken Vulkan or GLFW set-up can crash the
process outright instead of raising, so the application asks a subprocess first."""

import os
import subprocess
import sys
import tempfile

# Every probe starts Taichi on the CPU, quietly, without the kernel cache.
_START = "import taichi as ti\nti.init(arch=ti.cpu, log_level=ti.ERROR, offline_cache=False)\n"


def run_probe(script: str, marker: str, what: str, timeout_s: float) -> tuple[bool, str]:
    """Run ``script`` after starting Taichi (``ti`` is imported); (True, "") if it printed
    ``marker``, else (False, why), ``what`` naming the attempt in the message ("the
    GGUI/Vulkan probe", "opening a test window")."""
    script = _START + script
    try:
        # In a scratch directory: ImGui drops an imgui.ini into the working directory.
        with tempfile.TemporaryDirectory(prefix="mrsph_probe_") as scratch:
            proc = subprocess.run(
                [sys.executable, "-c", script], capture_output=True, text=True, timeout=timeout_s, cwd=scratch
            )
    except subprocess.TimeoutExpired:
        return False, f"{what} did not finish within {timeout_s:.0f} s"
    except OSError as e:
        return False, f"{what} could not start: {e}"
    if proc.returncode == 0 and marker in proc.stdout:
        return True, ""
    lines = [
        ln.strip() for ln in (proc.stderr + proc.stdout).splitlines() if ln.strip() and not ln.startswith("[Taichi]")
    ]
    how = f"crashed with signal {-proc.returncode}" if proc.returncode < 0 else f"failed (exit code {proc.returncode})"
    return False, f"{what} {how}" + (f": {lines[-1][:200]}" if lines else "")


#: Seconds the window probe may take (Taichi's start and a first frame on a software
#: Vulkan take a few).
WINDOW_PROBE_TIMEOUT_S = 60.0
_display_cache: dict = {}
_PROBE_SCRIPT = r"""
w = ti.ui.Window("mrsph display probe", (64, 48), show_window=True)
w.get_canvas().set_background_color((0.1, 0.1, 0.1))
w.show()
w.destroy()
print("MRSPH_DISPLAY_OK", flush=True)
"""


def display_available() -> tuple[bool, str]:
    """(True, description) when an interactive GGUI window can open here, else (False,
    why). Needs DISPLAY or WAYLAND_DISPLAY; the window itself is tried in a subprocess
    (a broken Vulkan/GLFW setup can crash instead of raising); cached per process."""
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return False, "no display: neither DISPLAY nor WAYLAND_DISPLAY is set"
    key = (os.environ.get("DISPLAY"), os.environ.get("WAYLAND_DISPLAY"))
    if key in _display_cache:
        return _display_cache[key]
    ok, why = run_probe(_PROBE_SCRIPT, "MRSPH_DISPLAY_OK", "opening a test window", WINDOW_PROBE_TIMEOUT_S)
    result = (True, f"a GGUI window opens on {key[0] or key[1]}") if ok else (False, why)
    _display_cache[key] = result
    return result

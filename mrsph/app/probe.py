"""Try a GGUI feature in a child process: a broken Vulkan or GLFW set-up can crash the
process outright instead of raising, so the application asks a subprocess first."""
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
            proc = subprocess.run([sys.executable, "-c", script], capture_output=True,
                                  text=True, timeout=timeout_s, cwd=scratch)
    except subprocess.TimeoutExpired:
        return False, f"{what} did not finish within {timeout_s:.0f} s"
    except OSError as e:
        return False, f"{what} could not start: {e}"
    if proc.returncode == 0 and marker in proc.stdout:
        return True, ""
    lines = [ln.strip() for ln in (proc.stderr + proc.stdout).splitlines()
             if ln.strip() and not ln.startswith("[Taichi]")]
    how = (f"crashed with signal {-proc.returncode}" if proc.returncode < 0
           else f"failed (exit code {proc.returncode})")
    return False, f"{what} {how}" + (f": {lines[-1][:200]}" if lines else "")

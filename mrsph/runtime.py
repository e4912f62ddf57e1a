"""The one place where Taichi is initialised.

Nothing in mrsph touches Taichi at import time; a :class:`~mrsph.simulation.Simulation`
calls :func:`ensure` with the arch and precision it needs, and the command line and the
test fixtures call it too.
"""

from __future__ import annotations

import os
from pathlib import Path

import taichi as ti

from . import kernel_build

ARCHES = ("auto", "cpu", "gpu")
# generation: Taichi programs started (or reset) so far; a Simulation built in an earlier
# one has lost its fields (``Simulation`` checks it)
_state: dict = {"key": None, "arch_name": None, "notice": None, "affinity": None, "generation": 0}

# ``threads="auto"``: scenes that start with fewer real particles than this (by
# dimension: a 3D particle has ~6x the candidates of a 2D one) run on one thread pinned to
# one core. Taichi's CPU backend hands every parallel loop to its thread pool and waits for
# it; waking a pool thread on another core costs 50-100 µs on the 2-core VM this was
# measured on, against ~15 µs on the same core, and a step has ~12 such loops. Measured
# (ms a step, one pinned thread / two threads): 2D dam break 10k 2.77 / 2.77, 20k
# 5.16 / 4.13; 3D adaptive dam break, 4k slots, 4.90 / 4.74; demo_2d 1.31 / 3.02.
AUTO_ONE_THREAD_BELOW = {2: 12000, 3: 4000}


#: Taichi's offline cache keeps at most 100 MB of kernels by default and then drops the
#: least recently used quarter. One scene with one solver leaves 1-3 MB (demo_2d: 3.1 MB,
#: with wcsph as well 4.0 MB), and the test suite's kernels, compiled without the advanced
#: optimisations, far more: after a test run the window's scenes compiled again (20-30 s
#: each instead of 3-5). 1 GiB holds them all; TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES, when
#: set, has the last word.
CACHE_MAX_BYTES = 1 << 30
CACHE_SIZE_ENV = "TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES"


# CUDA and Metal only: Taichi's Vulkan backend would also run on a software Vulkan
# device (lavapipe, installed for offscreen rendering), which is far slower than ti.cpu.
_GPU_ARCHES = ("cuda", "metal")


def _arch_name() -> str:
    return str(ti.lang.impl.current_cfg().arch).split(".")[-1]


def _try_gpu(kwargs) -> bool:
    """Initialise on the first GPU backend that works; False (and reset) if none does.
    Backends whose driver is missing are skipped before ti.init: a failed ti.init falls
    back to the CPU and announces it, which printed "Starting on arch=x64" twice."""
    ti.set_logging_level(ti.ERROR)  # the driver probe warns "libcuda.so lib not found"
    try:
        present = [name for name in _GPU_ARCHES if ti.lang.misc.is_arch_supported(getattr(ti, name))]
    finally:
        ti.set_logging_level(ti.WARN)
    for name in present:
        ti.init(**{**kwargs, "arch": getattr(ti, name), "log_level": ti.ERROR})
        if _arch_name() == name:
            ti.set_logging_level(ti.WARN)
            return True
        ti.reset()
    return False


def ensure(arch: str = "cpu", precision: str = "f32", threads: int | None = None) -> str:
    """Initialise Taichi once for (arch, precision); re-initialise only if they change.

    Re-initialising frees every field, so a process that mixes precisions should build
    its simulations one after another. Returns the name of the backend in use.
    ``arch="gpu"`` on a machine without one falls back to the CPU and leaves a one-line
    notice in :func:`notice` for the application to print.
    """
    if arch not in ARCHES:
        raise ValueError(f"arch: expected one of {', '.join(ARCHES)} (got {arch!r})")
    if precision not in ("f32", "f64"):
        raise ValueError(f"precision: expected f32 or f64 (got {precision!r})")
    if threads == "auto":
        raise ValueError("threads: resolve 'auto' with auto_threads(scene) first")
    key = (arch, precision, threads)
    if _state["key"] == key:
        return _state["arch_name"]
    kernel_build.install()  # Taichi's kernel builds remember the source they read
    if _state["key"] is not None:
        ti.reset()
    _state["notice"] = None
    kwargs = dict(
        arch=ti.cpu, default_fp=ti.f64 if precision == "f64" else ti.f32, log_level=ti.WARN, offline_cache=True
    )
    if threads:
        kwargs["cpu_max_num_threads"] = threads
    if not os.environ.get(CACHE_SIZE_ENV):
        kwargs["offline_cache_max_size_of_files"] = CACHE_MAX_BYTES
    _pin(threads == 1)  # before ti.init: its pool threads inherit the affinity
    if not (arch in ("auto", "gpu") and _try_gpu(kwargs)):
        if arch == "gpu":
            _state["notice"] = (
                "--arch gpu: Taichi found no CUDA or Metal GPU on this machine; running on the CPU instead"
            )
        ti.init(**kwargs)
    _state["key"] = key
    _state["arch_name"] = _arch_name()
    _state["generation"] += 1
    return _state["arch_name"]


def generation() -> int:
    """How many Taichi programs :func:`ensure` and :func:`reset` have started or ended: a
    field made when it read otherwise is gone."""
    return _state["generation"]


def _pin(one_core: bool) -> None:
    """Pin this thread (and the pool threads Taichi starts next) to one core, or undo it."""
    if not hasattr(os, "sched_setaffinity"):
        return
    if one_core:
        allowed = os.sched_getaffinity(0)
        if len(allowed) > 1:
            _state["affinity"] = _state["affinity"] or allowed
            core = _current_core()
            os.sched_setaffinity(0, {core if core in allowed else min(allowed)})
    elif _state["affinity"]:
        os.sched_setaffinity(0, _state["affinity"])
        _state["affinity"] = None


def _current_core() -> int | None:
    """The core this thread runs on now (Linux: field 39 of /proc/thread-self/stat), or None.
    One-thread runs pin to it rather than to the lowest core, so that two of them side
    by side (two recordings, or ``pytest -n 2``) run on the two cores the scheduler
    has already given them instead of sharing one."""
    try:
        with open("/proc/thread-self/stat", encoding="ascii") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return int(fields[36])  # field 39 counted from 1; fields 1-2 are before ")"
    except (OSError, IndexError, ValueError):
        return None


def starting_particles(scene) -> int:
    """About how many real particles the scene starts with: its fluid at the finest
    spacing, or for an adaptive scene at the coarsest (it starts there, but for the
    slabs that whole coarse cells leave, and refines only where a criterion asks)."""
    uniform = scene.estimate_particles()
    if not scene.data["adaptivity"]["enabled"]:
        return uniform
    return uniform // 2 ** (int(scene.data["dim"]) * (int(scene.data["adaptivity"]["levels"]) - 1))


def auto_threads(scene, threads="auto"):
    """Resolve ``threads``: an int stays; "auto" is 1 for scenes that start with fewer
    than AUTO_ONE_THREAD_BELOW particles (pinned, see there), else None (all cores)."""
    if threads != "auto":
        return threads
    small = starting_particles(scene) < AUTO_ONE_THREAD_BELOW[int(scene.data["dim"])]
    return 1 if small else None


def on_gpu() -> bool:
    """Whether Taichi runs on a GPU (after ``ensure``): serial loops there run on one of
    its threads, so the passes that have a parallel form take it."""
    return _state["arch_name"] in _GPU_ARCHES


def notice() -> str | None:
    """A one-line message about a fallback made by the last :func:`ensure`, if any."""
    return _state["notice"]


def reset() -> None:
    """Forget the current initialisation (tests call this between modules)."""
    if _state["key"] is not None:
        ti.reset()
        _state["generation"] += 1
    _state["key"] = None
    _pin(False)


def finish() -> None:
    """End this process's Taichi program, which writes the kernels it compiled into the
    offline cache, one process at a time. Taichi's own lock on the cache gives up when
    another process holds it ("Lock ... ticache.lock failed") and those kernels are lost;
    the window and its simulations' processes end together. The lock file sits beside
    the cache, where ``ti cache clean`` leaves it."""
    if _state["key"] is None:
        return
    try:
        import fcntl

        lock = Path(ti.lang.impl.current_cfg().offline_cache_file_path).parent / "mrsph-finish.lock"
        lock.parent.mkdir(parents=True, exist_ok=True)
        handle = open(lock, "w")  # noqa: SIM115  (held across the reset below)
    except (ImportError, OSError, AttributeError):
        reset()  # no fcntl (Windows) or no place for the lock: Taichi's lock alone
        return
    with handle:
        fcntl.flock(handle, fcntl.LOCK_EX)  # released when the file closes
        reset()

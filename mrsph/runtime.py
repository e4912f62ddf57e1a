"""The one place where Taichi is initialised.

Nothing in mrsph touches Taichi at import time; a :class:`~mrsph.solver.Simulation`
calls :func:`ensure` with the arch and precision it needs, and the command line and the
test fixtures call it too.
"""
from __future__ import annotations

import taichi as ti

ARCHES = ("auto", "cpu", "gpu")
_state: dict = {"key": None, "arch_name": None, "notice": None}


# CUDA and Metal only: Taichi's Vulkan backend would also run on a software Vulkan
# device (lavapipe, installed for offscreen rendering), which is far slower than ti.cpu.
_GPU_ARCHES = ("cuda", "metal")


def _arch_name() -> str:
    return str(ti.lang.impl.current_cfg().arch).split(".")[-1]


def _try_gpu(kwargs) -> bool:
    """Initialise on the first GPU backend that works; False (and reset) if none does."""
    for name in _GPU_ARCHES:
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
    key = (arch, precision, threads)
    if _state["key"] == key:
        return _state["arch_name"]
    if _state["key"] is not None:
        ti.reset()
    _state["notice"] = None
    kwargs = dict(arch=ti.cpu, default_fp=ti.f64 if precision == "f64" else ti.f32,
                  log_level=ti.WARN, offline_cache=True)
    if threads:
        kwargs["cpu_max_num_threads"] = threads
    if not (arch in ("auto", "gpu") and _try_gpu(kwargs)):
        if arch == "gpu":
            _state["notice"] = ("--arch gpu: Taichi found no CUDA or Metal GPU on this "
                                "machine; running on the CPU instead")
        ti.init(**kwargs)
    _state["key"] = key
    _state["arch_name"] = _arch_name()
    return _state["arch_name"]


def notice() -> str | None:
    """A one-line message about a fallback made by the last :func:`ensure`, if any."""
    return _state["notice"]


def reset() -> None:
    """Forget the current initialisation (tests call this between modules)."""
    if _state["key"] is not None:
        ti.reset()
    _state["key"] = None

"""mrsph: adaptive-resolution SPH fluids in Taichi.

The Python API, without importing Taichi until it is used::

    import mrsph
    scene = mrsph.load_scene("dam_break_2d", {"fluid.viscosity": "1.5"})
    sim = mrsph.Simulation(scene, arch="cpu")
    for _ in range(10):
        sim.advance_frame()
    print(sim.stats())

``load_scene``, ``Scene``, ``SceneError`` and ``list_scenes`` come from
:mod:`mrsph.scene.config` (no Taichi); ``Simulation`` and ``SimulationError`` from
:mod:`mrsph.simulation` and ``Disturbance`` from :mod:`mrsph.scene.interaction` (these import
Taichi on first access). The command line is :mod:`mrsph.cli` (``python3 main.py``).
"""
from __future__ import annotations

import importlib

__version__ = "0.4.0"  # pyproject.toml's (tests/test_packaging.py holds them together)

# public name -> submodule it lives in; resolved on first access (PEP 562)
_LAZY = {
    "load_scene": "scene.config",
    "Scene": "scene.config",
    "SceneError": "scene.config",
    "list_scenes": "scene.config",
    "Simulation": "simulation",
    "SimulationError": "simulation",
    "Disturbance": "scene.interaction",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'mrsph' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))

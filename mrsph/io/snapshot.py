"""What the application layer reads of a simulation: one frame, as numpy arrays.

Kept free of Taichi so that the window, the renderers and their tests can use it
without a simulation (as ``tests/fake_app.py`` does).
"""

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Snapshot:
    """One frame (fields documented in docs/ARCHITECTURE.md)."""

    dim: int
    levels: int
    time: float
    frame: int
    x: np.ndarray
    v: np.ndarray
    m: np.ndarray
    rho: np.ndarray
    level: np.ndarray
    kind: np.ndarray
    radius: np.ndarray
    domain_min: np.ndarray
    domain_max: np.ndarray
    obstacles: list = field(default_factory=list)
    stats: dict = field(default_factory=dict)
    p: np.ndarray | None = None  # pressure, Pa (None: a stand-in without one)

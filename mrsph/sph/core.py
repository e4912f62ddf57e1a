"""What every pass of a step reads: the particles, the levels, the neighbour grids and
their visitor, and the walls, built once (``Simulation``) and handed whole to each part,
which keeps the members it uses."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Core:
    """``dim``; ``levels`` (1 without adaptivity); ``adaptive``; ``pool``
    (``particles.ParticlePool``); ``lev`` (``levels.Levels``: h, s, m, kernel constants
    and ρ0); ``grids`` (``grid.LevelGrids``); ``nb`` (``neighbours.Neighbours``);
    ``boundary`` (``boundary.Boundary``)."""

    dim: int
    levels: int
    adaptive: bool
    pool: object
    lev: object
    grids: object
    nb: object
    boundary: object

"""The benchmark's cases: what is timed, for how long."""

from __future__ import annotations

from typing import NamedTuple

#: The phases that exist only because of the multiresolution scheme.
MULTIRES_PHASES = ("adapt", "virtual_coupling", "virtual_advect")


#: Turns an adaptive scene into the uniform run of a pair.
UNIFORM_OVERRIDE = "adaptivity.enabled=false"


#: The demo's finest spacing is compared with a uniform run of this many particles.
DEMO_REFERENCE_PARTICLES = 10_000


KINDS = ("run", "pair", "demo")


class Case(NamedTuple):
    """One benchmark case; ``warm`` and ``interval`` are simulated seconds."""

    name: str
    scene: str
    overrides: tuple
    warm: float
    interval: float
    kind: str = "run"


def _cases(full: bool) -> list[Case]:
    """The quick set (about 3 minutes on 2 free cores), or the full set (quick + long).

    Dam breaks are timed while the column collapses, not on the initial lattice (which
    is 1.3-2x cheaper). Pairs are timed once the front has reached the obstacle and the
    adaptive run has refined next to it (t = 0.24 s in 2D, 0.2 s in 3D); spacings give
    uniform runs of ~12k and ~38k particles in 2D, ~6k and ~21k in 3D.
    """
    quick = [
        Case("dam_break_2d uniform ~10k", "dam_break_2d", ("particles.spacing=0.0035",), 0.1, 0.02),
        Case("dam_break_3d uniform ~30k", "dam_break_3d", ("particles.spacing=0.0092",), 0.2, 0.005),
        Case(
            "dam_break_obstacle_2d s=3.5mm", "dam_break_obstacle_2d", ("particles.spacing=0.0035",), 0.24, 0.01, "pair"
        ),
        Case("dam_break_obstacle_3d s=15mm", "dam_break_obstacle_3d", ("particles.spacing=0.015",), 0.2, 0.01, "pair"),
        Case(
            "dam_break_2d dfsph ~10k", "dam_break_2d", ("particles.spacing=0.0035", "fluid.solver=\"dfsph\""), 0.1, 0.05
        ),
        Case("dam_break_2d pbf ~10k", "dam_break_2d", ("particles.spacing=0.0035", "fluid.solver=\"pbf\""), 0.1, 0.1),
        # the demos from their start over a simulated second, the opening stir included
        Case("demo_2d rendered", "demo_2d", (), 0.0, 1.0, "demo"),
        Case("demo_3d rendered", "demo_3d", (), 0.0, 1.0, "demo"),
        Case("pool_3d rendered", "pool_3d", (), 0.0, 0.2, "demo"),
    ]
    if not full:
        return quick
    return quick + [
        Case("dam_break_2d uniform ~50k", "dam_break_2d", ("particles.spacing=0.0016",), 0.25, 0.02),
        Case("dam_break_3d uniform ~100k", "dam_break_3d", ("particles.spacing=0.0063",), 0.2, 0.01),
        # the same flows with the divergence-free solver: its steps are ~10x longer, so the
        # interval is longer too (a handful of steps would time the launches, not the flow)
        Case(
            "dam_break_2d dfsph ~50k",
            "dam_break_2d",
            ("particles.spacing=0.0016", "fluid.solver=\"dfsph\""),
            0.25,
            0.05,
        ),
        Case("dam_break_2d pbf ~50k", "dam_break_2d", ("particles.spacing=0.0016", "fluid.solver=\"pbf\""), 0.25, 0.1),
        Case("dam_break_3d pbf ~100k", "dam_break_3d", ("particles.spacing=0.0063", "fluid.solver=\"pbf\""), 0.2, 0.1),
        Case(
            "dam_break_3d dfsph ~100k",
            "dam_break_3d",
            ("particles.spacing=0.0063", "fluid.solver=\"dfsph\""),
            0.2,
            0.03,
        ),
        Case("dam_break_obstacle_2d s=2mm", "dam_break_obstacle_2d", ("particles.spacing=0.002",), 0.24, 0.01, "pair"),
        Case("dam_break_obstacle_3d s=10mm", "dam_break_obstacle_3d", ("particles.spacing=0.01",), 0.2, 0.01, "pair"),
        Case(
            "dam_break_obstacle_2d s=2mm L=3",
            "dam_break_obstacle_2d",
            ("particles.spacing=0.002", "adaptivity.levels=3"),
            0.24,
            0.01,
            "pair",
        ),
        Case(
            "dam_break_obstacle_3d s=6mm L=3",
            "dam_break_obstacle_3d",
            ("particles.spacing=0.006", "adaptivity.levels=3"),
            0.2,
            0.01,
            "pair",
        ),
        # the finest pair: the uniform twin has 166k particles (~6 minutes, most of it
        # the uniform run's warm-up)
        Case(
            "dam_break_obstacle_3d s=5mm L=3",
            "dam_break_obstacle_3d",
            ("particles.spacing=0.005", "adaptivity.levels=3"),
            0.2,
            0.01,
            "pair",
        ),
    ]

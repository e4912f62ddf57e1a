"""Divergence-free SPH (Bender & Koschier 2015): the scene keys of ``[dfsph]`` and their
rules, Taichi-free, read by the scene's schema (``mrsph.scene.config``); the solver itself
is ``solver.py``, with its stopping rule (``tolerance.py``) and what its solves did
(``counts.py``)."""

from mrsph.pressure import key

NAME = "dfsph"
DOC = (
    "dfsph, divergence-free SPH (Bender & Koschier 2015), implicit, time step tied to the flow speed "
    "(keys in [dfsph])"
)


# The [dfsph] table: its keys, then its doc (a pair the schema turns into a Table).
TABLE = (
    {
        "cfl": key(
            "float",
            0.4,
            "(0, 1]",
            doc="lambda of the CFL bound dt <= lambda s / max |u| "
            "(s the particle's level spacing): a particle moves at most lambda spacings a step",
        ),
        "pressure_cfl": key(
            "float",
            0.3,
            ">= 0",
            doc="lambda_p of the pressure bound dt <= lambda_p s / sqrt(p / rho) (p the particle's last "
            "pressure, s its level's spacing): the pressure holds each particle in its place in the "
            "lattice with a stiffness of order p / s^2, explicitly, and a step past about 0.45 s / "
            "sqrt(p / rho) lets the lattice ring (docs/METHOD.md §16); 0: no such bound",
        ),
        "density_tolerance": key(
            "float",
            0.001,
            "> 0",
            doc="the density solve stops when the average density error it leaves, |rho* - rho0| / rho0 "
            "over the particles in its system, is within this (0.001 = 0.1 %); of an error a particle "
            "already has, the part that correction_time leaves to later steps is not counted",
        ),
        "rest_tolerance": key(
            "float",
            0.00001,
            "> 0",
            doc="the tightest density_tolerance gets: in a slow flow (slow_flow) density_tolerance and "
            "max_density_error are scaled by how slow, the first down to this. An error eta a solve "
            "leaves is undone at about eta s / correction_time, a noise of its own in water at rest, "
            "and a smooth pressure error shows in the density only where it ends, at a floor: the "
            "80-deep tank at rest needs 1e-5 (docs/METHOD.md §16); = density_tolerance: unscaled",
        ),
        "slow_flow": key(
            "float",
            0.1,
            "(0, 1]",
            doc="a step in which the real particles move on average less than this share of their "
            "spacing is a slow flow: the tolerances are scaled by mean |u| dt / s over this (see "
            "rest_tolerance)",
        ),
        "max_density_error": key(
            "float",
            0.01,
            "> 0",
            doc="and until no particle's density error is above this (0.01 = 1 %; in a slow flow scaled "
            "as density_tolerance is): a hot spot of a few dozen particles hides in the average "
            "(docs/performance.md, the stirred soak); larger is faster",
        ),
        "correction_time": key(
            "float",
            0.002,
            ">= 0",
            unit="s",
            doc="a density error a particle already has (a compression, or within the fluid an "
            "expansion) is removed over this time: a share dt / correction_time of it a step, all of "
            "it in a step this long or longer (0: within every step, the paper's). Removed within a "
            "step that the CFL bound shortened, a compression cost a speed proportional to the flow's "
            "own and fed it (docs/METHOD.md §16)",
        ),
        "divergence_tolerance": key(
            "float",
            0.01,
            "> 0",
            doc="the divergence solve stops when the "
            "average density rate of change times dt, over rho0, is within this",
        ),
        "min_iterations": key("int", 1, ">= 0", doc="iterations of the density solve at least"),
        "max_iterations": key(
            "int",
            100,
            ">= 1",
            doc="iterations of the density solve at most; "
            "a solve that stops here is counted in stats (unconverged) and warned once",
        ),
        "shorten_steps": key(
            "int",
            3,
            ">= 0",
            doc="a density solve that stops at max_iterations short of its tolerance is run again on "
            "a step half as long (the kick redone, the drift not yet made), up to this many times; only "
            "one still short at the last is counted unconverged (0: never; docs/METHOD.md §16)",
        ),
        "divergence_min_iterations": key(
            "int", 0, ">= 0", doc="velocity updates of the divergence solve at least"
        ),
        "divergence_max_iterations": key(
            "int",
            100,
            ">= 1",
            doc="velocity updates of the divergence solve at most (counted and warned as max_iterations)",
        ),
        "divergence_solve": key(
            "bool",
            True,
            doc="run the divergence solve each step (false: the density solve alone, as IISPH-like schemes)",
        ),
    },
    "The divergence-free solver (fluid.solver = \"dfsph\"); ignored by the other solvers.",
)


def rules(check, data: dict) -> None:
    """The cross-field rules of a scene that runs this solver (``check.add`` reports)."""
    ad = data["adaptivity"]
    if ad and ad["enabled"] and ad["coupling"] == "symmetric":
        check.add(
            "adaptivity.coupling",
            'not with fluid.solver = "dfsph"',
            '"symmetric"',
            '"variational" (the implicit solver hands a virtual particle\'s reaction to its '
            "owners and takes its velocity from them)",
        )


def solver_class():
    """The Taichi class (imported here, on first use, so that the keys stay Taichi-free)."""
    from .solver import DFSPH

    return DFSPH

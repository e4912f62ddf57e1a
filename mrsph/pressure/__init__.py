"""Pressure solvers, chosen by name (``fluid.solver``).

Each solver is a package here: its ``__init__`` holds its scene keys (``TABLE``, the
``[name]`` table of a scene, or None), their cross-field ``rules`` and a line of
``DOC``, without Taichi, so that the scene's schema can read them; its ``solver.py``
holds the solver class, built on ``PressureSolver`` (``base.py``: the hooks a step calls
and the time-step bound each solver owns). ``SOLVERS`` is the registry: a new solver is
its package and one line there.
"""

import importlib

SOLVERS = (
    "wcsph",  # weakly compressible (the default)
    "dfsph",  # divergence-free, implicit
    "pbf",  # position based, a time step tied to the frame
)


def key(*args, **kwargs):
    """A scene key of a solver's ``TABLE``, as the schema's ``Key`` takes it (kind, default,
    range, unit, doc, ...): kept as its arguments, so that this stays free of the schema."""
    return args, kwargs


def spec(name: str):
    """The Taichi-free package of solver ``name``: NAME, DOC, TABLE, rules, solver_class."""
    if name not in SOLVERS:
        raise ValueError(f"fluid.solver: expected one of {', '.join(SOLVERS)} (got {name!r})")
    return importlib.import_module(f"{__name__}.{name}")


def solver_class(name: str):
    """The solver class of ``name`` (imports Taichi)."""
    return spec(name).solver_class()

"""Weakly compressible SPH: pressure from an equation of state, time step tied to the
sound speed. Its keys are the fluid's own (``fluid.stiffness``, ``fluid.eos``,
``fluid.gamma``, ``fluid.clamp_negative_pressure``); the other solvers read the sound speed
that ``fluid.stiffness`` gives (the artificial viscosity's speed, the mouse's cap), the rest
is this solver's alone. The solver is ``solver.py``."""

NAME = "wcsph"
DOC = (
    "wcsph, weakly compressible, pressure from the equation of state fluid.eos, time step tied to "
    "the sound speed sqrt(fluid.stiffness)"
)
TABLE = None


def rules(check, data: dict) -> None:
    """No rules of its own."""


def solver_class():
    from .solver import WCSPH

    return WCSPH

"""Pressure solvers, chosen by name: each is a module with the same small interface.

A solver is built with the simulation's parts (``Parts``) and plugs into the passes of a
step (``solver.py``):

- ``density_done(i)`` (``ti.func``): particle i's density is final; set its pressure
  (an equation of state) or whatever the solver keeps per particle;
- ``pair_factor(i, inv_rho)`` (``ti.func``): the per-particle factor of the pair pressure
  term, p/ρ² with the pressure that i shows its neighbours (the level coupling decides
  that pressure, ``multires.coupling``);
- ``pair_term(i, j, grad)`` (``ti.func``): the pressure part of the force on i from j
  along r_ij, given the kernel gradient's scalar factor (∇W = grad · r_ij);
- ``signal_speed()`` (host): the speed the CFL bound adds to |u| (the sound speed of a
  weakly compressible fluid); ``cfl_number(physics)`` and ``cfl_rate(c, |u|, l)``
  (``ti.func``): the CFL bound dt <= λ / rate;
- ``damping_speed()`` (host): the c of the artificial viscosity's α c h, the sound speed
  sqrt(k) of ``fluid.stiffness`` for both solvers, so that switching solvers keeps the
  scene's dissipation;
- ``after_density(n, dt, phase)`` and, for an ``implicit`` solver, ``solve(n, dt, phase)``:
  host hooks the step calls after the density pass and between the kick and the drift;
- ``note_step(moved)`` (``ti.func``, an ``implicit`` solver's): the spacings the step's
  fastest particle moves, max |u| dt / s, once the integrator has chosen dt (dfsph
  tightens its tolerance in slow flow);
- ``one_launch``: True when those hooks do nothing on the host, so that an unprofiled
  step runs as one launch (``fused.py``);
- ``take_stats()``, ``reset_counters()``: iterations and density error for stats.csv;
- ``live_keys`` and ``set_param``: its live-tunable scene keys.

Solvers: ``wcsph`` (``wcsph.py``, METHOD.md §1: equation of state and the symmetric pair
pressure force) and ``dfsph`` (``dfsph.py``, divergence-free SPH: implicit, with a time
step set by the flow speed).
"""

from .dfsph import DFSPH
from .wcsph import WCSPH

SOLVERS = {"wcsph": WCSPH, "dfsph": DFSPH}


def make(name: str, parts):
    """The pressure solver ``name`` built on ``parts``."""
    try:
        cls = SOLVERS[name]
    except KeyError:
        raise ValueError(f"fluid.solver: expected one of {', '.join(SOLVERS)} (got {name!r})") from None
    return cls(parts)

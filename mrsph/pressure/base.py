"""What every pressure solver is to a step (SPlisHSPlasH's ``TimeStep`` in spirit): the
device hooks the density, force and integration passes call, the passes it adds to the
step's list (``sph/step.py``), and the time-step bound it owns. Each hook has a
do-nothing default, so a solver writes only what it does.

Device hooks (``ti.func``), called inside the other passes' loops:

- ``density_done(i)``: particle i's density is final (an equation of state sets p_i);
- ``pair_factor(i, 1/ρ_i)``: the per-particle factor of the pair pressure term;
- ``pair_term(i, j, grad)``: the pressure part of the pair force along r_ij, given the
  kernel gradient's scalar factor (∇W = grad · r_ij); 0 for a solver that does not push
  through the force pass;
- ``cfl_rate(c, |u|, l)``: the rate of the CFL bound, dt <= λ / rate (0: no CFL bound);
- ``step_rate(i, l)``: a bound of the solver's own on particle i, dt <= 1 / rate (read
  only where ``has_step_rate``);
- ``note_step(dt)``: the step's dt, once chosen.

Passes (``sph.step.Pass`` lists), which the Simulation schedules around its own:
``after_density()`` (before the forces), ``after_kick()`` (on the kicked velocities,
before the drift) and ``after_drift()`` (on the drifted positions). A solver whose
passes all have a device function lets a step run as one launch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import taichi as ti


@dataclass(frozen=True)
class TimeStepBound:
    """The time-step bound a solver sets, as the integrator applies it and as a blow-up
    message names it: dt <= λ L / (c + |u|) over the particles (L their level's
    ``length``: "h", the support, or "s", the spacing; c the ``signal_speed``), capped at
    ``dt_max``; ``key`` is λ's scene key and ``says`` a sentence on what sets the step."""

    key: str
    number: float
    signal_speed: float
    length: str
    dt_max: float
    says: str
    even_last_steps: bool = False  # a frame's steps are equal, what is left over the fewest (see integrator)
    force_limited: bool = True  # the force bound λ_f sqrt(h / |a|) applies

    def speed_at(self, dt: float, h0: float, s0: float) -> float:
        """|u| of a particle at the finest level whose CFL bound gives ``dt``."""
        length = h0 if self.length == "h" else s0
        return self.number * length / dt - self.signal_speed


@ti.data_oriented
class PressureSolver:
    """The base of every solver: the hooks and passes a step calls, with defaults that
    do nothing. A subclass sets ``name`` and overrides what it does; it is built as
    ``cls(core, params, coupling, fade, state, warn)``: the storage and geometry
    (``sph.core.Core``), the scene's frozen params (its own table is
    ``getattr(params, name)``), the level coupling's hooks, the split fade
    (multires/fade.py), the step's scalars and outcome (``sph.step.StepState``) and how a
    warning reaches the user."""

    name = ""
    live_keys: tuple = ()
    incompressible = False  # a block at rest starts at ρ0 with its hydrostatic pressure
    # the step's order: False, sort, measure, push, then integrate; True, integrate (predict)
    # first, then sort, measure and project the predicted positions (a position-based solver)
    predicts = False
    uses_forces = True  # the force pass runs (pair pressure, viscosity); False: the solver's passes do it
    has_step_rate = False  # ``step_rate`` bounds the step (else it is not called)

    # ------------------------------------------------------------------ host
    def bound(self) -> TimeStepBound:
        raise NotImplementedError

    def signal_speed(self) -> float:
        """The c the CFL bound adds to |u| (a weakly compressible fluid's sound speed)."""
        return self.bound().signal_speed

    def damping_speed(self) -> float:
        """The c of the artificial viscosity's α c h: the sound speed sqrt(k) of
        ``fluid.stiffness`` for every solver, so that switching solvers keeps the scene's
        dissipation."""
        raise NotImplementedError

    def force_viscosity(self, fluid) -> float:
        """μ of the force pass (Eq. 19): the scene's ``fluid.viscosity``."""
        return fluid.viscosity

    def stiffness(self) -> float:
        """k of the hydrostatic start's compression (inf: incompressible, none)."""
        return float("inf")

    def after_density(self) -> list:
        return []

    def after_kick(self) -> list:
        return []

    def after_drift(self) -> list:
        return []

    def take_stats(self) -> dict:
        """What the solver did since the last call, for the stats row (None: the row
        takes the real particles' mean compression)."""
        return {
            "density_iterations": 0.0,
            "divergence_iterations": 0.0,
            "density_error": None,
            "unconverged": 0,
            "shortened": 0,
            "clamped": 0,
        }

    def reset_counters(self) -> None:
        pass

    def solve_loops(self, stats: dict) -> float:
        """Neighbour loops a step of its host-driven solves (``stats``: a stats row)."""
        return 0.0

    def reported_pressure(self, p: np.ndarray) -> np.ndarray:
        """The pressure a reader sees (dumps, snapshots, the validation), from the pool's
        p of the first len(p) slots as the last step left them: p itself, unless a solver
        keeps part of it apart (pbf: its tensile correction's, outside the warm start)."""
        return p

    def reported_density(self, rho: np.ndarray, kind: np.ndarray) -> np.ndarray:
        """The density a reader sees (dumps, the stats), of the first len(rho) slots: the
        pool's, the density pass's, unless the solver measured its own after it (pbf: its
        last iteration's, at the projected positions)."""
        return rho

    def forget_step(self) -> None:
        """The slots no longer hold the last step's particles (a reset, a restored state,
        a sort outside a step): drop what ``reported_pressure`` and ``reported_density``
        take from the step."""

    def set_param(self, key: str, value) -> None:
        raise ValueError(f"{key}: not live-tunable with fluid.solver = {self.name}")

    # ------------------------------------------------------------------ device
    @ti.func
    def density_done(self, i):
        pass

    @ti.func
    def pair_factor(self, i, inv):
        pass

    @ti.func
    def pair_term(self, i, j, grad):
        return 0.0

    @ti.func
    def cfl_rate(self, c_sound, speed, l):
        return 0.0

    @ti.func
    def step_rate(self, i, l):
        return 0.0

    def step_rate_says(self, rate: float) -> str:
        """What the solver's own bound is, for a blow-up message (``rate`` its max, 1/s)."""
        return f"{self.name}'s own time-step bound sets it (1/dt = {rate:.3g} 1/s)"

    @ti.func
    def note_step(self, dt):
        pass

"""Weakly compressible SPH (METHOD.md §1, thesis Eq. 14–16): pressure from an equation of
state (``eos.py``, ``fluid.eos``), and the symmetric pair pressure force

    F_i = −m_i Σ_j m_j (p_i/ρ_i² + p_j/ρ_j²) ∇W_spiky(x_i − x_j, h_l),

the volume m_i/ρ_i times Eq. 16. The time step's CFL bound adds the sound speed
sqrt(k) to |u| (``signal_speed``), which is what ties this solver's step to k.
"""

import taichi as ti

from ..base import PressureSolver, TimeStepBound
from ..eos import pressure, sound_speed


@ti.data_oriented
class WCSPH(PressureSolver):
    name = "wcsph"
    live_keys = ("fluid.stiffness",)

    def __init__(self, core, params, coupling, fade, state, warn):
        """params: the scene's (its [fluid] and [physics]); coupling: the level coupling's
        hooks (the pressure a particle shows); fade: a split child's pressure reads ρ − δρ
        (multires/fade.py); state and warn: unused (no solve, nothing to warn of)."""
        fluid = params.fluid
        self.pool, self.lev, self.coupling, self.fade = core.pool, core.lev, coupling, fade
        self.physics = params.physics
        self.rest_density = core.lev.rest_density
        self.eos = fluid.eos
        self.tait = self.eos == "tait"
        self.clamp = fluid.clamp_negative_pressure
        self.gamma = fluid.gamma
        self.k = ti.field(float, shape=())
        self.k[None] = fluid.stiffness
        # p/ρ² with the pressure a particle shows its neighbours, set with the density:
        # it takes two divisions out of every pair
        self.press_term = ti.field(float, shape=core.pool.capacity)
        self._update_speed()

    def _update_speed(self):
        # host copy for dt, from the stored (possibly f32) k that the pressure kernel uses
        self._c = sound_speed(float(self.k[None]), self.eos)

    def bound(self) -> TimeStepBound:
        """dt <= λ h / (c + |u|), c = sqrt(k) the sound speed at rest (``physics.cfl``)."""
        return TimeStepBound(
            "physics.cfl",
            self.physics.cfl,
            self._c,
            "h",
            self.physics.dt_max,
            f"the sound speed sqrt(fluid.stiffness) = {self._c:.3g} m/s",
        )

    def damping_speed(self) -> float:
        """The artificial viscosity's c: the sound speed, as in the CFL bound."""
        return self._c

    def stiffness(self) -> float:
        return float(self.k[None])

    def set_param(self, key: str, value) -> None:
        self.k[None] = float(value)
        self._update_speed()

    @ti.func
    def cfl_rate(self, c_sound, speed, l):
        """(c + |u|)/h_l: dt = λ h / (c + |u|)."""
        return (c_sound + speed) / self.lev.h[l]

    @ti.func
    def density_done(self, i):
        p = ti.static(self.pool.p)
        p[i].p = pressure(
            p[i].rho - self.fade.excess(i), self.rest_density, self.k[None], self.gamma, self.tait, self.clamp
        )

    @ti.func
    def pair_factor(self, i, inv):
        p = ti.static(self.pool.p)
        self.press_term[i] = self.coupling.partner_pressure(p[i].kind, p[i].p) * inv * inv

    @ti.func
    def pair_term(self, i, j, grad):
        return -(self.press_term[i] + self.press_term[j]) * grad

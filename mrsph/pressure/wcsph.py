"""Weakly compressible SPH (METHOD.md §1, thesis Eq. 14–16): pressure from an equation of
state (``eos.py``, ``fluid.eos``), and the symmetric pair pressure force

    F_i = −m_i Σ_j m_j (p_i/ρ_i² + p_j/ρ_j²) ∇W_spiky(x_i − x_j, h_l),

the volume m_i/ρ_i times Eq. 16. The time step's CFL bound adds the sound speed
sqrt(k) to |u| (``signal_speed``), which is what ties this solver's step to k.
"""

import taichi as ti

from .eos import pressure, sound_speed


@ti.data_oriented
class WCSPH:
    live_keys = ("fluid.stiffness",)
    implicit = False  # no solve: the pressure is explicit, from the density
    one_launch = True  # no host work in its hooks: a step can be one launch (fused.py)

    def __init__(self, parts):
        fl = parts.scene["fluid"]
        self.pool, self.coupling, self.lev = parts.pool, parts.coupling, parts.lev
        self.fade = parts.fade  # a split child's pressure reads rho - drho (multires/fade.py)
        self.rest_density = float(fl["rest_density"])
        self.eos = fl["eos"]
        self.tait = self.eos == "tait"
        self.clamp = bool(fl["clamp_negative_pressure"])
        self.gamma = float(fl["gamma"])
        self.k = ti.field(float, shape=())
        self.k[None] = float(fl["stiffness"])
        # p/ρ² with the pressure a particle shows its neighbours, set with the density:
        # it takes two divisions out of every pair
        self.press_term = ti.field(float, shape=parts.pool.capacity)
        self._update_speed()

    def _update_speed(self):
        # host copy for dt, from the stored (possibly f32) k that the pressure kernel uses
        self._c = sound_speed(float(self.k[None]), self.eos)

    def signal_speed(self) -> float:
        """The sound speed at rest, sqrt(k): the CFL bound is λ h/(c + |u|)."""
        return self._c

    def damping_speed(self) -> float:
        """The artificial viscosity's c: the sound speed, as in the CFL bound."""
        return self._c

    def stiffness(self) -> float:
        return float(self.k[None])

    def cfl_number(self, physics: dict) -> float:
        """λ of dt <= λ h / (c + |u|): ``physics.cfl``."""
        return float(physics["cfl"])

    def after_density(self, n: int, dt: float, phase) -> None:
        pass

    def take_stats(self) -> dict:
        return {"density_iterations": 0.0, "divergence_iterations": 0.0, "density_error": None, "unconverged": 0}

    def reset_counters(self) -> None:
        pass

    @ti.func
    def cfl_rate(self, c_sound, speed, l):
        """(c + |u|)/h_l: dt = λ h / (c + |u|)."""
        return (c_sound + speed) / self.lev.h[l]

    def set_param(self, key: str, value) -> None:
        self.k[None] = float(value)
        self._update_speed()

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

"""The density solve's tolerance in slow flow (``dfsph.py``; keys ``dfsph.rest_tolerance``
and ``dfsph.slow_flow``). The compression a solve leaves, η, is undone the next step at a
speed of about η s/dt. Where the fastest particle moves a good part of a spacing a step,
that is a small share of its speed (η/λ in a step the CFL bound sets); in water at rest,
whose step is dt_max, it is a noise of its own that no flow outgrows (the resting 3D
tank's mean speed read 0.0126 √(gH) unscaled, docs/performance.md, "The rest noise")."""

import taichi as ti


@ti.data_oriented
class RestTolerance:
    """η_step = max(rest_tolerance, density_tolerance · min(1, m / slow_flow)), m the
    spacings the step's fastest particle moves. Kept in fields, not compiled in, so that
    a scene's values do not compile the solver's kernels again."""

    def __init__(self, cfg: dict, density_tolerance: float):
        self.share = ti.field(ti.f64, shape=())     # m / slow_flow, from ``note_step``
        self.floor = ti.field(ti.f64, shape=())     # rest_tolerance, at most the scene's
        self.slow = ti.field(ti.f64, shape=())      # slow_flow
        self.share[None] = 1.0
        self.floor[None] = min(float(cfg["rest_tolerance"]), density_tolerance)
        self.slow[None] = float(cfg["slow_flow"])

    @ti.func
    def note_step(self, moved):
        """The integrator's word on the step just chosen: m = max_i |u_i| dt / s_l."""
        self.share[None] = moved / self.slow[None]

    @ti.func
    def of(self, tol):
        """This step's tolerance, ``tol`` the scene's density_tolerance."""
        return ti.max(self.floor[None], tol * ti.min(self.share[None], 1.0))

"""A whole step in one kernel launch (METHOD.md §1; the phases of ``Simulation.step``).

A step of a few thousand particles is launch-bound: each call from Python into Taichi
costs 15–30 µs on the CPU (its arguments, its result, the pool's wake-up), and a step of
the default demo made nine of them, a tenth of its time. Here the phases after the
adaptivity pass are the passes' own device functions (``ti.func``), composed in the
step's order into one kernel:

    neighbour grids → [coupling: before density] → density → [coupling: after density]
      → pair forces → [coupling: after forces] → accelerations and time step, kick,
      drift, collide, advect virtual → stirrers to where their paths are at t + dt

The particle count stays on the device (the sort leaves it in the pool); dt comes back
as the launch's one result. The arithmetic is the separate launches' own, in the same
order; compiled apart, LLVM may contract a multiply-add in one and not the other, so a
fused and a profiled run agree to round-off (``tests/test_multires.py``,
``test_profiled_steps_take_the_same_physics_as_fused_ones``), and on the demo bit for bit.

Used for solvers whose hooks do no host work between the phases (``one_launch``:
WCSPH); DFSPH's solves decide on the host when to stop, and a profiled step
(``Simulation(profile=True)``, ``bench``) launches each phase alone to time it.
"""

import taichi as ti


@ti.data_oriented
class FusedStep:
    def __init__(self, grids, pool, coupling, density, forces, integrator, disturbances, paths, stirrers: int):
        self.grids, self.pool, self.coupling = grids, pool, coupling
        self.density, self.forces, self.integrator = density, forces, integrator
        self.disturbances, self.paths, self.stirrers = disturbances, paths, stirrers
        if len(integrator.launches) != 1:
            raise ValueError(
                "FusedStep: the integrator's end of the step is not one launch "
                "(an implicit solver solves in it); use the phase-by-phase step"
            )

    def run(self, max_dt: float | None, stirred: int, t: float) -> float:
        """One step from time t; returns dt, or -1 when the step did not go (nothing moved;
        ``Integrator.refuse`` says why)."""
        return self._step(*self.integrator.step_args(max_dt, stirred), t, self.stirrers)

    @ti.kernel
    def _step(
        self,
        c_sound: float,
        stirred: ti.i32,
        cfl: ti.f64,
        force_factor: ti.f64,
        cap: ti.f64,
        dt_min: ti.f64,
        max_dt: ti.f64,
        t: ti.f64,
        stirrers: ti.i32,
    ) -> ti.f64:
        n = self.grids.sort_func(self.pool)
        for ps in ti.static(self.coupling.before_density()):
            ps.func(n)
        self.density.run_func(n)
        for ps in ti.static(self.coupling.after_density()):
            ps.func(n)
        self.forces.run_func(n, c_sound, stirred)
        for ps in ti.static(self.coupling.after_forces()):
            ps.func(n)
        dt = self.integrator.end_step_func(
            n, c_sound, stirred, cfl, force_factor, cap, dt_min, max_dt, ti.static(self.integrator.launches[0])
        )
        # no stirrer moves when the step did not go (its count is then 0: a loop's bound,
        # not an ``if`` around it, which would run the loop on one thread)
        self.disturbances.follow_func(self.paths, 1, stirrers * self.integrator.step_go[None], t + dt)
        return dt

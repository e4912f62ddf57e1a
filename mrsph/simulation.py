"""The simulation: ``Simulation`` builds the parts of the method in the order they
depend on each other, each handed what it uses, and lists the passes of one time step
in the method's order (``_passes``, METHOD.md §1–6), which ``step()`` runs
(``sph/step.py``: pass by pass, or as one launch where the solver allows it). The order
is written once, there; docs/ARCHITECTURE.md's step table names each pass and is
checked against it (``tests/test_passes.py``).

Where each part lives (docs/ARCHITECTURE.md draws it): ``sph/`` the SPH core (levels,
grids, the neighbour visitor, density, forces, integration, walls, the step's runner);
``pressure/`` the solvers; ``multires/`` the adaptivity pass and the level coupling;
``scene/`` the scene's parameters, seeding, emitters, criteria and stirrers.
"""

import time as _time
import warnings

import numpy as np
import taichi as ti

from . import pressure as pressure_solvers
from . import runtime
from . import state as saved_state
from .io.snapshot import Snapshot
from .multires import Multires, SplitFade, make_coupling
from .report import StatsReport
from .scene.criteria import Criteria
from .scene.emitters import Emitters
from .scene.interaction import MOUSE_SLOT, Disturbance, Disturbances, Paths, StirrerPaths, path_sample
from .scene.seeding import Seeder, settle
from .sph.boundary import Boundary
from .sph.core import Core
from .sph.density import Density
from .sph.forces import Forces, Viscosity
from .sph.grid import CELLS_PER_SUPPORT, LevelGrids, PoolSort
from .sph.integrator import Integrator, SimulationError
from .sph.levels import Levels
from .sph.neighbours import Neighbours
from .sph.particles import DEAD, VIRTUAL_CHILD, ParticlePool
from .sph.step import Pass, Stepper, StepState

__all__ = ["Simulation", "SimulationError"]


def _as_scene(scene):
    from .scene.config import Scene, load_scene

    if isinstance(scene, Scene):
        return scene
    return load_scene(scene)


class Simulation:
    """One fluid scene on one Taichi arch. See the README for a usage example."""

    def __init__(self, scene, arch: str = "cpu", profile: bool = False, threads: int | None = None):
        self.scene = _as_scene(scene)
        prm = self.scene.params
        self.arch_name = runtime.ensure(arch, prm.particles.precision, threads)
        self._program = runtime.generation()  # the Taichi program that holds this one's fields
        self.threads = threads  # None: all cores (see runtime.auto_threads)
        self.dim = prm.dim
        self.adaptive = prm.adaptivity.enabled
        self.levels = prm.adaptivity.levels if self.adaptive else 1
        self.profile = profile
        self._build(prm)
        self.timers = dict.fromkeys(p.timer for p in self.stepper.passes)
        self.reset()

    @property
    def timers(self) -> dict:
        """Wall seconds per phase of the profiled steps (``profile``), by the passes' timers."""
        return self.stepper.timers

    @timers.setter
    def timers(self, value: dict) -> None:
        self.stepper.timers = {k: 0.0 for k in value}

    # ================================================================== set-up
    def _build(self, prm) -> None:
        """Every part, in dependency order, each handed what it uses."""
        d, L, ad, fl = self.dim, self.levels, prm.adaptivity, prm.fluid
        dom, part = prm.domain, prm.particles
        self.rest_density = fl.rest_density
        # the storage and geometry every pass reads (sph/core.py)
        self.pool = ParticlePool(d, part.capacity, unused=SplitFade.unused(ad, self.adaptive))
        # a few slots more than asked, so that the per-particle arrays do not alias
        # (particles.storage_slots); every per-particle field has this length
        self.capacity = self.pool.capacity
        symmetric = self.adaptive and ad.coupling == "symmetric"
        self.lev = Levels(d, L, part.spacing, part.support, fl.rest_density, symmetric)
        self.s0, self.h0, self.m0 = self.lev.s0, self.lev.h0, self.lev.m0
        self.grids = LevelGrids(
            d, L, dom.min, dom.max, self.h0, self.capacity, CELLS_PER_SUPPORT[d], runtime.on_gpu(), part.skin
        )
        # the pool in cell order, each step the lists are built (every step without a skin)
        self.sorting = PoolSort(self.grids, self.pool)
        self.boundary = Boundary(d, dom, prm.obstacles)
        self.neighbours = Neighbours(d, self.pool, self.grids, self.boundary)
        core = Core(d, L, self.adaptive, self.pool, self.lev, self.grids, self.neighbours, self.boundary)
        # what moves the fluid from outside: the mouse and the stirrers, on their paths
        self.disturbances = Disturbances(d)
        # band and background_level as config resolved them (given or automatic); a
        # uniform run (adaptivity off) has one level whatever the scene's background
        specs = prm.criteria if self.adaptive else ()
        # every waypoint path on the device: the stirrers', then the moving regions'
        stirring = [(st.path, st.loop) for st in prm.stirrers]
        regions = [(c.path, c.loop) for c in specs if c.type == "region" and c.path]
        self.paths = Paths(d, stirring + regions)
        self.criteria = Criteria(d, specs, ad.band, float(min(ad.background_level, L - 1)), self.paths, len(stirring))
        # the levels: topology, the split fade, the coupling's hooks
        self.fade = SplitFade(core, ad)
        self.multires = Multires(core, ad, self.criteria, self.disturbances, self.fade) if self.adaptive else None
        self.coupling = make_coupling(core, ad, self.fade, self.multires.offsets if self.adaptive else None)
        # the step: its scalars, the solver, the integrator, the forces, the density
        self.state = StepState()
        self.pressure = self._solver(core, prm)
        self.viscosity = Viscosity(self.pressure.force_viscosity(fl))
        self.integrator = Integrator(
            core, prm.physics, self.state, self.coupling, self.disturbances, self.pressure, self.fade,
            self.viscosity.value,
        )  # fmt: skip
        # a uniform run's force pass takes the accelerations (nothing else adds to a force)
        accelerate = None if self.adaptive or not self.pressure.uses_forces else self.integrator
        self.forces = Forces(
            core, fl, self.coupling, self.pressure, self.state, self.viscosity, self.integrator.gravity, accelerate
        )
        self.density = Density(core, self.coupling, self.fade, self.pressure, self.forces)
        self.stirring = StirrerPaths(self.disturbances, self.paths, len(prm.stirrers), self.state)
        # particles in
        self.seeder = Seeder(core, fl, self.integrator.gravity, self.pressure.stiffness)
        self.emitters = Emitters(core, prm.emitters, self.seeder)
        self.stepper = Stepper(
            self._passes(),
            self.state,
            fuse=True,
            profile=lambda: self.profile,
            count=self.sorting.count_func,
            count_host=self.pool.count,
        )

    def _solver(self, core, prm):
        """The pressure solver ``fluid.solver`` names (``mrsph.pressure``; each takes the
        same arguments, ``pressure.base.PressureSolver``)."""
        cls = pressure_solvers.solver_class(prm.fluid.solver)
        return cls(core, prm, self.coupling, self.fade, self.state, self._warn)

    def _passes(self) -> list:
        """One time step, in the method's order (METHOD.md §1; docs/ARCHITECTURE.md's
        step table is checked against this list)."""
        coupling, density, forces = self.coupling, self.density, self.forces
        integrator, pressure = self.integrator, self.pressure
        adapt_every = self.scene.params.adaptivity.interval
        measure = [
            Pass("grid", "grid", self.sorting.run, self.sorting.run_func, counts=True),
            *coupling.before_density(density),
            Pass("density", "density", density.run, density.run_func, loops=1),
            *coupling.after_density(forces),
            *pressure.after_density(),
            *(
                [
                    Pass("forces", "forces", forces.run, forces.run_func, loops=1),
                    *coupling.after_forces(forces, self.viscosity),
                ]
                if pressure.uses_forces
                else []
            ),
        ]
        move = [
            integrator.timestep_pass(),
            *integrator.motion(pressure.after_kick(), pressure.after_drift()),
            *([integrator.advect_pass()] if self.adaptive else []),
        ]
        stirrers = (
            [Pass("stirrers", "integrate", self.stirring.run, self.stirring.run_func)] if self.stirring.count else []
        )
        return [
            Pass("emit", "emit", self._emit, when=lambda: bool(self.emitters.specs)),
            Pass("adapt", "adapt", self._adapt, when=lambda: self.adaptive and self.steps % adapt_every == 0),
            # a position-based solver predicts first and projects what it predicted; the
            # pressure it ends with is the next step's warm start
            *(move + measure if pressure.predicts else measure + move),
            *stirrers,
            Pass("nozzles", "emit", self._nozzles, when=self.emitters.any_on),
        ]

    # ================================================================== state
    def reset(self) -> None:
        """Back to t = 0: seed the fluid blocks, refine where the criteria ask."""
        self._alive()
        prm = self.scene.params
        self.pool.clear()
        self.pressure.forget_step()
        self.pool.refused[None] = 0
        self.coupling.reset()
        self.emitters.reset()
        self.dt = self.pressure.bound().dt_max  # the first step's "last dt"
        self.state.set_dt(self.dt)
        self.integrator.set_chosen_dt(self.dt)
        self._start_clocks()
        hydro = prm.fluid.hydrostatic_start  # an adaptive start is compressed after its splits
        self.seeder.seed_blocks(prm.fluid.blocks, hydro, self.pressure.incompressible, not self.adaptive)
        self._stirrers(0.0)
        if self.adaptive:
            for _ in range(self.levels):
                self.multires.adapt(self.time)
            self.multires.take_counters()
            if prm.fluid.hydrostatic_start:
                self.seeder.hydrostatic_pool(prm.fluid.blocks)
        self.grids.sort(self.pool)
        if self.pool.refused[None] > 0:
            raise SimulationError(
                f"{self.scene.path}: particles.capacity = {prm.particles.capacity} is too "
                f"small for the initial fluid ({self.pool.refused[None]} claims refused); "
                "raise it or set 0 for automatic"
            )
        if prm.fluid.settle > 0.0:
            settle(self, prm.fluid.settle, prm.fluid.settle_damping)
            if self.adaptive:
                self.multires.take_counters()
            self._start_clocks()

    def _start_clocks(self) -> None:
        """t = 0 and the run's counters at zero: a reset's, and again after the settle."""
        self.pressure.reset_counters()
        self.time = 0.0
        self.frame = 0
        self.steps = 0
        self.report = StatsReport(self, self._warn)
        self.grids.take_rebuilds()
        self.warnings: list[str] = []

    # ================================================================== the step
    def step(self, max_dt: float | None = None) -> float:
        """Advance by one time step (METHOD.md §1), the passes of ``_passes`` in order;
        returns the dt taken. ``max_dt``: cut the step to end there (the end of a frame)."""
        self._alive()
        stirred = int(self.disturbances.any_active())
        dt = self.stepper.run(self.integrator.step_args(max_dt, stirred, self.time))
        if dt < 0.0:
            self.pressure.forget_step()  # a refused fused step may have sorted the pool anew
            self.integrator.refuse(self._where())
        self.time += dt
        self.steps += 1
        self.dt = dt
        return dt

    def neighbour_passes(self, stats: dict) -> float:
        """Loops over every particle's neighbours a step makes: the passes' own, and an
        iterative solver's (from ``stats``, a stats row: its iterations a step)."""
        return sum(p.loops * p.repeat for p in self.stepper.passes) + self.pressure.solve_loops(stats)

    def _alive(self) -> None:
        """Raise if Taichi was started again since this Simulation was built (another
        arch, precision or thread count, or a reset), which freed its fields: using them
        would fail deep in Taichi, or crash."""
        if runtime.generation() != self._program:
            raise SimulationError(
                f"{self.scene.path}: this Simulation's Taichi fields were freed when Taichi was "
                "initialised again (a Simulation with another arch, precision or thread count, or "
                "mrsph.runtime.reset()); build it again"
            )

    def _where(self) -> str:
        """The step and time, for a refused step's message (built only then)."""
        return f"step {self.steps} (t = {self.time:.6g} s)"

    def run_phases(self, *names: str) -> int:
        """Run the first passes of a step on the current state without integrating, for
        tests and tools that look inside a step: ``"grid"`` (sort the pool into the
        neighbour grids), ``"density"`` (density and neighbour lists, with the coupling's
        and the solver's passes around it), ``"forces"`` (pair forces, left in each
        particle's ``a``), up to the last one named. Returns the particle count n of the
        sorted pool."""
        self._alive()
        known = ("grid", "density", "forces")
        bad = [x for x in names if x not in known]
        if bad:
            raise ValueError(f"run_phases: unknown phase(s) {bad} (expected some of {known})")
        last = max(names, key=known.index)
        # the measuring block: from the sort to the coupling's passes after the forces (or
        # to the solver's, where it has no force pass); "density" stops before the forces,
        # and before a position-based solver's projection, which moves the particles
        inner = [p.name for p in self.stepper.passes]
        start = inner.index("grid")
        move = {p.name for p in self.integrator.motion(self.pressure.after_kick(), self.pressure.after_drift())}
        move |= {"timestep", "virtual_advect", "stirrers", "nozzles"}
        block = []
        for name in inner[start:]:
            if name in move:
                break
            block.append(name)
        stop = {p.name for p in self.pressure.after_density()} if self.pressure.predicts else set()
        stop |= {"forces"}
        density = next((k for k, name in enumerate(block) if name in stop), len(block))
        upto = {"grid": "grid", "density": block[density - 1], "forces": block[-1]}[last]
        args = self.integrator.step_args(None, int(self.disturbances.any_active()), self.time)
        n = self.stepper.run_span("grid", upto, args)
        self.pressure.forget_step()  # sorted anew: the last step's slots are gone
        ti.sync()
        return n

    def advance(self, seconds: float, wall_budget: float | None = None) -> int:
        """Advance by ``seconds`` of simulated time, ending exactly on it; returns steps.

        ``wall_budget`` (seconds of wall time): stop early, after the first step that ends
        past it (so at least one step, even with 0), so that an interactive window stays
        responsive on a machine too slow for its frames; the fluid then runs in slow
        motion. ``None``: no limit."""
        end = self.time + seconds
        deadline = None if wall_budget is None else _time.perf_counter() + wall_budget
        steps = 0
        while self.time < end - 1e-12:
            self.step(max_dt=end - self.time)
            steps += 1
            if deadline is not None and _time.perf_counter() >= deadline:
                break
        if self.time >= end - 1e-12:
            self.time = end
        self.report.collect()
        return steps

    def advance_frame(self, wall_budget: float | None = None, seconds: float | None = None) -> int:
        """Advance by one frame (1/fps simulated seconds, or ``seconds``: a window in real
        time passes the wall time its last frame took), or less within ``wall_budget``
        (see :meth:`advance`; ``None``, the whole frame, is what recordings need). The
        frame counter counts calls: a frame cut short by the budget counts as one."""
        steps = self.advance(1.0 / self.scene.params.run.fps if seconds is None else seconds, wall_budget)
        self.frame += 1
        return steps

    # ------------------------------------------------------------------ the host's passes
    def _emit(self):
        if self.emitters.emit(self.time, self.dt):
            self.report.warn_refused()

    def _adapt(self):
        self.multires.adapt(self.time)
        self.report.adapted()

    def _nozzles(self):
        self.emitters.hold(len(self.emitters.on))

    def _warn(self, msg: str) -> None:
        """A warning the app shows (``warnings``) and Python's warnings machinery reports."""
        self.warnings.append(msg)
        warnings.warn(msg, RuntimeWarning, stacklevel=4)

    def _stirrers(self, t):
        """The stirrers at time t: their slots are set once (radius, strength, mode; the
        host's copy keeps where each was then), then follow their paths on the device
        (each step's ``stirrers`` pass)."""
        for i, st in enumerate(self.scene.params.stirrers):  # at most MAX_STIRRERS
            if self.disturbances.get(1 + i) is None:
                pos, vel = path_sample(st.path, t, st.loop)
                self.disturbances.set(1 + i, Disturbance(tuple(pos), st.radius, st.strength, st.mode, tuple(vel)))
        if self.scene.params.stirrers:
            self.disturbances.follow(self.paths, 1, len(self.scene.params.stirrers), t)

    # ================================================================== reading out
    def particles(self, virtual: bool = True) -> dict:
        """Alive particles as numpy arrays: x, v, m, rho, p, level, kind, parent, drho, ..."""
        self._alive()
        n = self.pool.count()
        p = ti.static(self.pool.p)
        out = {
            k: getattr(p, k).to_numpy()[:n]
            for k in ("x", "v", "m", "rho", "p", "level", "kind", "parent", "nchild", "lam", "drho")
        }
        out["p"] = self.pressure.reported_pressure(out["p"])
        out["rho"] = self.pressure.reported_density(out["rho"], out["kind"])
        keep = out["kind"] != DEAD
        if not virtual:
            keep &= out["kind"] < VIRTUAL_CHILD
        if not keep.all():
            out = {k: v[keep] for k, v in out.items()}
        return out

    def stats(self, parts: dict | None = None) -> dict:
        """The stats row (the columns of stats.csv; ``report.py``). ``splits``, ``merges``
        and ``refused`` count since the last call."""
        return self.report.row(parts if parts is not None else self.particles())

    def snapshot(self, stats: bool = True) -> Snapshot:
        parts = self.particles()
        s = self.scene.params
        return Snapshot(
            dim=self.dim,
            levels=self.levels,
            time=self.time,
            frame=self.frame,
            x=parts["x"],
            v=parts["v"],  # the simulation's precision: dumps keep f64
            m=parts["m"],
            rho=parts["rho"],
            level=parts["level"],
            kind=parts["kind"],
            radius=np.array([0.5 * self.s0 * 2**l for l in range(self.levels)]),
            domain_min=np.asarray(s.domain.min, float),
            domain_max=np.asarray(s.domain.max, float),
            obstacles=[dict(o) for o in self.scene.data["obstacles"]],
            stats=self.stats(parts) if stats else {},
            p=parts["p"],
        )

    def save_state(self) -> dict:
        """The simulation's state in memory (numpy copies): every particle attribute, the
        links, the clocks and the emitters' progress. :meth:`restore_state` puts it back
        into a Simulation of the same scene, here or in another Taichi program; the scene's
        parameters, live-tuned ones included, and the mouse's disturbance are not part of
        it. ``bench`` uses it to time an adaptive run and its uniform twin turn about
        from the same warm state (``state.py``)."""
        self._alive()
        return saved_state.save(self)

    def restore_state(self, state: dict) -> None:
        """Put back a :meth:`save_state` of a Simulation of the same scene."""
        self._alive()
        saved_state.restore(self, state)

    # ================================================================== interaction
    def set_disturbance(self, d: Disturbance | None) -> None:
        self._alive()
        self.disturbances.set(MOUSE_SLOT, d)

    def _live(self):
        """Live-tunable keys and the part that owns each."""
        # a solver without a force pass owns the viscosity, if it takes it at all
        forces = (self.viscosity,) if self.pressure.uses_forces else ()
        owners = (*forces, self.pressure, self.integrator, self.coupling)
        return {k: part for part in owners for k in part.live_keys}

    @property
    def LIVE_KEYS(self) -> tuple:
        return tuple(self._live())

    def set_param(self, key: str, value) -> None:
        """Change a parameter while running (validated like the scene file)."""
        self._alive()
        if key == "adaptivity.enabled":
            raise ValueError(
                "adaptivity.enabled: changes the particle levels; rebuild the "
                "Simulation with scene.with_overrides({...}) instead"
            )
        live = self._live()
        if key not in live:
            raise ValueError(f"{key}: not live-tunable (expected one of {', '.join(live)})")
        self.scene = self.scene.with_overrides({key: value})
        live[key].set_param(key, self.scene.get(key))
        if live[key] is self.pressure:  # the artificial viscosity follows the signal speed
            self.forces.update_signal_speed()

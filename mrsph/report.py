"""What a Simulation reports between steps (``Simulation.stats``): the stats row, the
columns of stats.csv, and the tallies it counts since the last row (the adaptivity
passes' splits and merges, refused claims, neighbour-list rebuilds), with the one warning
a full pool gives. Host side only: it reads the device's counters when a row is asked
for, not after every pass."""

import math

import numpy as np

from .multires import COUNTERS
from .sph.particles import REGULAR, VIRTUAL_CHILD


class StatsReport:
    """The stats row of one Simulation and its tallies since the last row."""

    def __init__(self, sim, warn):
        """sim: the Simulation whose parts it reads (pool, multires, grids, pressure,
        integrator); warn: how a warning reaches the user (``Simulation._warn``)."""
        self.sim, self.warn = sim, warn
        self.events = dict.fromkeys(COUNTERS, 0)
        self.refused_reported = 0  # pool.refused at the last row
        self.steps_reported = 0  # steps at the last row
        self.events_due = False  # an adaptivity pass ran since its counters were read
        self.refusal_warned = False

    def restored(self, refused: int, steps: int) -> None:
        """A saved state was put back: the next row counts from its totals."""
        self.refused_reported, self.steps_reported = refused, steps

    def adapted(self) -> None:
        """An adaptivity pass ran: its counters are read at the next ``collect``."""
        self.events_due = True

    def collect(self) -> None:
        """Add the adaptivity passes' events since the last call to the row's counts and
        warn (once) if a claim was refused. Called by ``advance`` and ``row``, not after
        every pass: a read of the counters costs ~50 µs, a twentieth of a step at a few
        thousand particles."""
        if not self.events_due:
            return
        self.events_due = False
        for k, v in self.sim.multires.take_counters().items():
            self.events[k] += v
        if self.sim.pool.refused[None] > 0:  # any claim of the passes (or emitters) refused
            self.warn_refused()

    def warn_refused(self) -> None:
        if not self.refusal_warned:
            self.refusal_warned = True
            self.warn(
                f"particle pool full (particles.capacity = {self.sim.capacity}): splits/emission "
                f"refused and counted in stats (refused); the simulation goes on coarser"
            )

    def row(self, parts: dict) -> dict:
        """The stats row of the particles ``parts`` (``Simulation.particles``). ``splits``,
        ``merges`` and ``refused`` count since the last row; ``refused`` counts claims the
        pool could not hold: a split refused, or a particle an emitter could not place."""
        sim = self.sim
        real = parts["kind"] < VIRTUAL_CHILD
        m = parts["m"][real].astype(np.float64)
        v = parts["v"][real].astype(np.float64)
        mom = (m[:, None] * v).sum(axis=0) if len(m) else np.zeros(sim.dim)
        # before the first step there is no step to report: dt 0, not dt_max
        row = {
            "frame": sim.frame,
            "time": sim.time,
            "dt": sim.integrator.chosen_dt() if sim.steps else 0.0,
            "n_real": int(real.sum()),
            "n_virtual": int((~real).sum()),
            "total_mass": math.fsum(m.tolist()),
        }
        for k, ax in enumerate("xyz"[: sim.dim]):
            row[f"momentum_{ax}"] = float(mom[k])
        row["kinetic_energy"] = float(0.5 * (m * (v * v).sum(axis=1)).sum())
        # the density the pressure reads: less the split fade's offset drho (a sampling error)
        rho = parts["rho"][real] - np.maximum(parts["drho"][real], 0.0) if "drho" in parts else parts["rho"][real]
        row["max_density_ratio"] = float(rho.max() / sim.rest_density) if len(rho) else 0.0
        lv = parts["level"]
        for l in range(sim.levels):
            row[f"n_level_{l}"] = int(((lv == l) & real).sum())
        for l in range(sim.levels):
            row[f"n_virtual_level_{l}"] = int(((lv == l) & ~real).sum())
        row["n_transient"] = int((real & (parts["kind"] > REGULAR)).sum())
        row.update(self._solve(rho))
        # steps that built the neighbour lists (all of them without a skin)
        rebuilds = sim.grids.take_rebuilds()
        row["rebuilds"] = sim.steps - self.steps_reported if rebuilds is None else rebuilds
        self.steps_reported = sim.steps
        self.collect()
        row["splits"] = self.events["splits"]
        row["merges"] = self.events["merges"]
        row["absorbed"] = self.events["absorbed"]  # of the merges: groups given to a neighbour
        refused = int(sim.pool.refused[None])  # a running total in the pool
        row["refused"] = refused - self.refused_reported
        self.refused_reported = refused
        for k in self.events:
            self.events[k] = 0
        return row

    def _solve(self, rho) -> dict:
        """The pressure solver's columns: mean iterations a step of each solve since the
        last row, the average density error (DFSPH: the density solve's last, of the
        predicted density; WCSPH: the real particles' mean compression), solves stopped
        at their maximum, steps halved so that a solve converged (dfsph), particles a
        velocity clamp slowed (pbf)."""
        pressure, rho0 = self.sim.pressure, self.sim.rest_density
        solve = pressure.take_stats()
        if solve["density_error"] is None:
            solve["density_error"] = float(np.maximum(rho - rho0, 0.0).mean() / rho0) if len(rho) else 0.0
        out = {"solver": pressure.name}
        for k in ("density_iterations", "divergence_iterations", "density_error", "unconverged", "clamped"):
            out[k] = solve[k]
        out["shortened"] = solve.get("shortened", 0)
        return out

"""What pbf's steps (``solver.py``) did, for the stats row: their iterations, their average
density errors, the steps that stopped short of ``pbf.tolerance`` or ``pbf.max_density_error``
(counted and warned about once a run, never silent) and the particles the velocity clamp
slowed. The steps add to it on the device, so that a fused step reads nothing back."""

import numpy as np
import taichi as ti

# stats[] (f64): Σ over steps of the average error, the largest step average, the
# largest particle error, steps, steps above the tolerance, clamped particles, iterations
ERR_SUM, ERR_WORST, ERR_PEAK, STEPS, UNCONVERGED, CLAMPED, ITERS = range(7)


@ti.data_oriented
class StepCounts:
    def __init__(self, warn):
        self.warn = warn
        self.stats = ti.field(ti.f64, shape=7)
        self._warned = False

    def reset(self) -> None:
        self.stats.fill(0.0)
        self._warned = False

    @ti.func
    def step(self, avg, peak, iterations, short):
        """One step: its average error, its largest, its iterations, and whether it stopped
        short of a bound."""
        self.stats[ERR_SUM] += avg
        self.stats[ERR_WORST] = ti.max(self.stats[ERR_WORST], avg)
        self.stats[ERR_PEAK] = ti.max(self.stats[ERR_PEAK], ti.cast(peak, ti.f64))
        self.stats[STEPS] += 1.0
        self.stats[ITERS] += ti.cast(iterations, ti.f64)
        if short:
            self.stats[UNCONVERGED] += 1.0

    @ti.func
    def clamped(self):
        ti.atomic_add(self.stats[CLAMPED], 1.0)

    def take(self, iterations: int, tolerance: float, max_error: float) -> dict:
        """The steps since the last call: the mean of their average density errors (at
        the last iteration's multipliers, before its corrections), the steps above
        ``pbf.tolerance`` or with a particle above ``pbf.max_density_error`` (warned about
        once; ``max_error`` inf: no such bound) and the particles the clamp slowed."""
        err_sum, worst, peak, steps, unconverged, clamped, iters = self.stats.to_numpy().tolist()
        self.stats.fill(0.0)
        if unconverged and not self._warned:
            self._warned = True
            largest = ""
            if np.isfinite(max_error):
                largest = f" or a particle's above pbf.max_density_error = {max_error:g} (worst {peak:.3g})"
            self.warn(
                f"pbf: {int(unconverged)} of {int(steps)} steps stopped at pbf.iterations = {iterations} "
                f"with an average density error above pbf.tolerance = {tolerance:g} (worst {worst:.3g})"
                + largest
                + ": raise pbf.iterations or pbf.substeps (counted in stats as unconverged; warned once a run)"
            )
        return {
            "density_iterations": iters / steps if steps else 0.0,
            "divergence_iterations": 0.0,
            "density_error": err_sum / steps if steps else 0.0,
            "unconverged": int(unconverged),
            "clamped": int(clamped),
        }

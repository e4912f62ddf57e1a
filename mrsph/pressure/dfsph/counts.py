"""What the DFSPH solves (``solver.py``) did, for the stats row: each solve's iterations a
step, the last density error, and the solves that stopped at their maximum iterations
beyond the scene's tolerance, counted and warned about once a run, never silent."""

DENSITY, DIVERGENCE = 0, 1  # the two solves
SOLVE_NAMES = ("density", "divergence")
MAX_KEYS = ("max_iterations", "divergence_max_iterations")


class SolveCounts:
    """What the solves did since the last ``take``, for the stats row: the iterations of
    each solve per step, the last density error, and the solves that stopped at their
    maximum iterations, the first of which is warned about (once a run), in a line that
    says when, which criterion the solve was short of, and which keys to change."""

    def __init__(self, tolerance, max_iterations, warn, max_error=None):
        """tolerance, max_iterations: (density, divergence); max_error: the density solve's
        largest error allowed (``dfsph.max_density_error``, a share of rho0)."""
        self.tolerance, self.max_iterations, self.warn = tolerance, max_iterations, warn
        self.max_error = max_error
        self.reset()

    def reset(self) -> None:
        self._clear()
        self.last_error = 0.0
        self._warned = False

    def _clear(self) -> None:
        self.iterations = [0, 0]  # DENSITY, DIVERGENCE
        self.steps = 0
        self.unconverged = 0
        self.shortened = 0  # halvings of a step whose density solve stopped at its maximum

    def add(self, which: int, iterations: int, error: float, hit_max: bool, peak=None, t=None, shortened=0) -> None:
        """One solve's outcome: its iterations, its final average error (kept for the
        density solve, the row's ``density_error``), whether it stopped at its maximum, for
        the warning its largest error (a share of rho0) and the time of its step, and the
        times its step was halved first (``dfsph.shorten_steps``)."""
        self.iterations[which] += iterations
        self.shortened += shortened
        if which == DENSITY:
            self.steps += 1
            self.last_error = error
        if hit_max:
            self.unconverged += 1
            if not self._warned:
                self._warned = True
                self.warn(self.message(which, error, peak, t, shortened))

    def message(self, which: int, error: float, peak=None, t=None, shortened=0) -> str:
        """The warning of a solve that stopped at its maximum: when, how far from which of
        its criteria, and what to change."""
        name, key = SOLVE_NAMES[which], f"dfsph.{MAX_KEYS[which]}"
        when = f" at t = {t:.4g} s" if t is not None else ""
        tol_key = "dfsph.density_tolerance" if which == DENSITY else "dfsph.divergence_tolerance"
        short = []
        if error > self.tolerance[which]:
            tol = 100.0 * self.tolerance[which]
            short.append(f"average error {100.0 * error:.3g} % against {tol_key} = {tol:.3g} %")
        if which == DENSITY and peak is not None and self.max_error is not None and peak > self.max_error:
            short.append(
                f"largest error {100.0 * peak:.3g} % against dfsph.max_density_error = {100.0 * self.max_error:.3g} %"
            )
        why = "; ".join(short) or f"short of its tolerance {self.tolerance[which]:g}"
        halved = f", its step halved {shortened} time(s) first (dfsph.shorten_steps)" if shortened else ""
        return (
            f"dfsph: the {name} solve stopped at {key} = {self.max_iterations[which]}{when} ({why}{halved}): "
            f"raise {key}, or loosen the tolerance named; counted in the stats row (unconverged), warned once a run"
        )

    def take(self) -> dict:
        steps = max(self.steps, 1)
        out = {
            "density_iterations": self.iterations[DENSITY] / steps,
            "divergence_iterations": self.iterations[DIVERGENCE] / steps,
            "density_error": self.last_error,
            "unconverged": self.unconverged,
            "shortened": self.shortened,
            "clamped": 0,
        }
        self._clear()
        return out

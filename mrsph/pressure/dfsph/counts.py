"""What the DFSPH solves (``dfsph.py``) did, for the stats row: each solve's iterations a
step, the last density error, and the solves that stopped at their maximum iterations
beyond the scene's tolerance, counted and warned about once a run, never silent."""

DENSITY, DIVERGENCE = 0, 1  # the two solves
SOLVE_NAMES = ("density", "divergence")
MAX_KEYS = ("max_iterations", "divergence_max_iterations")


class SolveCounts:
    """What the solves did since the last ``take``, for the stats row: the iterations of
    each solve per step, the last density error, and the solves that stopped at their
    maximum iterations, the first of which is warned about (once a run)."""

    def __init__(self, tolerance, max_iterations, warn):
        self.tolerance, self.max_iterations, self.warn = tolerance, max_iterations, warn
        self.reset()

    def reset(self) -> None:
        self._clear()
        self.last_error = 0.0
        self._warned = False

    def _clear(self) -> None:
        self.iterations = [0, 0]  # DENSITY, DIVERGENCE
        self.steps = 0
        self.unconverged = 0

    def add(self, which: int, iterations: int, error: float, hit_max: bool) -> None:
        """One solve's outcome: its iterations, its final average error (kept for the
        density solve, the row's ``density_error``), whether it stopped at its maximum."""
        self.iterations[which] += iterations
        if which == DENSITY:
            self.steps += 1
            self.last_error = error
        if hit_max:
            self.unconverged += 1
            if not self._warned:
                self._warned = True
                self.warn(
                    f"dfsph: the {SOLVE_NAMES[which]} solve stopped at dfsph.{MAX_KEYS[which]} = "
                    f"{self.max_iterations[which]} before reaching its tolerance "
                    f"{self.tolerance[which]:g} (counted in stats as unconverged; warned once)"
                )

    def take(self) -> dict:
        steps = max(self.steps, 1)
        out = {
            "density_iterations": self.iterations[DENSITY] / steps,
            "divergence_iterations": self.iterations[DIVERGENCE] / steps,
            "density_error": self.last_error,
            "unconverged": self.unconverged,
            "clamped": 0,
        }
        self._clear()
        return out

"""Helpers shared by the physics test modules: scene boxes and known failures."""
import pytest


def box(dim, lo2, hi2, z=(0.0, 0.1)):
    """Corners of a box from its (x, y) corners; in 3D z spans ``z``."""
    if dim == 2:
        return [float(v) for v in lo2], [float(v) for v in hi2]
    return [float(v) for v in lo2] + [float(z[0])], [float(v) for v in hi2] + [float(z[1])]


def known_xfail(request, known: dict, dim: int, key: str, measured: float) -> None:
    """Mark the running test xfail (not strict) if ``known`` lists (key, dim) as a known
    library failure: it runs and prints its numbers, with this run's in the reason, and
    its failure does not fail the suite."""
    reason = known.get((key, dim))
    if reason:
        request.applymarker(pytest.mark.xfail(strict=False, reason=f"{reason} (this run: {measured:.4g})"))

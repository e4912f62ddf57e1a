"""The start of a run (docs/METHOD.md §18): the hydrostatic placement of a pool seeded with
levels, and the settle before t = 0."""

import numpy as np
import pytest

from mrsph.scene.config import load_scene
from mrsph.simulation import Simulation
from mrsph.sph.particles import REGULAR

pytestmark = pytest.mark.usefixtures("taichi_f32")


def _start(dim: int, adaptive: bool) -> dict:
    """The deep tank at twice its spacing under wcsph (the solver whose start is compressed),
    as it stands at t = 0."""
    sets = ['fluid.solver="wcsph"', "particles.spacing=0.01", f"adaptivity.enabled={str(adaptive).lower()}"]
    sim = Simulation(load_scene(f"tank_rest_{dim}d", sets), arch="cpu", threads=1)
    return sim.particles(virtual=False)


@pytest.mark.slow_params("3d")
def test_an_adaptive_start_puts_its_fine_particles_where_a_uniform_start_does(dim):
    """The fine half of the adaptive tank is split from the coarse lattice at t = 0; compressed
    after the split, every fine particle sits on a point of the uniform start's compressed
    lattice. Compressed before it, each pair of sibling rows kept its parent's spacing:
    the rows then pushed alternately up and down at about 0.4 g."""
    uniform, adaptive = _start(dim, False), _start(dim, True)
    fine = (adaptive["level"] == 0) & (adaptive["kind"] == REGULAR)
    assert fine.sum() > 100, fine.sum()
    x, ref = adaptive["x"][fine].astype(np.float64), uniform["x"].astype(np.float64)
    # the nearest uniform point of each fine particle (a few thousand each: all pairs fit)
    gap = np.sqrt(((x[:, None, :] - ref[None, :, :]) ** 2).sum(-1).min(axis=1))
    # float32 positions near 0.4 m are 3e-8 m apart; the compression within a pair of rows
    # that the split missed is ~1e-5 m here
    assert gap.max() < 1e-6, f"a fine particle {gap.max():.2e} m off the uniform start's lattice"


def test_the_settle_damps_the_fluid_before_the_clock_starts():
    """fluid.settle on a pool across its tank thrown sideways at 0.5 m/s: 0.1 s at the
    default damping (100/s, e^-10) takes its speed to under 1 % of that, and the run then
    starts at t = 0 with its counters at zero; without the settle the pool moves at t = 0."""
    base = {
        "description": "a pool thrown sideways",
        "dim": 2,
        "domain": {"min": [0.0, 0.0], "max": [1.0, 0.5]},
        "particles": {"spacing": 0.02},
        "fluid": {"solver": "wcsph", "blocks": [{"min": [0.0, 0.0], "max": [1.0, 0.2], "velocity": [0.5, 0.0]}]},
    }
    thrown = Simulation(load_scene(base), arch="cpu", threads=1)
    assert np.abs(thrown.particles()["v"][:, 0]).mean() == pytest.approx(0.5)
    base["fluid"]["settle"] = 0.1
    sim = Simulation(load_scene(base), arch="cpu", threads=1)
    assert (sim.time, sim.frame, sim.steps) == (0.0, 0, 0)
    p = sim.particles()
    assert np.linalg.norm(p["v"], axis=1).mean() < 0.005, np.linalg.norm(p["v"], axis=1).mean()
    # the settle ran: the pool was carried towards the wall before it stopped
    assert p["x"][:, 0].mean() > thrown.particles()["x"][:, 0].mean() + 1e-4
    sim.step()
    assert sim.steps == 1 and sim.time > 0.0

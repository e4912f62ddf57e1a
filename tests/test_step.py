"""The step taken two ways, fused and profiled, moves the particles alike.

``bench`` times each phase with a profiled step (one launch a phase, ``Simulation(profile=True)``);
a plain step is as few fused launches as its list allows (``mrsph/sph/step.py``). A test holds them to the same physics,
so that what ``bench`` times is what the window runs.
"""

import numpy as np
import pytest
from scenekit import for_solver, moving_region_scene, raw_pool

from mrsph.scene.config import load_scene

pytestmark = pytest.mark.usefixtures("fresh_program")


@pytest.mark.slow_params("2d-adaptive", "3d-adaptive", "3d-uniform", "3d-adaptive-pbf")
@pytest.mark.parametrize(
    ("adaptive", "solver"),
    [(True, "wcsph"), (False, "wcsph"), (True, "pbf")],
    ids=["adaptive", "uniform", "adaptive-pbf"],
)
def test_profiled_steps_take_the_same_physics_as_fused_ones(dim, adaptive, solver):
    """``bench`` times each phase by calling the fused end of the step (accelerations, dt,
    integration, boundaries, virtual advection) one phase a call. Both ways must move the
    particles alike. Adaptive: a slab falling onto the floor through a moving refinement
    box, splits and merges going on. Uniform: the same slab thrown at the floor at 6 m/s,
    one particle of it put under the floor, which the walls must project back (the
    ghost forces keep the others off the walls; faster, the adaptive run's split
    decisions tip on round-off and the two runs part). The two ways are compiled apart, and LLVM
    may contract a multiply-add in one and not the other (measured: one velocity a few
    ulp apart after 6 steps), so they agree to round-off, not to the bit. One thread: on
    more, an adaptive run's reactions are atomic float adds in the threads' order, and
    two plain runs of it already part at round-off (see the restored-state test below)."""
    from mrsph.simulation import Simulation

    scene = for_solver(moving_region_scene(dim), solver)
    scene["physics"]["gravity"] = [0.0, -9.81] + [0.0] * (dim - 2)
    scene["adaptivity"]["enabled"] = adaptive
    block = scene["fluid"]["blocks"][0]
    scene["domain"]["min"][1] = block["min"][1]  # the floor under the slab
    speed = 1.5 if adaptive else 6.0
    block["velocity"] = [0.0, -speed] + [0.0] * (dim - 2)
    runs = []
    for profile in (False, True):
        sim = Simulation(load_scene(scene), arch="cpu", profile=profile, threads=1)
        if not adaptive:  # the slab's lowest particle under the floor: the walls project it
            low = int(np.argmin(sim.pool.p.x.to_numpy()[: sim.pool.count(), 1]))
            x = sim.pool.p.x[low]
            x[1] = block["min"][1] - 0.002
            sim.pool.p.x[low] = x
        for _ in range(60):
            sim.step()
        runs.append((sim.time, sim.steps, raw_pool(sim)))
    (t0, n0, fused), (t1, n1, split) = runs
    assert n0 == n1 and t1 == pytest.approx(t0, rel=1e-6), (
        f"{dim}D: fused steps reached t = {t0!r} in {n0}, profiled ones t = {t1!r} in {n1}"
    )
    for key in ("n", "level", "kind", "nchild"):
        assert np.array_equal(fused[key], split[key]), f"{dim}D: profiled and fused steps differ in {key}"
    dx = float(np.abs(fused["x"] - split["x"]).max())
    dv = float(np.abs(fused["v"] - split["v"]).max())
    assert dx < 1e-6 and dv < 1e-4, (
        f"{dim}D: after 60 steps profiled and fused positions differ by up to {dx:.3g} m, "
        f"velocities by {dv:.3g} m/s (slab at {speed} m/s)"
    )

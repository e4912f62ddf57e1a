"""A saved state (``Simulation.save_state`` / ``restore_state``) restored into another
Simulation of the scene steps exactly as the original; ``bench`` times a pair's two runs
turn about from such states, and the overflowed-list test starts from one.
"""

import numpy as np
import pytest
from scenekit import moving_region_scene, raw_pool

from mrsph.scene.config import load_scene

pytestmark = pytest.mark.usefixtures("fresh_program")


@pytest.mark.slow_params("3d")
def test_a_restored_state_steps_exactly_as_the_original(dim):
    """``save_state``/``restore_state`` (what ``bench`` uses to time a pair's two runs
    turn about): a second Simulation of the scene, given the first one's state in the
    middle of a run with splits and merges going on, takes the same next steps to the bit.
    The adaptivity pass runs every few steps (its phase is the step count) and the box
    moves with the time, so the clocks must come back too, not only the particles.
    One thread: with more, the reactions handed on to the owners are atomic float adds
    in whatever order the threads reach them, and two runs part at round-off level (two
    plain runs of this scene on two threads: the first velocity differs after 42 steps)."""
    from mrsph.simulation import Simulation

    scene = moving_region_scene(dim)
    first = Simulation(load_scene(scene), arch="cpu", threads=1)
    for _ in range(25):  # an odd count: the pass's phase matters
        first.step()
    state = first.save_state()
    first.stats()  # counts events since the last call: start from zero here
    for _ in range(30):
        first.step()
    events = first.stats()
    assert events["splits"] + events["merges"] > 0, (
        f"{dim}D: no split or merge in the 30 steps compared ({events['splits']}, {events['merges']})"
    )
    second = Simulation(load_scene(scene), arch="cpu", threads=1)
    second.restore_state(state)
    for _ in range(30):
        second.step()
    a, b = raw_pool(first), raw_pool(second)
    assert (second.time, second.steps) == (first.time, first.steps), (
        f"{dim}D: restored run at t = {second.time!r} after {second.steps} steps, original at "
        f"t = {first.time!r} after {first.steps}"
    )
    for key in a:
        assert np.array_equal(a[key], b[key]), f"{dim}D: the restored run's {key} differs after 30 steps"
    # a state of another dimension or pool size is refused before anything is written
    for wrong in (dict(state, dim=5 - dim), dict(state, capacity=state["capacity"] + 16)):
        with pytest.raises(ValueError, match="does not fit"):
            second.restore_state(wrong)
    assert np.array_equal(raw_pool(second)["x"], b["x"]), f"{dim}D: a refused state changed the pool"

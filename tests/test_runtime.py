"""Taichi start-up (mrsph/runtime.py): the automatic thread count and the core pinning
that goes with one thread."""

import os

import pytest

from mrsph import runtime
from mrsph.config import load_scene


def test_auto_threads_by_starting_particles():
    demo = load_scene("demo_2d")             # adaptive, starts at its coarsest level
    assert runtime.starting_particles(demo) == demo.estimate_particles() // 16
    assert runtime.auto_threads(demo) == 1
    big = load_scene("dam_break_2d", ["particles.spacing=0.0016"])   # ~48k particles
    assert runtime.starting_particles(big) > runtime.AUTO_ONE_THREAD_BELOW[2]
    assert runtime.auto_threads(big) is None
    assert runtime.auto_threads(big, 3) == 3 and runtime.auto_threads(demo, None) is None


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="needs a CPU affinity of two cores or more")
def test_one_thread_is_pinned_and_released():
    before = os.sched_getaffinity(0)
    runtime.reset()
    try:
        runtime.ensure("cpu", "f32", threads=1)
        pinned = os.sched_getaffinity(0)
        assert len(pinned) == 1 and pinned <= before, f"affinity with one thread: {pinned}"
        runtime.ensure("cpu", "f32")              # all cores again: the pin is undone
        assert os.sched_getaffinity(0) == before
    finally:
        runtime.reset()
    assert os.sched_getaffinity(0) == before

"""The window's simulations in processes of their own (mrsph.app.host), on the stand-in.

A worker is forked from the zygote, builds the stand-in, compiles it with a step and a
reset, and then answers frames, resets and parameters; a simulation put back is kept
and comes back with a reset; a failed build says why; a worker that dies is noticed.
The real solver's switch is timed by tools/switch_times.py and seen in the window tests.
"""

from __future__ import annotations

import os
import signal
import time

import pytest
from fake_app import FakeSimulation

from mrsph.app import host


def make_sim(name, overrides=None):
    if name == "broken":
        raise ValueError("broken: no such scene (expected fake)")
    sim = FakeSimulation(dim=3 if name == "fake_3d" else 2)
    if overrides and "steps" in overrides:
        sim.steps_per_frame = int(overrides["steps"])
    return sim


def ready(handle, timeout=60.0):
    end = time.time() + timeout
    while handle.poll() == "busy":
        assert time.time() < end, f"still {handle.stage} after {timeout} s"
        time.sleep(0.01)
    return handle.state


@pytest.fixture
def sims():
    ok, why = host.separate_processes_possible()
    if not ok:
        pytest.skip(why)
    pool = host.Sims(make_sim, True)
    assert pool.separate, pool.why_local
    yield pool
    pool.close()


def test_a_worker_builds_advances_and_resets(sims):
    handle = sims.open("fake_2d")
    assert isinstance(handle, host.RemoteSim) and handle.pid != os.getpid()
    try:
        _build_advance_reset(handle)
    finally:
        handle.close()


def _build_advance_reset(handle):
    assert ready(handle) == "ready", handle.error
    assert handle.dim == 2 and handle.levels == 3 and handle.time == 0.0, "not reset after the compiling step"
    first = handle.snapshot()
    handle.advance_frame(None)
    assert handle.time == pytest.approx(1 / 30) and handle.snapshot().frame == first.frame + 1
    handle.set_param("fluid.viscosity", 0.5)
    with pytest.raises(KeyError, match="unknown parameter"):
        handle.set_param("no.such.key", 1.0)  # the worker's error, raised here
    handle.reset()
    assert handle.time == 0.0 and handle.snapshot().frame == 0


def test_a_simulation_put_back_comes_back_at_once_and_overrides_make_another(sims):
    a = sims.open("fake_2d")
    assert ready(a) == "ready"
    a.advance_frame(None)
    sims.put_back(a)
    b = sims.open("fake_2d", {"steps": 2})
    assert ready(b) == "ready" and b is not a, "other overrides, another simulation"
    sims.put_back(b)
    again = sims.open("fake_2d")
    assert again is a and again.stage == "reset", "the kept one was not taken"
    t0 = time.perf_counter()
    assert ready(again) == "ready" and again.time == 0.0
    assert time.perf_counter() - t0 < 2.0
    sims.put_back(again)


def test_only_the_last_few_are_kept(sims):
    handles = []
    for steps in range(host.KEEP + 2):
        h = sims.open("fake_2d", {"steps": steps + 1})
        assert ready(h) == "ready"
        handles.append(h)
        sims.put_back(h)
    assert len(sims.kept) == host.KEEP
    assert handles[0].state == "dead" and handles[-1].state == "ready"


def test_a_failed_build_says_why_and_a_dead_worker_is_noticed(sims):
    bad = sims.open("broken")
    assert ready(bad) == "failed" and "no such scene" in str(bad.error)
    bad.close()
    good = sims.open("fake_2d")
    assert ready(good) == "ready"
    os.kill(good.pid, signal.SIGKILL)
    with pytest.raises(RuntimeError, match="process stopped"):
        for _ in range(50):
            good.advance_frame(None)
            time.sleep(0.01)
    assert not good.alive()
    good.close()


def test_in_process_when_asked(monkeypatch):
    monkeypatch.setenv(host.IN_PROCESS_ENV, "1")
    pool = host.Sims(make_sim, True)
    try:
        assert not pool.separate and host.IN_PROCESS_ENV in pool.why_local
        handle = pool.open("fake_2d")
        assert isinstance(handle, host.LocalSim) and ready(handle) == "ready"
        handle.advance_frame(None)
        assert handle.time > 0 and handle.dim == 2
    finally:
        pool.close()


def test_a_scene_crosses_to_the_window_whole():
    """A Scene goes to the window as what makes it again (it does not pickle as it is):
    what the window reads of it, and its overrides, are the same there."""
    import pickle

    from mrsph.scene.config import load_scene

    scene = load_scene("demo_2d", ['fluid.solver="wcsph"'])
    there = host._scene_in(pickle.loads(pickle.dumps(host._scene_out(scene))))
    assert type(there) is type(scene) and there.name == scene.name and there.path == scene.path
    assert there.data == scene.data and there.get("fluid.solver") == "wcsph"
    assert there.with_overrides({"fluid.solver": "dfsph"}).get("fluid.solver") == "dfsph"
    assert host._scene_in(host._scene_out({"name": "fake_2d"})) == {"name": "fake_2d"}


def test_a_simulation_built_ahead_opens_ready_and_one_no_longer_wanted_is_kept(sims):
    """Built ahead (mrsph.app.ahead), one at a time in the order wanted: opening one takes
    it ready, without a build or a reset; one no longer wanted, once ready, is kept."""
    sims.ahead.want([("fake_2d", {"steps": 2}), ("fake_3d", {})])
    end = time.time() + 60
    while sims.ahead.ready() < 2:
        sims.ahead.tick()
        assert sum(h.state == "busy" for h in sims.ahead.handles.values()) <= 1, "more than one built at once"
        assert time.time() < end, {k: h.state for k, h in sims.ahead.handles.items()}
        time.sleep(0.01)
    from mrsph.app.ahead import NICE

    ours = os.getpriority(os.PRIO_PROCESS, 0)
    pid = sims.ahead.handles[host.key_of("fake_2d", {"steps": 2})].pid
    assert os.getpriority(os.PRIO_PROCESS, pid) == min(ours + NICE, 19), "not built at a lower priority"
    handle = sims.open("fake_2d", {"steps": 2})
    assert handle.state == "ready" and handle.poll() == "ready", handle.state
    assert handle.time == 0.0 and handle.snapshot().frame == 0, "built ahead, not at its start"
    if os.geteuid() == 0:  # only a privileged process may raise a priority again
        assert os.getpriority(os.PRIO_PROCESS, pid) == ours, "its priority was not restored"
    _build_advance_reset(handle)
    sims.ahead.want([])
    assert not sims.ahead.handles, "one no longer wanted is still built ahead"
    assert host.key_of("fake_3d", {}) in sims.kept, "a ready one no longer wanted was dropped"


def test_a_failed_build_ahead_is_not_tried_again(sims):
    sims.ahead.want([("broken", {})])
    end = time.time() + 60
    while host.key_of("broken", {}) not in sims.ahead.failed:
        sims.ahead.tick()
        assert time.time() < end
        time.sleep(0.01)
    sims.ahead.tick()
    assert not sims.ahead.handles and sims.ahead.ready() == 0


def test_the_count_built_ahead_is_checked():
    from mrsph.app import ahead

    assert ahead.count({}) == ahead.DEFAULT_COUNT and ahead.count({"MRSPH_AHEAD": "0"}) == 0
    for bad in ("x", "-1", "4"):
        with pytest.raises(ValueError, match="MRSPH_AHEAD"):
            ahead.count({"MRSPH_AHEAD": bad})

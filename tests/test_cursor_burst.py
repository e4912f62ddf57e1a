"""A still cursor entering water at rest refines it without throwing it about, and
leaving it lets it merge back without throwing it either (``adaptivity.split_fade``, set
in demo_2d; METHOD.md §14), measured by tools/cursor_burst.py on the default demo as the
window shows it: the pool at rest after its opening stir, the mouse's refinement
splitting level 2 down to 0 under the cursor in one adaptivity pass. The numbers these
bounds sit between are in docs/validation.md, "A cursor in resting water".
"""

import pytest
from toolload import load_tool

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures("fresh_program")]

#: demo_2d's own solver (scenes/demo_2d.toml), then the others
SOLVERS = {"pbf": [], "dfsph": ['fluid.solver="dfsph"'], "wcsph": ['fluid.solver="wcsph"']}


@pytest.mark.parametrize("solver", SOLVERS)
def test_a_still_cursor_in_resting_water_throws_nothing(solver):
    tool = load_tool("cursor_burst")
    rows = tool.burst("demo_2d", SOLVERS[solver], tool.AT, tool.RADIUS, 2.5, (2.5, 20.0), threads=1, leave=True)
    (_, rest, _), (_, soon, _), (_, later, _), (_, gone, _), _ = rows
    # Without the fade 1,638 particles were above 1 m/s 2.5 ms after the cursor came, the
    # fastest at 11 m/s; with it a handful. The count is the measure; the fastest
    # particle, one particle, is held to half of what it was.
    fast = int((soon > 1.0).sum())
    assert soon.max() <= 5.5 and fast <= 150, (
        f"demo_2d ({solver}) at rest, a still cursor at {tool.AT}: 2.5 ms after it came the fastest particle "
        f"moves at {soon.max():.2f} m/s and {fast} of {len(soon)} above 1 m/s (expected <= 5.5 m/s and "
        f"<= 150; at rest before it {rest.max():.2f} m/s)"
    )
    assert later.max() <= 2.0, (
        f"demo_2d ({solver}), a still cursor: 20 ms after it came the fastest particle moves "
        f"at {later.max():.2f} m/s (expected <= 2)"
    )
    # and when it goes, the refined fluid merges back: with the splits' fade alone 336
    # particles were above 1 m/s 2.5 ms later, 23 with the merges' offsets too, and none
    # or one with the neighbours of a change of level re-measured
    thrown = int((gone > 1.0).sum())
    assert thrown <= 100, (
        f"demo_2d ({solver}): 2.5 ms after the cursor left, {thrown} of {len(gone)} particles move "
        f"faster than 1 m/s, the fastest at {gone.max():.2f} m/s (expected <= 100)"
    )


@pytest.mark.parametrize("solver", SOLVERS)
def test_letting_go_of_a_held_cursor_splashes_nothing(solver):
    """The window's mouse (strength 20 1/s) held still in resting water for 0.1 s, then
    let go: the fluid it refined merges back. Each merge (and absorption, gathering,
    new coupling) changes what the particles around it read, and those re-measure their
    split-fade offset (``SplitFade.remeasure_touched``). The kinetic energy
    (J per metre of depth) over the 20 ms after, at four places and times: 44-52 J at
    its peak with no offset handed on, 19-44 J with the merged particle's own offset
    handed on, 3.7-5.8 J with its neighbours re-measured too, 0.2-0.3 J at rest before
    (docs/validation.md, "A cursor in resting water"). The bound sits between."""
    tool = load_tool("cursor_burst")
    rows = tool.burst(
        "demo_2d",
        SOLVERS[solver],
        tool.AT,
        tool.RADIUS,
        2.5,
        (2.5, 6.0, 10.0, 20.0, 100.0),
        threads=1,
        leave=True,
        strength=20.0,
    )
    held = rows[5][2]
    after = [(-ms, ke, sp.max()) for ms, sp, ke in rows if ms < 0]
    peak = max(after, key=lambda r: r[1])
    assert peak[1] <= 12.0, (
        f"demo_2d ({solver}): {peak[0]:g} ms after a cursor held 0.1 s at strength 20 was let go, "
        f"the kinetic energy is {peak[1]:.2f} J (held: {held:.2f} J; expected <= 12), "
        f"the fastest particle at {peak[2]:.2f} m/s"
    )


#: (where the cursor starts, its velocity): along the floor, and the two diagonals of
#: tools/cursor_burst.py's twelve paths that threw the pool furthest under dfsph before the
#: split kept its centre of mass and the limiter read densities as the pressure does
DRAGS = {
    "floor": ((0.3, 0.12), (2.0, 0.0)),
    "up-right": ((0.2, 0.1), (1.5, 1.0)),
    "mid-up-right": ((0.7, 0.2), (2.0, 1.0)),
}


@pytest.mark.parametrize("drag", DRAGS)
@pytest.mark.parametrize("solver", SOLVERS)
def test_a_cursor_dragged_through_resting_water_throws_nothing(solver, drag):
    """The mouse's refinement alone (no push) dragged through demo_2d's resting pool at
    1.8-2.2 m/s, jumping every 10 ms as the window moves it once a frame: the pool should
    stay near rest. The kinetic energy's peak over 0.4 s, one thread, 2026-11-28
    (docs/validation.md, "A cursor in resting water"):

    ============  ======================  =====
    drag          dfsph (before → after)  wcsph
    ============  ======================  =====
    floor         45.1 → 11.0 J           13.1 J
    up-right      5979 → 12.1 J           11.4 J
    mid-up-right  35.2 → 13.2 J           5.1 J
    ============  ======================  =====

    Under dfsph the density solve removes within one step a compression that the
    adaptivity pass makes and the split fade does not see, and throws the pool: a split
    whose children the placement moved as a group (its virtual parent followed them and
    compressed the coarse level: ``test_multires.py::test_a_split_moves_no_mass``), and
    the virtual-mass limiter reading a coarse particle's raw density while its offset
    was being re-measured (``SplitFade.seen``)."""
    tool = load_tool("cursor_burst")
    at, velocity = DRAGS[drag]
    rows = tool.drag("demo_2d", SOLVERS[solver], at, tool.RADIUS, 2.5, velocity, 400.0, 10, threads=1)
    ms, sp, ke = max(rows[1:], key=lambda r: r[2])
    assert ke <= 25.0, (
        f"demo_2d ({solver}): the refinement of a cursor dragged from {at} at {velocity} m/s "
        f"through the resting pool threw it to {ke:.2f} J at {ms:g} ms, {int((sp > 1.0).sum())} "
        f"particles above 1 m/s, the fastest at {sp.max():.2f} m/s (at rest before "
        f"{rows[0][2]:.2f} J; expected <= 25)"
    )

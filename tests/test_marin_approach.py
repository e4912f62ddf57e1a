"""tools/marin_approach.py: MARIN's dam break before the box, as a 2D section along the tank's
centre line (docs/validation.md, MARIN's H1). The section must be the box scene's tank and
reservoir, and its gate must open from the floor as the run goes (its answer to a bad key is
tested with the other tools', in test_tank_rest.py)."""

import pytest
from toolload import load_tool

A = load_tool("marin_approach")
V = load_tool("validate")


def test_the_section_is_the_box_scene_s_tank_and_reservoir_without_the_box():
    from mrsph.scene.config import load_scene

    box = load_scene(V.SCENES["box"]).data
    scene = A.section(0.02, "dfsph", ["fluid.viscosity=0.5"], None)
    data = scene.data
    assert scene.dim == 2 and data["particles"]["spacing"] == 0.02 and data["fluid"]["solver"] == "dfsph"
    assert data["fluid"]["viscosity"] == 0.5 and data["fluid"]["stiffness"] == box["fluid"]["stiffness"]
    assert list(data["domain"]["max"]) == list(box["domain"]["max"][:2])
    block = data["fluid"]["blocks"][0]
    assert list(block["min"]) == list(box["fluid"]["blocks"][0]["min"][:2])
    assert list(block["max"]) == list(box["fluid"]["blocks"][0]["max"][:2])
    assert not data.get("obstacles")
    gate = A.section(0.02, "wcsph", [], 2.0).data["obstacles"][0]
    assert gate["max"][0] == block["min"][0] and gate["min"][0] == pytest.approx(block["min"][0] - 0.08)
    assert gate["min"][1] == 0.0 and gate["max"][1] == box["domain"]["max"][1]


def test_the_gate_lifts_off_the_floor():
    """``lift`` moves the plate's lower edge and opens its foot, so that a particle under it is
    not held against the floor (sph/boundary.py: a foot on the floor is shut); the faces on
    other walls stay shut."""

    class Fields:
        def __init__(self, shut):
            self.box_c, self.box_half, self.box_shut_lo = {}, {}, {0: shut}

    plate = A.section(0.02, "wcsph", [], 2.0).data["obstacles"][0]
    f = Fields([0, 1])
    A.lift(f, plate, 0, 0.0)
    assert f.box_c[0][1] == pytest.approx(0.5) and f.box_half[0][1] == pytest.approx(0.5) and f.box_shut_lo[0] == [0, 1]
    A.lift(f, plate, 0, 0.3)
    assert f.box_c[0] == pytest.approx([1.952, 0.65]) and f.box_half[0] == pytest.approx([0.04, 0.35])
    assert f.box_shut_lo[0] == [0, 0]
    f = Fields([0, 1, 1])  # 3D: a plate across the tank, its sides on the side walls
    A.lift(f, {"min": [1.9, 0.0, 0.0], "max": [2.0, 1.0, 1.0]}, 0, 0.25)
    assert f.box_c[0] == pytest.approx([1.95, 0.625, 0.5]) and f.box_half[0] == pytest.approx([0.05, 0.375, 0.5])
    assert f.box_shut_lo[0] == [0, 0, 1]


@pytest.mark.slow
@pytest.mark.xdist_group("validation-approach-2d")
def test_a_lifting_gate_thins_the_stream_and_holds_it_back():
    """At 14 layers: the stream released at once stands at H3 about as deep as the 3D runs'
    (0.130-0.141 m at 14 to 40 layers; docs/validation.md), and a gate lifted at 2 m/s makes it
    thinner and its body later. A gate that never moved would hold the water back for good; one
    never there would change nothing. The clock fit then moves the gated run earlier."""
    free = A.approach(0.55 / 14, "wcsph", [], None)
    gated = A.approach(0.55 / 14, "wcsph", [], 2.0)
    assert 0.125 < free["depth"] < 0.145, free
    assert gated["depth"] < free["depth"] - 0.005, (free, gated)
    assert gated["first"][2] is not None and gated["first"][2] > free["first"][2] + 0.01, (free, gated)
    assert gated["fit"]["shift"] < free["fit"]["shift"] - 0.01, (free["fit"], gated["fit"])


def test_the_clock_fit_finds_a_known_shift():
    """The data's own H3 and H4 played 0.03 s late read a shift of -0.03 s (moved earlier) and
    fit to nothing; as played, their RMS is the lateness's."""
    import numpy as np

    exp = V.read_csv(V.DATA / "kleefsman_2005_heights.csv")
    t = np.arange(0.0, A.UNTIL, 0.002)
    h3, h4 = (np.interp(t - 0.03, exp["t"], exp[name]) for name in ("H3", "H4"))
    fit = A.clock_fit(t, h3, h4)
    assert fit["shift"] == pytest.approx(-0.03, abs=1e-9), fit
    assert fit["shifted"]["H3"] < 0.002 and fit["shifted"]["H4"] < 0.002, fit
    assert fit["as_run"]["H3"] > 0.005, fit

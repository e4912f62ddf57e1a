"""tools/box_gate.py: MARIN's box with its reservoir released by a lifted gate (docs/validation.md,
MARIN's H1). The gated scene must be the validation's box with one plate more, against the
reservoir's face and across the tank, and the plate must lift off the floor in 3D while its
sides stay shut against the side walls (its answer to a bad key is tested with the other
tools', in test_tank_rest.py)."""

import pytest
from toolload import load_tool

G = load_tool("box_gate")
A = load_tool("marin_approach")


def test_the_gated_box_is_the_validation_s_box_with_a_plate_against_the_reservoir():
    free = G.scene_with_gate("wcsph", True, [], None).data
    gated = G.scene_with_gate("dfsph", True, ["fluid.viscosity=0.5"], 2.0).data
    s = 0.55 / G.LAYERS_QUICK
    assert gated["particles"]["spacing"] == pytest.approx(s) and gated["fluid"]["solver"] == "dfsph"
    assert gated["fluid"]["viscosity"] == 0.5 and not gated["adaptivity"]["enabled"]
    assert len(free["obstacles"]) == 1 and gated["obstacles"][:1] == free["obstacles"]
    plate, face = gated["obstacles"][1], free["fluid"]["blocks"][0]["min"][0]
    assert plate["max"][0] == face and plate["min"][0] == pytest.approx(face - 4 * s)
    assert list(plate["min"][1:]) == [0.0, 0.0] and list(plate["max"][1:]) == list(free["domain"]["max"][1:])


def test_the_plate_lifts_off_the_floor_in_taichi_s_fields(taichi_f32):
    """``lift`` on the Boundary's own fields (3D): its foot opens, its sides stay shut."""
    import taichi as ti

    class Fields:
        box_c = ti.Vector.field(3, float, shape=2)
        box_half = ti.Vector.field(3, float, shape=2)
        box_shut_lo = ti.Vector.field(3, int, shape=2)

    f = Fields()
    f.box_shut_lo[1] = [0, 1, 1]
    A.lift(f, {"min": [1.9, 0.0, 0.0], "max": [2.0, 1.0, 1.0]}, 1, 0.25)
    assert f.box_c.to_numpy()[1] == pytest.approx([1.95, 0.625, 0.5])
    assert f.box_half.to_numpy()[1] == pytest.approx([0.05, 0.375, 0.5])
    assert f.box_shut_lo.to_numpy().tolist() == [[0, 0, 0], [0, 0, 1]]

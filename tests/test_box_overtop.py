"""tools/box_overtop.py: which way the water reaches MARIN's probe behind the box. Its mark must
follow each particle through the step's sorts, which the slow test holds on the coarse run
(its answer to a bad key is tested with the other tools', in test_tank_rest.py)."""

import pytest
from toolload import load_tool


@pytest.mark.slow
@pytest.mark.xdist_group("validation-box-3d")
def test_the_first_water_in_the_box_s_shadow_came_over_the_box():
    """At 14 layers water is above the box from 0.7 s and comes down behind it into the
    shadow before the bore from the far wall gets there (docs/validation.md, MARIN's H1).
    A mark lost in a sort would leave a share of the shadow's water unmarked; a mark put on
    every particle would mark the water that never went over the box, which stays outside
    the shadow's first litres."""
    rows = load_tool("box_overtop").overtop("wcsph", True, [], 0.7, 1.06)
    assert rows[0]["above"] > 1.0, rows[0]
    wet = [r for r in rows if r["shadow"] > 0.3]
    assert wet, rows[-1]
    first = wet[0]
    assert first["shadow_over"] > 0.95 * first["shadow"], first
    assert first["near_h1"] == 0.0, first  # H1 is still dry: the water is only behind the box
    assert first["marked"] < 100.0, first  # of the column's 675 L

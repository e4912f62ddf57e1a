"""The step's order is written once: ``Simulation._passes``. docs/ARCHITECTURE.md's step
table names every pass a scene can have, in order; each scene's list must be a
subsequence of it, and the scenes below, between them, hold every pass of the table."""

import re
from pathlib import Path

import pytest

from mrsph.scene.config import load_scene

DOC = Path(__file__).resolve().parent.parent / "docs" / "ARCHITECTURE.md"

# Small set-ups that between them take every pass: (scene, overrides)
SETUPS = [
    ("dam_break_2d", ["particles.spacing=0.04"]),  # uniform wcsph: integrate
    ("demo_2d", ["particles.spacing=0.02", "adaptivity.levels=2", 'fluid.solver="dfsph"']),  # dfsph, limiter, stirrers
    ("region_2d", ["particles.spacing=0.02", "adaptivity.coupling=symmetric"]),  # symmetric
    ("pour_2d", ["particles.spacing=0.02"]),  # emitters
    ("demo_2d", ["particles.spacing=0.02", "adaptivity.levels=2"]),  # pbf (the demo's own)
]


def table_passes() -> list[str]:
    text = DOC.read_text(encoding="utf-8")
    section = text.split("## One step", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"^\| `(\w+)` \|", section, flags=re.MULTILINE)


def predicted(order) -> list[str]:
    """The table's order for a solver that predicts first: its time step through the
    virtual advection, then the grid through the coupling's passes after the forces."""
    a, b, c = order.index("grid"), order.index("timestep"), order.index("virtual_advect") + 1
    return order[:a] + order[b:c] + order[a:b] + order[c:]


def is_subsequence(names, order) -> bool:
    it = iter(order)
    return all(any(n == o for o in it) for n in names)


@pytest.fixture(scope="module")
def lists():
    from mrsph import runtime
    from mrsph.simulation import Simulation

    runtime.reset()
    out = {}
    for scene, overrides in SETUPS:
        sim = Simulation(load_scene(scene, overrides), threads=1)
        out[(scene, tuple(overrides))] = [p.name for p in sim.stepper.passes]
    return out


def test_the_table_lists_passes():
    names = table_passes()
    assert len(names) >= 20 and len(set(names)) == len(names), names


def test_every_scenes_passes_follow_the_table(lists):
    order = table_passes()
    for setup, names in lists.items():
        unknown = [n for n in names if n not in order]
        assert not unknown, f"{setup}: passes {unknown} are not in docs/ARCHITECTURE.md's step table"
        assert is_subsequence(names, order) or is_subsequence(names, predicted(order)), (
            f"{setup}: the passes {names} are not in the table's order {order}"
        )


def test_the_scenes_take_every_pass_of_the_table(lists):
    seen = {n for names in lists.values() for n in names}
    missing = [n for n in table_passes() if n not in seen]
    assert not missing, f"no set-up of tests/test_passes.py takes {missing}: the table lists a pass no scene has"

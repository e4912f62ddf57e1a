"""The test run's own scheduling (tests/conftest.py): the tests that read one expensive
module fixture run in one process, so that the fixture is built once."""

from conftest import GROUPED, group_name
from xdist.scheduler.loadgroup import LoadGroupScheduling


def test_a_fixture_case_is_one_xdist_group():
    """xdist groups a test by the name after its node id's ``@`` only where no ``]``
    follows it: two tests of one fixture case, and of one module, land in one group."""
    split = LoadGroupScheduling._split_scope
    for stem, by in GROUPED.items():
        stem = stem.removesuffix(".py")
        case = "3d-pbf" if by == "case" else None
        group = group_name(stem, case)
        ids = [f"tests/{stem}.py::test_{n}[3d-pbf]@{group}" for n in ("a", "b")]
        assert split(None, ids[0]) == split(None, ids[1]) == group, (ids, split(None, ids[0]))

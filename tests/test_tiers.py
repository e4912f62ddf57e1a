"""The test run's own scheduling (tests/conftest.py): the tests that read one expensive
module fixture run in one process, so that the fixture is built once; the kernels compile
without Taichi's advanced optimisation, but a window's that the test times."""

import os
from types import SimpleNamespace

import pytest
from conftest import GROUPED, UNOPTIMISED_HERE, as_users_run, group_name
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


def test_the_tests_compile_unoptimised_and_a_timed_window_as_users_run(monkeypatch):
    """Unless the caller chose (then the variable is theirs), a test's kernels compile without
    the advanced passes; a ``wallclock`` test's app gets the optimised kernels back."""
    if not os.environ.get(UNOPTIMISED_HERE):
        pytest.skip("TI_ADVANCED_OPTIMIZATION was set by the caller")
    assert os.environ["TI_ADVANCED_OPTIMIZATION"] == "0"
    marks = {"wallclock": object(), "slow": None}
    for mark, optimised in (("wallclock", True), ("slow", False)):
        node = SimpleNamespace(get_closest_marker=lambda name, m=mark: marks[name] if name == m else None)
        with monkeypatch.context() as m:
            as_users_run(node, m)
            assert ("TI_ADVANCED_OPTIMIZATION" not in os.environ) is optimised, mark
    assert os.environ["TI_ADVANCED_OPTIMIZATION"] == "0"

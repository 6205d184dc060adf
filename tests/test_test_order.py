"""The test run's own order: the modules conftest.py moves to the front exist (a renamed chain
module would otherwise drop out of the list silently and run last again), do come first, and
reach the workers in that order (pytest-xdist's loadfile scheduler sorts modules by their number
of tests unless told not to)."""
import re

from tests.conftest import LONGEST_FIRST, ROOT


def test_the_longest_first_modules_exist():
    missing = [name for name in LONGEST_FIRST if not (ROOT / name).is_file()]
    assert not missing, f"tests/conftest.py LONGEST_FIRST names modules that are not there: {missing}"


def test_they_are_collected_first(request):
    seen = []
    for item in request.session.items:
        rel = item.nodeid.split("::")[0]
        if rel not in seen:
            seen.append(rel)
    collected = [m for m in LONGEST_FIRST if m in seen]   # a run may select only some modules
    assert seen[:len(collected)] == collected


def test_make_test_keeps_the_order_under_xdist():
    makefile = (ROOT / "Makefile").read_text()
    xdist = re.search(r"^XDIST = (.*)$", makefile, re.M)
    assert xdist and "--dist loadfile" in xdist.group(1) and "--no-loadscope-reorder" in xdist.group(1)

"""The test run's own order: the modules conftest.py moves to the front exist (a renamed chain
module would otherwise drop out of the list silently and run last again) and do come first."""
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

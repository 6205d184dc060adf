"""Outside plugins that break: a package whose method module calls ``sys.exit(0)`` at
import, a second that registers a built-in method's key again and a broken classifier module; in a
fresh interpreter with the package on PYTHONPATH, ``viewfuse --help`` prints its usage, the
registries hold the built-ins, and only the stages that use a broken kind refuse, naming the kind,
the entry point and the cause. Names that become paths and colours are checked at registration."""
from __future__ import annotations

import json

import numpy as np
import pytest

from loaders.real_imagery.read_check import check_photos
from pipeline.infra.extension import ExtensionError
from tests.support.outside_package import ROOT, run_with, write_package

EXITS = "import sys\nsys.exit(0)\n"
TWICE = '''
import viewfuse as vf
from pipeline.method.methods.simple_bayes import SimpleBayes

@vf.register
class Again(SimpleBayes):
    key = "with_uncertainty"
'''
PROBE = '''
import json
from types import SimpleNamespace
from pipeline.method.registry import keys
from stages.framework.outside import check_loaded
out = {"keys": list(keys())}
cfg = SimpleNamespace(classifier=SimpleNamespace(arch="alexnet"), data=SimpleNamespace(source="synthetic"))
for stage, methods in (("data", False), ("classifier", False), ("evaluate", True)):
    try:
        check_loaded(cfg, stage, methods)
        out[stage] = "runs"
    except ValueError as e:
        out[stage] = str(e)
print("PROBE " + json.dumps(out))
'''


@pytest.fixture(scope="module")
def broken_site(tmp_path_factory):
    where = tmp_path_factory.mktemp("broken_plugins")
    write_package(where, "vf_exits", EXITS, {"viewfuse.methods": {"exits": "vf_exits"}})
    write_package(where, "vf_twice", TWICE, {"viewfuse.methods": {"twice": "vf_twice"}})
    write_package(where, "vf_badnet", "raise RuntimeError('no GPU here')\n",
                  {"viewfuse.classifiers": {"badnet": "vf_badnet"}})
    return where


@pytest.mark.slow
def test_help_works_and_only_the_stages_that_use_a_broken_kind_refuse(broken_site, tmp_path):
    r = run_with(broken_site, "from stages.commands.cli import main; main(['--help'])", tmp_path)
    assert r.returncode == 0 and "usage: viewfuse" in r.stdout, r.stderr[-2000:]
    r = run_with(broken_site, "from stages.commands.cli import main; main(['evaluate', '--help'])", tmp_path)
    assert r.returncode == 0 and "config keys this stage reads" in r.stdout, r.stderr[-2000:]
    r = run_with(broken_site, PROBE, tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(next(x for x in r.stdout.splitlines() if x.startswith("PROBE "))[6:])
    assert out["keys"][0] == "with_uncertainty" and "Again" not in out["keys"]
    assert out["data"] == "runs" and out["classifier"] == "runs"       # alexnet: the broken net is not used
    ev = out["evaluate"]
    assert "fusion method entry point 'exits' = 'vf_exits' of group 'viewfuse.methods' does not load: SystemExit: 0" in ev
    assert "entry point 'twice'" in ev and "registered twice" in ev
    assert "fusion method entry point 'exits'" in r.stderr       # the warning, once per entry point
    assert r.stderr.count("'exits' = 'vf_exits'") == 1


def test_the_cli_boundary_prints_a_refusal_on_one_line(broken_site, tmp_path):
    cfg = ROOT / "configs" / "smoke.toml"
    r = run_with(broken_site, "from stages.commands.cli import main; main(['status', '--config', "
                              f"{str(cfg)!r}, '--set', 'run.artifacts={tmp_path}'])", tmp_path)
    lines = [x for x in r.stdout.splitlines() if x.startswith("evaluate")]
    assert lines and "unknown: " in lines[0] and "'exits'" in lines[0], r.stdout + r.stderr[-2000:]
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("name", ["a/b", "..", ".hidden", "a b", "", "x" * 200])
def test_object_names_from_a_dataset_source_are_plain_names(name):
    rgb, mask = np.zeros((4, 4, 3), np.uint8), np.ones((4, 4), bool)
    with pytest.raises(ExtensionError, match=r"dataset source 'mine' \(read\): object name .*not a plain name"):
        check_photos("mine", {"ok": {0: (rgb, mask)}, name: {0: (rgb, mask)}})


@pytest.mark.parametrize("views, words", [
    ({"90": None}, r"angle '90' is str, not a whole number of degrees"),
    ({90.0: None}, "angle 90.0 is float"),
    ({400: None}, "angle 400 is outside \\[0, 360\\)"),
    ({90: (np.zeros((4, 4, 3)), np.ones((4, 4), bool))}, "angle 90: rgb must be a uint8 array"),
    ({90: (np.zeros((4, 4, 3), np.uint8), np.ones((4, 5), bool))}, "angle 90: mask must be a bool array"),
])
def test_what_read_returns_is_checked_naming_source_hook_and_cause(views, words):
    with pytest.raises(ExtensionError, match=r"dataset source 'mine' \(read\): object 'mug': " + words):
        check_photos("mine", {"mug": views})


@pytest.mark.parametrize("attrs, words", [({"key": "a/b"}, "not a plain name"), ({"key": ".."}, "not a plain name"),
                                          ({"color": "notacolour"}, "not a colour matplotlib can draw"),
                                          ({"color": None}, "color must be a colour string")])
def test_method_keys_and_colours_are_checked_at_registration(attrs, words):
    from pipeline.method.registry import register
    from tests.support.toy_method import ToyTempered

    with pytest.raises(ExtensionError, match=words):
        register(type("Bad", (ToyTempered,), attrs))

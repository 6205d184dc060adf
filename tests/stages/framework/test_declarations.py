"""The config package's settings enter a stage's key as resolved values, not as code: rewording a
setting's doc reruns nothing, a new default reruns the stages that declare its section (and
those below them), and what the config package computes still reruns every stage that imports it."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
CONFIG = ROOT / "pipeline" / "infra" / "config"
PACKAGES = ("pipeline", "loaders", "stages", "reports")


def _edit(path: Path, old: str, new: str, count: int = 1) -> None:
    text = path.read_text()
    assert text.count(old) >= count, f"{path.name}: {old!r} not found; the test needs updating"
    path.write_text(text.replace(old, new))


def _reword_docs(folder: Path) -> int:
    """Prefix every ``doc="..."`` of the config modules in ``folder``; the number rewritten."""
    n = 0
    for f in sorted(folder.glob("*.py")):
        text, k = re.subn(r'\bdoc="', 'doc="reworded: ', f.read_text())
        f.write_text(text)
        n += k
    return n


@pytest.fixture
def config_copy(tmp_path, monkeypatch):
    """The config package copied under a source tree at ``tmp_path`` the registry reads."""
    import stages.framework.registry as registry

    dst = tmp_path / "pipeline" / "infra" / "config"
    shutil.copytree(CONFIG, dst, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(registry, "ROOT", tmp_path)
    return dst


def _fingerprints(folder: Path) -> dict[str, str]:
    from stages.framework.registry import source_fingerprint
    return {f.name: source_fingerprint(f) for f in sorted(folder.glob("*.py"))}


def test_a_settings_doc_default_or_range_leaves_the_config_fingerprints_as_they_were(config_copy):
    before = _fingerprints(config_copy)
    assert _reword_docs(config_copy) > 100
    _edit(config_copy / "plan.py", "budget: int = _f(10, lo=2, hi=200,", "budget: int = _f(12, lo=2, hi=300,")
    _edit(config_copy / "learning.py", "restarts: int = _f(5, lo=0, hi=100)", "restarts: int = _f(7, lo=0, hi=100)")
    assert _fingerprints(config_copy) == before


@pytest.mark.parametrize("module, old, new", [
    ("evaluation.py", 'return "scan" if', 'return "scans" if'),                            # cluster_of
    ("learning.py", "min(early_epochs, epochs - 1)", "min(early_epochs, epochs - 2)"),    # early_epochs_run
    ("inputs.py", '    "advil_liqui_gels",\n', '    "advil_liqui_gel",\n'),                # a module constant
    ("inputs.py", "return self.own.built(self.source)", "return self.own.built(self.source.lower())"),  # a property
    ("root.py", 'source_path: str = field(default=""', 'source_path: str = field(default="."'),  # an internal field
    ("root.py", "return Path(dict(self.path_roots).get(key, self.root)) / p",
     "return Path(self.root) / p"),                                                      # a method
    ("load.py", 'value = raw  # bare words', 'value = raw.strip()  # bare words'),       # the loader
])
def test_what_the_config_package_computes_still_changes_its_fingerprint(config_copy, module, old, new):
    before = _fingerprints(config_copy)
    _edit(config_copy / module, old, new)
    after = _fingerprints(config_copy)
    assert {m for m in before if before[m] != after[m]} == {module}


def test_settings_are_left_out_only_in_the_config_package(tmp_path, monkeypatch):
    import stages.framework.registry as registry

    monkeypatch.setattr(registry, "ROOT", tmp_path)
    (tmp_path / "pipeline" / "method").mkdir(parents=True)
    f = tmp_path / "pipeline" / "method" / "own_section.py"   # an extension's section, elsewhere
    f.write_text((CONFIG / "plan.py").read_text())
    before = registry.source_fingerprint(f)
    _reword_docs(f.parent)
    assert registry.source_fingerprint(f) != before


def test_every_settings_class_of_the_config_package_is_in_the_resolved_config():
    """The left-out declarations are safe only where their values reach ``to_dict(cfg)``: every
    dataclass of the config package with ``setting`` fields is a section of ``Config``."""
    import dataclasses
    import importlib

    from pipeline.infra.config import Config

    reached, todo = set(), [Config()]
    while todo:
        obj = todo.pop()
        reached.add(type(obj))
        todo.extend(v for f in dataclasses.fields(obj) if dataclasses.is_dataclass(v := getattr(obj, f.name)))
    declared = set()
    for f in sorted(CONFIG.glob("*.py")):
        mod = importlib.import_module(f"pipeline.infra.config.{f.stem}" if f.stem != "__init__" else "pipeline.infra.config")
        for obj in vars(mod).values():
            if (isinstance(obj, type) and dataclasses.is_dataclass(obj) and obj.__module__ == mod.__name__
                    and any("doc" in fl.metadata for fl in dataclasses.fields(obj))):
                declared.add(obj)
    assert len(declared) >= 10
    assert declared <= reached, sorted(c.__name__ for c in declared - reached)


# Reading a setting's declared default elsewhere would make a stage depend on a declaration the key
# leaves out. These read one, each for a reason:
DEFAULT_READERS = {
    "stages.framework.runner": "the hash of every default, for StageSpec.defaults",
    "reports.main.reviewer": "the report lists the keys a run sets apart from the defaults: StageSpec.defaults",
    "pipeline.method.gp_fit": "keyword defaults for tests and tools; every stage's call passes each setting",
    "pipeline.method.gp_instance_fit": "as gp_fit",
}


def test_no_stage_reads_a_settings_declared_default_outside_the_config_package():
    import dataclasses
    import importlib

    from stages.framework.registry import STAGES, _module_file, code_deps

    classes = set()
    for f in sorted(CONFIG.glob("*.py")):
        mod = importlib.import_module(f"pipeline.infra.config.{f.stem}" if f.stem != "__init__" else "pipeline.infra.config")
        classes.update(k for k, v in vars(mod).items() if isinstance(v, type) and dataclasses.is_dataclass(v)
                       and v.__module__ == mod.__name__ and any("doc" in f.metadata for f in dataclasses.fields(v)))
    assert {"Config", "EvaluateConfig", "ModelsConfig", "SimulateConfig"} <= classes
    use = re.compile(r"\b(%s)\s*(\(|\.__dataclass_fields__)" % "|".join(sorted(classes)))
    reached = {m for s in STAGES.values() for m in code_deps(s.module) if not m.startswith("pipeline.infra.config")}
    readers = {m for m in reached if use.search(_module_file(m).read_text())}
    assert readers == set(DEFAULT_READERS), sorted(readers ^ set(DEFAULT_READERS))
    assert STAGES["report"].defaults and not any(s.defaults for n, s in STAGES.items() if n != "report")


# ------------------------------------------------------------------------------------------------
# Whole stage keys, in a copy of the source tree (the edited module is what the process imports)

_KEYS = """
import json, sys
from pipeline.infra.config import load_config
from stages.framework.registry import ORDER, ROOT, STAGES
from stages.framework.runner import stage_key
cfg, keys = load_config(sys.argv[1]), {}
for n in ORDER:   # an upstream digest stands in as its key (the outputs are the same bytes)
    keys[n] = stage_key(cfg, STAGES[n], {u: keys[u] for u in STAGES[n].upstream})[0]
print(json.dumps({"root": str(ROOT), "keys": keys}))
"""


@pytest.fixture(scope="module")
def tree_copy(tmp_path_factory):
    """(a copy of the source tree, its stage keys)."""
    dst = tmp_path_factory.mktemp("tree")
    for pkg in PACKAGES:
        shutil.copytree(ROOT / pkg, dst / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    (dst / "configs").mkdir()
    # every key at its default: a new default is a new resolved value
    (dst / "configs" / "keys.toml").write_text(f'[run]\nname = "keys"\nartifacts = "{dst / "art"}"\n')
    return dst, _keys(dst)


def _keys(tree: Path) -> dict[str, str]:
    env = {**os.environ, "PYTHONPATH": str(tree), "PYTHONDONTWRITEBYTECODE": "1"}
    out = subprocess.run([sys.executable, "-c", _KEYS, str(tree / "configs" / "keys.toml")], cwd=tree, env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert Path(got["root"]) == tree   # the copy was imported, not the checkout
    return got["keys"]


def _changed(tree_keys: tuple[Path, dict], module: str, edit) -> set[str]:
    tree, before = tree_keys
    path = tree / "pipeline" / "infra" / "config" / module
    texts = {f: f.read_text() for f in path.parent.glob("*.py")}
    try:
        edit(path)
        after = _keys(tree)
    finally:
        for f, text in texts.items():
            f.write_text(text)
    assert set(before) == set(after)
    return {s for s in before if before[s] != after[s]}


def test_a_reworded_doc_in_every_config_module_leaves_every_stage_key(tree_copy):
    assert _changed(tree_copy, "plan.py", lambda p: _reword_docs(p.parent)) == set()


def test_a_new_default_reruns_the_stages_that_declare_it_and_those_below(tree_copy):
    # models.restarts: the models stage declares [models]; data declares only models.min_views
    assert _changed(tree_copy, "learning.py", lambda p: _edit(p, "restarts: int = _f(5,", "restarts: int = _f(7,")) \
        == {"models", "evaluate", "report"}
    assert _changed(tree_copy, "plan.py", lambda p: _edit(p, "budget: int = _f(10,", "budget: int = _f(12,")) \
        == {"evaluate", "report"}
    # the report also lists every key a run sets apart from the defaults (StageSpec.defaults)
    assert _changed(tree_copy, "simulate.py", lambda p: _edit(p, " realizations: int = _f(300,", " realizations: int = _f(301,")) \
        == {"simulate", "report"}


def test_an_edit_to_what_the_config_package_computes_reruns_every_stage(tree_copy):
    # cluster_of: every stage imports the config package, so every stage's code holds it
    assert _changed(tree_copy, "evaluation.py", lambda p: _edit(p, 'return "scan" if', 'return "scans" if')) \
        == {"data", "classifier", "features", "models", "evaluate", "report", "simulate"}


def test_the_methods_registered_from_outside_still_enter_the_keys_of_the_stages_that_run_them(tmp_config, monkeypatch):
    import stages.framework.runner as runner
    from stages.framework.registry import STAGES

    cfg = tmp_config()
    keys = {}
    for fp in ("outside_vote=aaaa", "outside_vote=bbbb"):
        monkeypatch.setattr(runner, "outside_fingerprint", lambda fp=fp: fp)
        keys[fp] = {n: runner.stage_key(cfg, s, {})[0] for n, s in STAGES.items()}
    moved = {n for n in STAGES if keys["outside_vote=aaaa"][n] != keys["outside_vote=bbbb"][n]}
    assert moved == {n for n, s in STAGES.items() if s.methods} == {"evaluate", "simulate"}


def test_a_stage_stale_by_a_new_default_alone_says_so():
    from stages.framework.runner import _key_reason

    old = {"stage": "report", "sections": {"report": {}}, "code": "c", "upstream": {}, "defaults": "d1"}
    assert _key_reason({"parts": old}, {**old, "defaults": "d2"}) == "a setting's default changed"

"""docs/api.md, README.md and configs/synthetic.toml list the built-in methods, planners and
metrics as the registries hold them: their generated blocks (tools/gen_docs.py) match, and a
drifted block is caught and named with the command that rewrites it."""
import importlib.util
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("gen_docs", ROOT / "tools" / "gen_docs.py")
gen_docs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(gen_docs)


def test_the_generated_lists_match_the_registries():
    stale = gen_docs.drift()
    assert not stale, f"generated blocks out of date in {', '.join(stale)}: run `{gen_docs.COMMAND}`"


def test_every_file_holds_its_blocks():
    names = {"README.md": {"builtins"}, "docs/api.md": {"methods", "planners_metrics"},
             "configs/synthetic.toml": {"evaluate", "plan"}}
    for rel, want in names.items():
        text = (ROOT / rel).read_text()
        pattern = gen_docs.TOML if rel.endswith(".toml") else gen_docs.MD
        assert {m.group(2) for m in pattern.finditer(text)} == want, rel


def test_a_drifted_block_is_caught_and_rewritten(tmp_path):
    for rel in gen_docs.FILES:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / rel, tmp_path / rel)
    lists = gen_docs.builtins()
    grown = {**lists, "planners": [*lists["planners"], "my_planner"]}
    assert gen_docs.drift(tmp_path, grown) == list(gen_docs.FILES)
    gen_docs.write(tmp_path, grown)
    assert gen_docs.drift(tmp_path, grown) == []
    assert "`my_planner`" in (tmp_path / "README.md").read_text()
    assert f"The {len(grown['planners'])} built-in planners" in (tmp_path / "configs/synthetic.toml").read_text()

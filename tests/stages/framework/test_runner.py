"""Stage runner: manifests, skipping, staleness propagation, atomic output."""
import sys
import types

import pytest

import pipeline.infra.outputs as outputs
import stages.framework.registry as registry
import stages.framework.runner as runner
from stages.framework.registry import StageSpec


@pytest.fixture
def fake_stages(monkeypatch):
    """Two fake stages a -> b reading sections 'features' and 'models'; counts runs."""
    calls = []

    def make(name, fail=False):
        mod = types.ModuleType(f"fake_stage_{name}")

        def run(ctx):
            calls.append(name)
            (ctx.out / "out.txt").write_text(name)
            if fail:
                (ctx.out / "half.txt").write_text("half")
                raise RuntimeError("boom")
            return f"wrote {name}"
        mod.run = run
        monkeypatch.setitem(sys.modules, mod.__name__, mod)
        return mod

    make("a"), make("b")
    specs = {
        "a": StageSpec("a", "fake_stage_a", (), ("features",)),
        "b": StageSpec("b", "fake_stage_b", ("a",), ("models",)),
    }
    monkeypatch.setattr(runner, "STAGES", specs)
    monkeypatch.setattr(registry, "STAGES", specs)
    for s in specs:  # what the fake stages write, declared in the catalog
        monkeypatch.setitem(outputs.CATALOG, s, {"out": outputs.Artifact("out.txt", "text", "tests.stages.framework.test_runner:run", None),
                                                 "half": outputs.Artifact("half.txt", "text", "tests.stages.framework.test_runner:run", None)})
    return calls, make


def test_an_undeclared_output_is_refused_and_nothing_is_swapped_in(tmp_config, fake_stages, monkeypatch):
    monkeypatch.setitem(outputs.CATALOG, "a", {"other": outputs.Artifact("other.txt", "text", "x:y", None)})
    cfg = tmp_config()
    with pytest.raises(RuntimeError, match=r"stage 'a' wrote output\(s\) .* does not declare: out\.txt"):
        runner.ensure(cfg, "a")
    assert not cfg.stage_dir("a").exists() and not any(cfg.run_dir.glob(".a.tmp"))


def test_runs_upstream_then_skips(tmp_config, fake_stages, capsys):
    calls, _ = fake_stages
    cfg = tmp_config()
    runner.ensure(cfg, "b")
    assert calls == ["a", "b"]
    assert (cfg.stage_dir("b") / "out.txt").read_text() == "b"
    m = runner.read_manifest(cfg, "b")
    assert m["summary"] == "wrote b" and m["seconds"] >= 0
    runner.ensure(cfg, "b")
    assert calls == ["a", "b"]
    assert "up to date" in capsys.readouterr().out


def test_the_manifest_records_the_stage_cpu_seconds(tmp_config, fake_stages, monkeypatch):
    _, make = fake_stages
    mod = make("a")
    plain = mod.run

    def busy(ctx):  # about 0.2 CPU s of work inside the stage
        import time
        c0 = time.process_time()
        while time.process_time() - c0 < 0.2:
            pass
        return plain(ctx)
    monkeypatch.setattr(mod, "run", busy)
    cfg = tmp_config()
    runner.ensure(cfg, "a")
    m = runner.read_manifest(cfg, "a")
    assert 0.2 <= m["cpu_seconds"] < 0.2 + m["seconds"] * 4 + 1


def test_section_change_reruns_only_dependents(tmp_config, fake_stages):
    calls, _ = fake_stages
    runner.ensure(tmp_config(), "b")
    calls.clear()
    runner.ensure(tmp_config({"models": {"restarts": 2}}), "b")
    assert calls == ["b"]          # 'a' does not read [models]
    calls.clear()
    runner.ensure(tmp_config({"models": {"restarts": 2}, "features": {"margin": 0.5}}), "b")
    assert calls == ["a", "b"]     # upstream change propagates
    calls.clear()
    runner.ensure(tmp_config({"models": {"restarts": 2}, "features": {"margin": 0.5},
                              "evaluate": {"seed": 7}}), "b")
    assert calls == []             # unrelated section


def test_force_reruns_only_requested(tmp_config, fake_stages):
    calls, _ = fake_stages
    cfg = tmp_config()
    runner.ensure(cfg, "b")
    calls.clear()
    runner.ensure(cfg, "b", force=True)
    assert calls == ["b"]


def test_failed_stage_leaves_no_output(tmp_config, fake_stages):
    calls, make = fake_stages
    cfg = tmp_config()
    runner.ensure(cfg, "b")
    before = runner.read_manifest(cfg, "b")
    make("b", fail=True)
    with pytest.raises(RuntimeError, match="boom"):
        runner.ensure(cfg, "b", force=True)
    # The previous complete output is intact; no temp folder or half file remains.
    assert runner.read_manifest(cfg, "b") == before
    assert not (cfg.stage_dir("b") / "half.txt").exists()
    assert not any(p.name.startswith(".") for p in cfg.run_dir.iterdir())


def test_cli_reports_config_errors(tmp_path, capsys):
    from stages.commands.cli import main
    bad = tmp_path / "bad.toml"
    bad.write_text("[run]\ncolour = 1\n")
    assert main(["data", "--config", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "run.colour" in err and str(bad) in err


def test_write_json_is_strict_json(tmp_path):
    import json

    import numpy as np

    from pipeline.infra.cache import write_json
    p = tmp_path / "s.json"
    write_json(p, {"inf": float("inf"), "nan": np.float64("nan"), "f32": np.float32(-np.inf),
                   "arr": np.array([1.0, np.nan]), "ok": 2.5, "n": np.int64(3)})
    text = p.read_text()
    assert "Infinity" not in text and "NaN" not in text
    assert json.loads(text) == {"inf": None, "nan": None, "f32": None, "arr": [1.0, None], "ok": 2.5, "n": 3}

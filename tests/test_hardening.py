"""The bad-input audit of issue 14, one test (or more) per case, on generated fixtures.

Numbers in the test names follow the issue's list: 1 skips, 2 corrupt JPEG, 3 caches,
5 truncated npz, 6 calibration, 7 minor (threads, orphans, up-front checks, npz bytes, skip counts),
8 progress, 9 derived code dependencies, 10 layering, 11 test-only code.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from loaders.errors import BadInputError, SkipLog, SkipPolicy
from tests.readers_fixtures import make_avd_scan, make_bigbird_object, write_jpeg

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------------------------
# helpers

def corrupt_entropy(data: bytes) -> bytes:
    """A JPEG whose markers are intact (SOI, SOS, EOI) but whose entropy-coded data stops early."""
    sos = data.find(b"\xff\xda")
    start = sos + 2 + int.from_bytes(data[sos + 2:sos + 4], "big")
    eoi = data.rfind(b"\xff\xd9")
    return data[:start + (eoi - start) // 3] + b"\xff\xd9"


def real_cfg(tmp_config, tmp_path, skip=True, **over):
    bb, avd = tmp_path / "bigbird", tmp_path / "avd"
    return tmp_config({"data": {"source": "real", "bigbird_root": str(bb), "avd_root": str(avd),
                                "scans": ["Home_001_1"], "skip_bad_views": skip, **over},
                       "features": {"bigbird_cameras": [1]}})


@pytest.fixture
def real_data(tmp_path):
    make_bigbird_object(tmp_path / "bigbird", angles=(0, 3), cameras=(1,))
    return make_avd_scan(tmp_path / "avd")


# ------------------------------------------------------------------------------------------------
# 1. one skip policy, counted in the manifest of the stage that meets the bad entry

def _bad_box_and_missing_image(ann):
    first = sorted(ann)[0]
    ann[first]["bounding_boxes"].append([50, 50, 40, 60, 2, 1])          # degenerate box
    ann["Home_001_1_nope.jpg"] = {"bounding_boxes": []}                   # names a missing image


def test_1_skips_on_counted_in_the_data_manifest_and_off_stops_the_data_stage(tmp_config, tmp_path):
    from stages.runner import ensure, read_manifest

    make_bigbird_object(tmp_path / "bigbird", angles=(0, 3), cameras=(1,))
    make_avd_scan(tmp_path / "avd", annotation_edit=_bad_box_and_missing_image)
    cfg = real_cfg(tmp_config, tmp_path, skip=True)
    ensure(cfg, "data")
    sk = read_manifest(cfg, "data")["extra"]["skipped"]["avd"]
    assert sk["skipped"] == 2
    assert any("degenerate box" in e for e in sk["examples"])
    assert any("Home_001_1_nope.jpg" in e and "annotations.json" in e for e in sk["examples"])

    off = real_cfg(tmp_config, tmp_path, skip=False, seed=1)   # another key: reruns
    with pytest.raises(BadInputError, match=r"annotations\.json: .*(nope|degenerate)"):
        ensure(off, "data")


def test_1_policy_gives_the_same_log_to_every_reader_and_raises_when_off(tmp_path):
    from loaders.avd import AVDScan

    make_avd_scan(tmp_path / "avd", annotation_edit=_bad_box_and_missing_image)
    on = SkipPolicy(True)
    scan = AVDScan(tmp_path / "avd", "Home_001_1", skip=on.log("avd", "AVD entry"))
    assert on.count == 2 and set(on.summary()) == {"avd"}
    assert len(scan.images) == 24                            # the images themselves are kept
    off = SkipPolicy(False)
    assert off.log("avd") is None and off.summary() == {}
    with pytest.raises(BadInputError):
        off.handle(BadInputError("x.jpg", "bad"), "avd")
    with pytest.raises(BadInputError, match="annotations.json"):
        AVDScan(tmp_path / "avd", "Home_001_1", skip=off.log("avd"))


# ------------------------------------------------------------------------------------------------
# 2. libjpeg's corrupt-data warning becomes a named error / a counted skip

def test_2_entropy_cut_jpeg_is_named_not_scored(tmp_path, capfd):
    from loaders.bigbird import BigBirdObject, read_rgb

    p = tmp_path / "x.jpg"
    rng = np.random.default_rng(0)
    write_jpeg(p, rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    good = read_rgb(p)
    assert good.shape == (48, 64, 3)
    p.write_bytes(corrupt_entropy(p.read_bytes()))
    with pytest.raises(BadInputError, match=r"x\.jpg: corrupt JPEG: libjpeg reports .*premature end of data segment"):
        read_rgb(p)
    assert "Corrupt JPEG data" not in capfd.readouterr().err  # captured, not printed without a name

    make_bigbird_object(tmp_path / "bb", angles=(0, 3, 6), cameras=(1,))
    view = tmp_path / "bb" / "aunt_jemima_original_syrup" / "NP1_3.jpg"
    view.write_bytes(corrupt_entropy(view.read_bytes()))
    obj = BigBirdObject(tmp_path / "bb" / "aunt_jemima_original_syrup")
    skip = SkipLog("BigBIRD view")
    recs = list(obj.iter_views((1,), skip=skip))
    assert [r.view.angle for r in recs] == [0, 6]
    assert skip.count == 1 and "NP1_3.jpg" in skip.examples[0] and "premature end" in skip.examples[0]


def test_2_other_c_stderr_output_is_passed_on(capfd):
    from loaders.bigbird import _c_stderr_captured

    with _c_stderr_captured() as lines:
        os.write(2, b"unrelated native message\nCorrupt JPEG data: bad Huffman code\n")
    assert any("Huffman" in ln for ln in lines)
    err = capfd.readouterr().err
    assert "unrelated native message" in err and "Huffman" not in err


# ------------------------------------------------------------------------------------------------
# 3. caches check contents: outputs, inputs, upstream outputs, model files vs index.json

@pytest.fixture
def fake_chain(monkeypatch, tmp_path):
    """a -> b; a writes out.txt (its text settable) and reads an input file (note_read)."""
    import stages.registry as registry
    import stages.runner as runner
    from pipeline.infra.cache import note_read
    from stages.registry import StageSpec

    calls, state = [], {"text": "a1"}
    src = tmp_path / "input.bin"
    src.write_bytes(b"input v1")

    def mod(name, body):
        m = types.ModuleType(f"fake_hard_{name}")
        m.run = body
        monkeypatch.setitem(sys.modules, m.__name__, m)

    def run_a(ctx):
        calls.append("a")
        note_read(src, src.read_bytes())
        (ctx.out / "out.txt").write_text(state["text"])
        return "a"

    def run_b(ctx):
        calls.append("b")
        (ctx.out / "copy.txt").write_text((ctx.input("a") / "out.txt").read_text())
        return "b"

    mod("a", run_a), mod("b", run_b)
    specs = {"a": StageSpec("a", "fake_hard_a", (), ("features",)),
             "b": StageSpec("b", "fake_hard_b", ("a",), ("models",))}
    monkeypatch.setattr(runner, "STAGES", specs)
    monkeypatch.setattr(registry, "STAGES", specs)
    return calls, state, src


def test_3_changed_output_reruns_and_says_which_file(tmp_config, fake_chain, capsys):
    from stages.runner import ensure, plan

    calls, _, _ = fake_chain
    cfg = tmp_config()
    ensure(cfg, "b")
    assert plan(cfg, "b")["state"] == "up to date"
    out = cfg.stage_dir("a") / "out.txt"
    out.write_text("tampered")                    # bytes of an upstream output changed
    st = plan(cfg, "a")
    assert st["state"] == "stale" and str(out) in st["why"] and "content changed" in st["why"]
    assert plan(cfg, "b")["state"] == "stale"      # and everything downstream
    calls.clear()
    capsys.readouterr()
    ensure(cfg, "b")
    # a reruns and writes the same bytes again, so b's inputs are what b was built from
    assert calls == ["a"]
    assert f"output {out}" in capsys.readouterr().out
    assert out.read_text() == "a1" and plan(cfg, "b")["state"] == "up to date"


def test_3_forced_upstream_rerun_with_new_results_makes_downstream_stale(tmp_config, fake_chain):
    from stages.runner import ensure, plan

    calls, state, _ = fake_chain
    cfg = tmp_config()
    ensure(cfg, "b")
    state["text"] = "a2"                           # e.g. evaluate --force gives other numbers
    ensure(cfg, "a", force=True)
    assert plan(cfg, "b")["state"] == "stale"
    calls.clear()
    ensure(cfg, "b")
    assert calls == ["b"] and (cfg.stage_dir("b") / "copy.txt").read_text() == "a2"
    calls.clear()
    ensure(cfg, "a", force=True)                   # same bytes again: downstream stays valid
    ensure(cfg, "b")
    assert calls == ["a"]


def test_3_input_rewritten_in_place_is_detected(tmp_config, fake_chain, capsys):
    from stages.runner import ensure, read_manifest

    calls, _, src = fake_chain
    cfg = tmp_config()
    ensure(cfg, "a")
    assert str(src) in read_manifest(cfg, "a")["inputs"]
    src.write_bytes(b"input v2")
    calls.clear()
    capsys.readouterr()
    ensure(cfg, "a")
    assert calls == ["a"] and f"input {src}" in capsys.readouterr().out
    os.utime(src)                                  # touched, same bytes: still up to date
    calls.clear()
    ensure(cfg, "a")
    assert calls == []


def test_3_swapped_model_files_are_an_error_naming_both(tmp_path):
    from pipeline.method.gp import ModelFileError, GPClassModels
    from tests.test_gp import make_models

    m = make_models(np.random.default_rng(0))
    m.save(tmp_path)
    index = json.loads((tmp_path / "index.json").read_text())
    a, b = (tmp_path / index["files"][c] for c in m.classes[:2])
    da, db = a.read_bytes(), b.read_bytes()
    a.write_bytes(db), b.write_bytes(da)
    with pytest.raises(ModelFileError) as e:
        GPClassModels.load(tmp_path)
    assert str(a) in str(e.value) and str(b) in str(e.value) and "swapped" in str(e.value)
    a.write_bytes(da[:-10] + b"0123456789")
    with pytest.raises(ModelFileError, match="content differs from the sha256 recorded"):
        GPClassModels.load(tmp_path)


# ------------------------------------------------------------------------------------------------
# 5 and 7. npz files: truncated or random bytes are named, never "pickled data"

def test_5_7_bad_npz_files_are_named(tmp_path):
    from pipeline.infra.cache import NpzFileError, load_npz
    from pipeline.method.gp import GPClassModels, ModelFileError
    from tests.test_gp import make_models

    good = tmp_path / "g.npz"
    np.savez(good, a=np.arange(3))
    assert load_npz(good)["a"].tolist() == [0, 1, 2]
    trunc = tmp_path / "gp_models.npz"
    trunc.write_bytes(good.read_bytes()[:60])
    with pytest.raises(NpzFileError, match=r"gp_models\.npz: not a valid \.npz file \(truncated"):
        load_npz(trunc)
    rnd = tmp_path / "bias_maps.npz"
    rnd.write_bytes(np.random.default_rng(0).bytes(400))
    with pytest.raises(NpzFileError, match=r"bias_maps\.npz: not a valid \.npz file") as e:
        load_npz(rnd)
    assert "pickle" not in str(e.value)
    obj = tmp_path / "obj.npz"
    np.savez(obj, a=np.array([{"x": 1}], dtype=object))
    with pytest.raises(NpzFileError, match="object arrays"):
        load_npz(obj)

    models = tmp_path / "models"
    make_models(np.random.default_rng(1)).save(models)
    index = json.loads((models / "index.json").read_text())
    index.pop("sha256")                            # an index without digests: the npz check still names it
    (models / "index.json").write_text(json.dumps(index))
    f = models / index["files"]["class_0"]
    f.write_bytes(np.random.default_rng(2).bytes(500))
    with pytest.raises(ModelFileError, match="not a valid .npz file") as e:
        GPClassModels.load(models)
    assert "pickle" not in str(e.value) and str(f) in str(e.value)


# ------------------------------------------------------------------------------------------------
# 6. calibration: a missing file is named (skip or error), a missing key is one named error

def test_6_object_without_calibration_is_a_named_skip_or_error(tmp_config, tmp_path, real_data):
    from stages.runner import ensure, read_manifest

    make_bigbird_object(tmp_path / "bigbird", name="crystal_hot_sauce", angles=(0, 3), cameras=(1,))
    calib = tmp_path / "bigbird" / "crystal_hot_sauce" / "calibration.h5"
    calib.unlink()
    cfg = real_cfg(tmp_config, tmp_path, skip=True)
    ensure(cfg, "data")
    sk = read_manifest(cfg, "data")["extra"]["skipped"]["bigbird"]
    assert sk["skipped"] == 1 and str(calib) in sk["examples"][0]
    with pytest.raises(BadInputError, match=f"{calib}: object folder has views but no calibration"):
        ensure(real_cfg(tmp_config, tmp_path, skip=False), "data")


def test_6_missing_calibration_key_is_one_error_naming_file_and_key(tmp_config, tmp_path, real_data):
    import h5py

    from stages.features import _bigbird_objects

    calib = tmp_path / "bigbird" / "aunt_jemima_original_syrup" / "calibration.h5"
    with h5py.File(calib, "a") as f:
        del f["H_NP1_from_NP5"]
    cfg = real_cfg(tmp_config, tmp_path, skip=True)
    policy = SkipPolicy(True)
    with pytest.raises(BadInputError, match=f"{calib}: missing HDF5 dataset 'H_NP1_from_NP5'"):
        _bigbird_objects(cfg, tmp_path / "bigbird", policy)
    assert policy.count == 0                       # not one skip per view
    from stages.runner import ensure
    with pytest.raises(BadInputError, match="H_NP1_from_NP5"):
        ensure(cfg, "data")                        # and it stops the run before any scoring


# ------------------------------------------------------------------------------------------------
# 7. minor cases

def test_7_threads_flag_is_validated_like_the_config_value(capsys):
    from stages.cli import main

    assert main(["status", "--config", str(ROOT / "configs" / "synthetic.toml")]) == 0
    capsys.readouterr()
    assert main(["data", "--threads", "-1"]) == 2
    assert "'run.threads' = -1 is below the minimum 0" in capsys.readouterr().err


def test_7_orphan_temp_folders_are_removed_at_the_next_run(tmp_config):
    from stages.runner import remove_orphans

    cfg = tmp_config()
    cfg.run_dir.mkdir(parents=True)
    dead = cfg.run_dir / ".features.tmp"
    (dead / "sub").mkdir(parents=True)
    (dead / ".owner").write_text("999999999")      # no such process
    bare = cfg.run_dir / ".models.tmp"
    bare.mkdir()
    live = cfg.run_dir / ".evaluate.tmp"
    live.mkdir()
    (live / ".owner").write_text(str(os.getppid()))  # a running process is still writing it
    removed = remove_orphans(cfg)
    assert sorted(p.name for p in removed) == [".features.tmp", ".models.tmp"]
    assert not dead.exists() and not bare.exists() and live.exists()


@pytest.mark.parametrize("what", ["json", "instance_map", "mat"])
def test_7_avd_format_errors_stop_the_data_stage(tmp_config, tmp_path, real_data, what):
    from stages.runner import ensure

    folder = tmp_path / "avd" / "Home_001_1"
    target = {"json": folder / "annotations.json", "instance_map": tmp_path / "avd" / "instance_id_map.txt",
              "mat": folder / "image_structs.mat"}[what]
    target.write_text({"json": "{not json", "instance_map": "background 0\nbroken line here\n",
                       "mat": "not a mat file"}[what])
    with pytest.raises(BadInputError, match=str(target)):
        ensure(real_cfg(tmp_config, tmp_path, skip=True), "data")


def test_7_skip_counts_are_read_back_per_stage(tmp_config, tmp_path):
    from stages.runner import ensure, stage_skips

    make_bigbird_object(tmp_path / "bigbird", angles=(0, 3), cameras=(1,))
    make_avd_scan(tmp_path / "avd", annotation_edit=_bad_box_and_missing_image)
    cfg = real_cfg(tmp_config, tmp_path, skip=True)
    ensure(cfg, "data")
    assert stage_skips(cfg)["data"]["avd"]["skipped"] == 2


# ------------------------------------------------------------------------------------------------
# 8. progress: bars on a terminal only; a log gets a few plain lines, no carriage returns

LOOP = """
import logging, sys
logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
from pipeline.infra import progress
progress.LOG_AFTER_S = 0.0
progress.set_mode(sys.argv[1])
log = logging.getLogger("viewfuse.test")
with progress.redirect_logging():
    for i in progress.bar(range(400), desc="outer", unit="step"):
        if i == 200:
            log.info("halfway message")
    with progress.bar(total=50, desc="inner", leave=False) as b:
        for _ in range(50):
            b.update(1)
progress.echo("[stage] done")
"""


@pytest.mark.parametrize("mode", ["auto", "off"])
def test_8_redirected_output_has_no_carriage_returns(tmp_path, mode):
    log = tmp_path / "log"
    with open(log, "wb") as fh:
        subprocess.run([sys.executable, "-c", LOOP, mode], cwd=ROOT, stdout=fh, stderr=subprocess.STDOUT,
                       env={**os.environ, "PYTHONPATH": str(ROOT)}, check=True)
    text = log.read_bytes().decode()  # not read_text(): it would turn \r into \n
    assert "\r" not in text and "\x1b[" not in text
    outer = [ln for ln in text.splitlines() if "outer:" in ln]
    assert len(outer) == (0 if mode == "off" else 4) and len(outer) <= 5
    assert "INFO viewfuse.test: halfway message" in text.splitlines()
    assert "[stage] done" in text.splitlines()


def test_8_on_mode_draws_tqdm_and_log_lines_do_not_glue(tmp_path):
    log = tmp_path / "log"
    with open(log, "wb") as fh:
        subprocess.run([sys.executable, "-c", LOOP, "on"], cwd=ROOT, stdout=fh, stderr=subprocess.STDOUT,
                       env={**os.environ, "PYTHONPATH": str(ROOT)}, check=True)
    text = log.read_bytes().decode()  # not read_text(): it would turn \r into \n
    assert "\r" in text                                   # tqdm draws when asked to
    lines = [seg for ln in text.split("\n") for seg in ln.split("\r")]
    assert "INFO viewfuse.test: halfway message" in lines  # on a line of its own


# ------------------------------------------------------------------------------------------------
# 9. code dependencies derived from the imports

def test_9_stage_code_dependencies_follow_the_imports():
    from stages.registry import STAGES, code_deps

    deps = {n: set(code_deps(s.module)) for n, s in STAGES.items()}
    # the modules the hand-written lists missed (reports.results_io is now reports.artifacts)
    assert {"reports.artifacts", "reports.simulate_findings", "pipeline.infra.cache"} <= deps["simulate"]
    assert {"stages.data", "loaders.bigbird"} <= deps["evaluate"]
    assert "pipeline.infra.cache" in deps["models"]
    # imports inside functions count too (stages.data imports the writers lazily)
    assert "loaders.synthetic.avd_writer" in deps["data"]
    assert all(d.split(".")[0] in ("pipeline", "loaders", "stages", "reports") for ds in deps.values() for d in ds)


def test_9_editing_an_imported_module_changes_the_stage_key(tmp_path, monkeypatch):
    import stages.registry as registry

    pkg = tmp_path / "reports"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "zz_leaf.py").write_text("X = 1\n")
    (pkg / "zz_top.py").write_text("def f():\n    from reports import zz_leaf\n    return zz_leaf.X\n")
    monkeypatch.setattr(registry, "_module_file", lambda n: {
        "reports": pkg / "__init__.py", "reports.zz_leaf": pkg / "zz_leaf.py",
        "reports.zz_top": pkg / "zz_top.py"}.get(n))
    spec = registry.StageSpec("zz", "reports.zz_top")
    assert registry.code_deps("reports.zz_top") == ("reports", "reports.zz_leaf", "reports.zz_top")
    before = registry.code_version(spec)[0]
    # What the code says about itself (comments, docstrings, blank lines) does not change the key ...
    (pkg / "zz_leaf.py").write_text('"""A leaf module."""\n\n# the value\nX = 1  # one\n')
    assert registry.code_version(spec)[0] == before
    # ... what it does does.
    (pkg / "zz_leaf.py").write_text("X = 2\n")
    assert registry.code_version(spec)[0] != before
    (pkg / "zz_leaf.py").write_text('X = 1\ndef f():\n    """doc"""\n    return "doc"\n')
    changed = registry.code_version(spec)[0]
    (pkg / "zz_leaf.py").write_text('X = 1\ndef f():\n    """other doc"""\n    return "other"\n')
    assert registry.code_version(spec)[0] != changed  # a string that is not a docstring counts


def test_9_output_names_are_declared_once():
    from pipeline.infra.outputs import name
    from stages.registry import STAGES, output_name

    assert output_name("evaluate", "results") == name("evaluate", "results") == "results.parquet"
    assert STAGES["models"].outputs["index"] == "index.json"
    with pytest.raises(KeyError, match="declares no output 'nope'"):
        output_name("evaluate", "nope")


# ------------------------------------------------------------------------------------------------
# 11. test-only code lives in tests/

def test_11_test_only_helpers_are_not_in_the_package():
    import pipeline.scoring.classifier
    import pipeline.scoring.features
    import pipeline.method.fusion
    import pipeline.evaluation.metrics

    assert not (ROOT / "pipeline" / "methods.py").exists()
    for mod, name in ((pipeline.scoring.classifier, "full_passes_with_masks"), (pipeline.method.fusion, "fuse_with_uncertainty_sampled"),
                      (pipeline.evaluation.metrics, "summary_table"), (pipeline.scoring.features, "meta_columns")):
        assert not hasattr(mod, name), f"{mod.__name__}.{name}"
    import stages.runner
    assert not hasattr(stages.runner, "StageNotImplemented")


# ------------------------------------------------------------------------------------------------
# CLI: status, --version, per-stage help

def test_cli_status_version_and_stage_help(tmp_path, capsys):
    from stages.cli import main

    assert main(["status", "--set", f"run.artifacts={tmp_path}"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [ln.split()[0] for ln in lines] == ["data", "classifier", "features", "models", "evaluate",
                                               "report", "simulate"]
    assert all(ln.split(None, 1)[1] == "missing" for ln in lines)
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.startswith("viewfuse ")
    with pytest.raises(SystemExit):
        main(["features", "--help"])
    out = capsys.readouterr().out
    assert "features.n_samples = 10 in [1, 1000]: N_s dropout samples per AVD crop" in out
    assert "models.restarts" not in out and "--progress {auto,on,off}" in out


def test_many_skips_are_counted_but_not_all_logged(caplog):
    skip = SkipLog("AVD entry")
    with caplog.at_level("WARNING", logger="viewfuse.loaders"):
        for i in range(500):
            skip.skip(BadInputError(f"img{i}.jpg", "corrupt JPEG"))
    assert skip.count == 500 and skip.reasons == {"corrupt JPEG": 500} and len(skip.examples) == 20
    assert len(caplog.records) == SkipLog.LOG_FIRST + 1
    assert "counted, not logged" in caplog.records[-1].getMessage()


# ------------------------------------------------------------------------------------------------
# 12. comments cite files inside the repository

def test_12_no_citations_of_files_outside_the_repository():
    import re

    bad = []
    files = [ROOT / "README.md", *(ROOT / "configs").glob("*.toml")]
    for d in ("pipeline", "loaders", "stages", "reports", "tests"):
        files += sorted((ROOT / d).rglob("*.py"))
    outside = re.compile(r"DESIGN §|/work/shared|(?<![\w/])formats/")
    for path in files:
        for no, line in enumerate(path.read_text().splitlines(), start=1):
            if outside.search(line) and "outside = re.compile" not in line:
                bad.append(f"{path.relative_to(ROOT)}:{no}: {line.strip()}")
    assert not bad, "citations of files outside the repository:\n" + "\n".join(bad)
    for cited in ("docs/design.md", "docs/formats/avd.md", "docs/formats/bigbird.md",
                  "docs/formats/avd_instance_id_map.txt"):
        assert (ROOT / cited).is_file(), cited

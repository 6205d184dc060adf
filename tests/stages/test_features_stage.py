"""Features stage on a tiny synthetic chain: Parquet schema and metadata, rows, crops, cache key."""
import json
import shutil

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.infra.config import merge
from pipeline.scoring.crops import crop_box
from pipeline.scoring.features import build_table, read_features

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)

N_S = 3
TINY = {
    "data": {"scans": ["Home_001_1"], "synthetic": {"instances_per_scan": 0, "angle_step_deg": 60, "bigbird_width": 160, "bigbird_height": 128,
                           "avd_width": 320, "avd_height": 180, "room_size_m": [2.4, 2.1],
                           "grid_step_m": 0.6, "distractors": 2, "workers": 1}},
    "classifier": {"input_size": 64, "training": {"train_images": 36, "val_images": 12, "epochs": 1,
                                                  "batch_size": 12, "min_accuracy": 0.0}},
    "features": {"n_samples": N_S, "bigbird_samples": 2, "max_difficulty": 5, "batch_size": 16},
}


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    from pipeline.infra.config import load_config
    from stages.framework.runner import ensure
    from tests.conftest import DEFAULT_CONFIG

    art = tmp_path_factory.mktemp("feat") / "artifacts"
    cfg = load_config(DEFAULT_CONFIG, merge(TINY, {"run": {"artifacts": str(art)}}))
    ensure(cfg, "features", device="cpu")
    return cfg


def _meta(path):
    md = pq.read_schema(path).metadata
    return {k.decode(): v.decode() for k, v in md.items()}


def test_parquet_schemas_follow_the_contract(chain):
    d = chain.stage_dir("features")
    bb = pq.read_schema(d / "bigbird.parquet")
    av = pq.read_schema(d / "avd.parquet")
    i32, f64 = pa.int32(), pa.float64()
    want_bb = {"object": pa.string(), "camera": i32, "angle_deg": i32, "image": pa.string(),
               **{c: i32 for c in ("box_x0", "box_y0", "box_x1", "box_y1", "crop_x0", "crop_y0", "crop_x1", "crop_y1")},
               "cam_x": f64, "cam_y": f64, "cam_z": f64, "u_x": f64, "u_y": f64, "pass": pa.int16()}
    want_av = {"scan": pa.string(), "image": pa.string(), "instance": pa.string(), "instance_id": i32,
               "difficulty": pa.int8(),
               **{c: i32 for c in ("box_x0", "box_y0", "box_x1", "box_y1", "crop_x0", "crop_y0", "crop_x1", "crop_y1")},
               "cam_x": f64, "cam_y": f64, "heading": f64, "registered": pa.bool_(), "pass": pa.int16()}
    for sch, want in ((bb, want_bb), (av, want_av)):
        assert sch.names == list(want) + ["scores"]
        for name, t in want.items():
            assert sch.field(name).type == t, name
        st = sch.field("scores").type
        assert pa.types.is_fixed_size_list(st) and st.list_size == 12 and st.value_type == pa.float32()


def test_parquet_metadata_names_config_classifier_and_seed(chain):
    d = chain.stage_dir("features")
    card = json.loads((chain.stage_dir("classifier") / "card.json").read_text())
    for name in ("bigbird.parquet", "avd.parquet"):
        md = _meta(d / name)
        assert md["viewfuse.config_hash"] == chain.section_hash("features")
        assert md["viewfuse.classifier_hash"] == card["hash"]
        assert md["viewfuse.seed"] == str(chain.features.seed)
        assert md["viewfuse.n_samples"] == str(N_S) and md["viewfuse.score_dim"] == "12"
        assert json.loads(md["viewfuse.output_names"]) == card["output_names"]


def test_bigbird_rows_are_the_deterministic_pass_then_dropout_passes_per_view(chain):
    from loaders.bigbird import BigBirdObject
    from stages.framework.roots import data_roots

    full, all_scores, meta = read_features(chain.stage_dir("features") / "bigbird.parquet")
    root, _ = data_roots(chain)
    # Each view: pass -1 (the GP training target) then features.bigbird_samples dropout passes.
    assert full["pass"].tolist() == [-1, 0, 1] * (len(full) // 3)
    drop = all_scores[full["pass"].to_numpy() >= 0]
    assert not np.array_equal(drop[0::2], drop[1::2])                    # the dropout passes differ
    det = (full["pass"] == -1).to_numpy()
    df, scores = full[det].reset_index(drop=True), all_scores[det]
    assert len(df) == len(chain.data.synthetic.instances) * 6            # 360 / 60 angles each
    assert not df.duplicated(["object", "camera", "angle_deg"]).any()
    assert scores.shape == (len(df), 12) and scores.dtype == np.float32
    np.testing.assert_allclose(scores.sum(1), 1.0, atol=1e-5)
    r = df.iloc[3]
    obj = BigBirdObject(root / r["object"])
    np.testing.assert_allclose([r.cam_x, r.cam_y, r.cam_z], obj.camera_position(r.camera, r.angle_deg))
    assert (root / r["image"]).is_file()
    np.testing.assert_allclose(np.hypot(df.u_x, df.u_y), 1.0)
    np.testing.assert_allclose(np.arctan2(df.u_y, df.u_x), np.arctan2(df.cam_y, df.cam_x))
    for _, r in df.iterrows():
        assert (r.crop_x0, r.crop_y0, r.crop_x1, r.crop_y1) == crop_box(
            (r.box_x0, r.box_y0, r.box_x1, r.box_y1), chain.features.margin, chain.features.square)


def test_avd_rows_cover_every_box_with_the_dropout_samples(chain):
    from loaders.avd import AVDScan
    from stages.framework.roots import data_roots

    df, scores, _ = read_features(chain.stage_dir("features") / "avd.parquet")
    _, root = data_roots(chain)
    # Expected crops straight from the annotation file (present instances, difficulty <= 5).
    ann = json.loads((root / chain.data.scans[0] / "annotations.json").read_text())
    scan = AVDScan(root, chain.data.scans[0])
    present = {scan.instance_ids[n] for n in scan.present_instances}
    n_boxes = sum(1 for e in ann.values() for b in e["bounding_boxes"] if b[4] in present and b[5] <= 5)
    assert n_boxes > 0 and len(df) == n_boxes * (1 + N_S)
    det = df[df["pass"] == -1]
    assert len(det) == n_boxes
    # Each crop: pass -1 then 0..N_s-1 in consecutive rows with the same box.
    passes = df["pass"].to_numpy().reshape(n_boxes, 1 + N_S)
    assert (passes == np.arange(-1, N_S)).all()
    keys = df[["image", "instance", "box_x0", "box_y0"]].to_numpy().reshape(n_boxes, 1 + N_S, 4)
    assert (keys == keys[:, :1]).all()
    s = scores.reshape(n_boxes, 1 + N_S, 12)
    np.testing.assert_allclose(s.sum(-1), 1.0, atol=1e-5)
    assert np.abs(s[:, 1:] - s[:, :1]).max() > 1e-4          # samples differ from the eval pass
    assert np.abs(s[:, 1] - s[:, 2]).max() > 1e-4            # and from each other
    r = det.iloc[0]
    img = scan.images[r["image"]]
    assert (r.cam_x, r.cam_y, r.heading, r.registered) == (img.position[0], img.position[1], img.heading, img.registered)
    assert (df["scan"] == chain.data.scans[0]).all()


def test_cache_key_reruns_on_relevant_settings_only(chain, capsys):
    from stages.framework.registry import STAGES
    from stages.framework.runner import ensure, plan, read_manifest, stage_key
    from pipeline.infra.config import load_config
    from tests.conftest import DEFAULT_CONFIG

    def cfg_with(over):
        # one BigBIRD object models one class: "all" candidates, so the config's own check (a sampled
        # set needs n_candidates modelled classes) does not refuse a features-only selection
        base = merge(TINY, {"run": {"artifacts": str(chain.run_dir.parent)}, "evaluate": {"candidates": "all"}})
        return load_config(DEFAULT_CONFIG, merge(base, over))

    def key(cfg):
        # Upstream digests planned, not run: the key the runner would compute now.
        up = {u: plan(cfg, u)["digest"] for u in STAGES["features"].upstream}
        return stage_key(cfg, STAGES["features"], up)[0]

    base = read_manifest(chain, "features")["key"]
    assert key(chain) == base
    # Unrelated sections: same key, and the stage is skipped.
    for over in ({"evaluate": {"track_length": 5}}, {"models": {"n_components": 3}}, {"report": {"dpi": 80}}):
        c = cfg_with(over)
        assert key(c) == base, over
    capsys.readouterr()
    ensure(cfg_with({"evaluate": {"track_length": 5}}), "features", device="cpu")
    assert "[features] up to date" in capsys.readouterr().out
    # Anything that changes a score: a new key.
    for over in ({"features": {"margin": 0.2}}, {"features": {"n_samples": 4}}, {"features": {"seed": 1}},
                 {"features": {"pad": "edge"}}, {"classifier": {"dropout": 0.3}}):
        assert key(cfg_with(over)) != base, over
    # And the margin change really reruns it, with new crops.
    before = read_features(chain.stage_dir("features") / "bigbird.parquet")[0]
    ensure(cfg_with({"features": {"margin": 0.2}}), "features", device="cpu")
    after = read_features(chain.stage_dir("features") / "bigbird.parquet")[0]
    assert read_manifest(chain, "features")["key"] != base
    assert (after["crop_x1"] - after["crop_x0"]).sum() > (before["crop_x1"] - before["crop_x0"]).sum()
    ensure(chain, "features", device="cpu")            # back to the fixture's state for other tests
    assert read_manifest(chain, "features")["key"] == base


def test_weights_identity_is_in_the_key(chain, tmp_path):
    from stages.features import extra_key

    card = json.loads((chain.stage_dir("classifier") / "card.json").read_text())
    assert extra_key(chain) == f"classifier={card['hash']}"


def test_rerun_is_deterministic_and_a_bad_view_is_a_counted_skip(chain, tmp_path):
    from loaders.errors import BadInputError, SkipPolicy
    from stages.features import bigbird_jobs
    from stages.framework.runner import ensure, read_manifest

    # A copy of the run with one corrupt BigBIRD image; the data stage's manifest still matches.
    art = tmp_path / "artifacts"
    shutil.copytree(chain.run_dir, art / chain.run.name)
    from pipeline.infra.config import load_config
    from tests.conftest import DEFAULT_CONFIG
    cfg = load_config(DEFAULT_CONFIG, merge(TINY, {"run": {"artifacts": str(art)}}))
    ensure(cfg, "features", device="cpu", force=True)
    a = read_features(chain.stage_dir("features") / "avd.parquet")[1]
    b = read_features(cfg.stage_dir("features") / "avd.parquet")[1]
    np.testing.assert_array_equal(a, b)                  # same seed, same masks, same scores

    obj = sorted(cfg.data.synthetic.instances)[0]
    bad = cfg.stage_dir("data") / "bigbird" / obj / "NP1_60.jpg"
    bad.write_bytes(bad.read_bytes()[:200])              # truncated JPEG
    # ensure() would see the data stage's output changed and render it again: run features alone.
    from stages.framework.registry import STAGES
    from stages.framework.runner import plan, run_stage, stage_key
    up = {u: read_manifest(cfg, u) for u in STAGES["features"].upstream}
    from stages.framework.runner import digest
    key, parts = stage_key(cfg, STAGES["features"], {u: digest(m) for u, m in up.items()})
    run_stage(cfg, STAGES["features"], key, parts, device="cpu", threads=0)
    assert plan(cfg, "data")["state"] == "stale"         # the runner knows the image changed
    m = read_manifest(cfg, "features")
    assert m["extra"]["skipped"]["bigbird"]["skipped"] == 1
    assert "NP1_60.jpg" in m["extra"]["skipped"]["bigbird"]["examples"][0]
    df = read_features(cfg.stage_dir("features") / "bigbird.parquet")[0]
    df = df[df["pass"] == -1]
    assert len(df) == len(cfg.data.synthetic.instances) * 6 - 1
    assert not ((df["object"] == obj) & (df["angle_deg"] == 60)).any()

    class Bar:
        def reset(self, total): pass
        def update(self, n): pass
    with pytest.raises(BadInputError, match="NP1_60.jpg"):
        list(bigbird_jobs(cfg, cfg.stage_dir("data") / "bigbird", SkipPolicy(False), Bar()))


def test_build_table_checks_shapes_and_orders_passes():
    cols = {c: [0, 1] for c in ("camera", "angle_deg", "box_x0", "box_y0", "box_x1", "box_y1",
                                "crop_x0", "crop_y0", "crop_x1", "crop_y1")}
    cols.update({"object": ["a", "b"], "image": ["a/x.jpg", "b/x.jpg"], "cam_x": [1.0, 2.0], "cam_y": [0.0, 1.0],
                 "cam_z": [0.5, 0.5], "u_x": [1.0, 0.0], "u_y": [0.0, 1.0]})
    det = np.array([[0.2, 0.8], [0.6, 0.4]], np.float32)
    mc = np.arange(12, dtype=np.float32).reshape(2, 3, 2)
    t = build_table("bigbird", cols, det, mc, {"viewfuse.seed": "0"})
    assert t.column("pass").to_pylist() == [-1, 0, 1, 2] * 2
    assert t.column("object").to_pylist() == ["a"] * 4 + ["b"] * 4
    s = np.asarray(t.column("scores").combine_chunks().flatten()).reshape(-1, 2)
    np.testing.assert_array_equal(s[4], det[1])
    np.testing.assert_array_equal(s[5:8], mc[1])
    with pytest.raises(ValueError, match="dropout scores"):
        build_table("bigbird", cols, det, mc[:1], None)
    del cols["cam_z"]
    with pytest.raises(KeyError, match="cam_z"):
        build_table("bigbird", cols, det, None, None)
    empty = build_table("avd", {}, np.zeros((0, 2), np.float32), np.zeros((0, 3, 2), np.float32))
    assert empty.num_rows == 0 and empty.schema.field("scores").type.list_size == 2
    with pytest.raises(FileNotFoundError, match="features file not found"):
        read_features("/nonexistent/avd.parquet")


def test_object_and_instance_selection_keys_are_checked(chain):
    from loaders.avd import AVDScan
    from loaders.errors import SkipPolicy
    from pipeline.infra.config import load_config
    from stages.framework.roots import data_roots
    from stages.features import avd_jobs, bigbird_jobs
    from tests.conftest import DEFAULT_CONFIG

    class Bar:
        total = 0
        def reset(self, total): self.total = total
        def update(self, n): pass

    def cfg_with(over):
        # one BigBIRD object models one class: "all" candidates, so the config's own check (a sampled
        # set needs n_candidates modelled classes) does not refuse a features-only selection
        base = merge(TINY, {"run": {"artifacts": str(chain.run_dir.parent)}, "evaluate": {"candidates": "all"}})
        return load_config(DEFAULT_CONFIG, merge(base, over))

    bb, avd = data_roots(chain)
    one = sorted(chain.data.synthetic.instances)[1]
    jobs = list(bigbird_jobs(cfg_with({"features": {"bigbird_objects": [one]}}), bb, SkipPolicy(False), Bar()))
    assert len(jobs) == 6 and {j.columns["object"] for j in jobs} == {one}
    with pytest.raises(ValueError, match="'features.bigbird_objects' names 'nope'"):
        list(bigbird_jobs(cfg_with({"features": {"bigbird_objects": ["nope"]}}), bb, SkipPolicy(False), Bar()))
    scan = AVDScan(avd, chain.data.scans[0])
    jobs = list(avd_jobs(cfg_with({"features": {"avd_instances": [one], "max_difficulty": 3}}), scan, SkipPolicy(False), Bar()))
    assert {j.columns["instance"] for j in jobs} <= {one} and all(j.columns["difficulty"] <= 3 for j in jobs)
    with pytest.raises(ValueError, match="'features.avd_instances' names 'nope'"):
        list(avd_jobs(cfg_with({"features": {"avd_instances": ["nope"]}}), scan, SkipPolicy(False), Bar()))

"""The models stage on a tiny features Parquet the test writes (contract in docs/design.md §6)."""
import json

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from pipeline.method.components import choose_components
from pipeline.method.gp_files import load_bank
from pipeline.infra.config import ModelsConfig
from pipeline.banks.model_bank import FeaturesError, fit_from_features
from stages.framework.registry import STAGES
from stages.framework.runner import read_manifest, run_stage

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)

CLASSES = ["aunt_jemima_original_syrup", "cholula_chipotle_hot_sauce", "crystal_hot_sauce"]
D = 6
NAMES = [f"category_{i}" for i in range(D)]


def class_scores(c, theta):
    """Softmax scores over D outputs that vary smoothly with the viewing angle."""
    logits = np.zeros((len(theta), D))
    logits[:, 1] = 2.0 + np.sin(theta + c)
    logits[:, 4] = 1.5 + np.cos(theta - c)
    logits[:, 2] = 3.0 if c == 0 else -1.0           # high for one class only
    e = np.exp(logits)
    return e / e.sum(axis=1, keepdims=True)


def write_features(path, classes=CLASSES, n_angles=24, with_names=True, drop_column=None, shift=0.0,
                   dropout=True):
    """Camera 1 (the training views): the deterministic pass and two dropout passes whose mean is
    the deterministic score moved ``shift`` of the way to a rolled copy of it; plus camera-3 rows the stage
    must ignore, with scores that would change the component choice."""
    rows = {k: [] for k in ("object", "camera", "angle_deg", "image", "u_x", "u_y", "pass")}
    scores, truth = [], {}
    for c, obj in enumerate(classes):
        ang = np.arange(n_angles) * (360 // n_angles)
        th = np.radians(ang)
        s = class_scores(c, th)
        truth[obj] = (th, s)
        # Both perturbations sum to 0 over the components and keep every score in [0, 1], so each
        # pass is a probability vector like a real softmax pass (the reader checks that).
        r = np.roll(s, 1, axis=1) * s
        e, g = 0.25 * (r - s * r.sum(axis=1, keepdims=True)), shift * (np.roll(s, 2, axis=1) - s)
        passes = ((1, 0, s + e + g), (1, 1, s - e + g)) if dropout else ()
        for cam, pas, sc in ((1, -1, s), (3, -1, np.roll(s, 3, axis=1)), (3, 0, np.roll(s, 1, axis=1)), *passes):
            for a, t, v in zip(ang, th, sc):
                rows["object"].append(obj), rows["camera"].append(cam), rows["angle_deg"].append(int(a))
                rows["image"].append(f"{obj}/NP{cam}_{a}.jpg"), rows["pass"].append(pas)
                rows["u_x"].append(np.cos(t)), rows["u_y"].append(np.sin(t))
                scores.append(v)
    sc = np.asarray(scores, np.float32)
    cols = {
        "object": pa.array(rows["object"], pa.string()), "camera": pa.array(rows["camera"], pa.int32()),
        "angle_deg": pa.array(rows["angle_deg"], pa.int32()), "image": pa.array(rows["image"], pa.string()),
        "u_x": pa.array(rows["u_x"], pa.float64()), "u_y": pa.array(rows["u_y"], pa.float64()),
        "pass": pa.array(rows["pass"], pa.int16()),
        "scores": pa.FixedSizeListArray.from_arrays(pa.array(sc.ravel(), pa.float32()), D),
    }
    if drop_column:
        cols.pop(drop_column)
    meta = {"viewfuse.config_hash": "0" * 64, "viewfuse.seed": "0", "viewfuse.score_dim": str(D),
            "viewfuse.n_samples": "1"}
    if with_names:
        meta["viewfuse.output_names"] = json.dumps(NAMES)
    table = pa.table(cols).replace_schema_metadata(meta)
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, path)
    return truth


def mcfg(**kw):
    base = dict(classes=tuple(CLASSES), n_components=2, restarts=0, min_views=8)
    base.update(kw)
    return ModelsConfig(**base)


def test_stage_writes_models(tmp_config):
    cfg = tmp_config({"models": {"classes": CLASSES, "n_components": 2, "restarts": 1},
                      "evaluate": {"n_candidates": 3, "targets": [CLASSES[0]]}})
    feat = cfg.stage_dir("features")
    truth = write_features(feat / "bigbird.parquet")
    (feat / "manifest.json").write_text(json.dumps({"stage": "features", "key": "fake"}))
    run_stage(cfg, STAGES["models"], "k", {}, device="cpu", threads=1)
    out = cfg.stage_dir("models")
    index = json.loads((out / "index.json").read_text())
    # Component choice from the camera-1 views only (rule top_mean; dropout mean = deterministic here).
    expected = np.argsort(-np.concatenate([s for _, s in truth.values()]).mean(0), kind="stable")[:2]
    assert index["components"] == [int(i) for i in expected]
    assert index["component_names"] == [NAMES[i] for i in expected]
    assert index["component_choice"]["rule"] == "top_mean" and index["camera"] == 1
    assert index["candidate_sets"] == {CLASSES[0]: {
        "classes": sorted(CLASSES), "components": index["components"], "component_names": index["component_names"],
        "choice": index["component_choice"]}}
    for d in index["diagnostics"]:   # the training scores' spread is recorded per fit
        c, f = CLASSES.index(d["class"]), index["components"].index(d["component"])
        assert d["train_std"] == pytest.approx(float(truth[d["class"]][1][:, d["component"]].std()), rel=1e-5)
    assert index["features"]["rows_used"] == 3 * 24
    assert len(index["diagnostics"]) == 6
    for d in index["diagnostics"]:
        assert {"amplitude", "length_scale", "noise", "log_marginal_likelihood", "warnings", "at_bound"} <= set(d)
    assert sorted(p.name for p in out.glob("*.npz")) == sorted(f"{c}.npz" for c in CLASSES)
    with np.load(out / f"{CLASSES[1]}.npz", allow_pickle=False) as z:
        assert z["X"].shape == (24, 2) and z["Y"].shape == (2, 24)
        np.testing.assert_allclose(z["Y"], truth[CLASSES[1]][1][:, expected].T, atol=2e-6)  # float32 scores
    models = load_bank(out)
    assert models.classes == CLASSES
    # The fitted GP mean follows the training scores on the ring.
    th, s = truth[CLASSES[2]]
    mu, _ = models.marginal(np.c_[np.cos(th), np.sin(th)])
    assert np.abs(mu[:, 2, :] - s[:, expected]).max() < 0.05
    m = read_manifest(cfg, "models")
    assert "3 classes x 2 components" in m["summary"] and m["extra"]["classes"] == CLASSES


@pytest.mark.parametrize("rule", ["top_mean", "top_min", "explicit"])
def test_component_rules(tmp_path, rule):
    truth = write_features(tmp_path / "bigbird.parquet")
    per_class = np.stack([s.mean(0) for _, s in truth.values()])
    models, extra = fit_from_features(tmp_path / "bigbird.parquet",
                                      mcfg(component_rule=rule, components=(5, 0) if rule == "explicit" else ()),
                                      progress=False)
    if rule == "top_mean":
        key = np.concatenate([s for _, s in truth.values()]).mean(0)
    else:
        key = per_class.min(0)
    # candidates "all" (fit_from_features' default): N_f = max(n_components = 2, 3 candidates), the
    # paper's N_f = N_c; the explicit rule keeps the components it names
    expected = [5, 0] if rule == "explicit" else [int(i) for i in np.argsort(-key, kind="stable")[:3]]
    # The plan keeps the rule's rank order; the bank holds the components in index order.
    assert all(p["components"] == expected for p in extra["candidate_sets"].values())
    assert models.components == sorted(expected)
    assert extra["component_choice"]["rule"] == rule


def test_top_min_differs_from_top_mean():
    # One class scores component 0 very high, the others never: top_mean may take it, top_min not.
    a = np.array([[0.9, 0.05, 0.05]] * 3)
    b = np.array([[0.0, 0.5, 0.5]] * 3)
    assert choose_components([a, b], 1, "top_mean")[0] == [0]
    assert choose_components([a, b], 1, "top_min")[0] == [1]   # tie 1 vs 2 -> lower index
    with pytest.raises(ValueError, match="distinct"):
        choose_components([a, b], 2, "explicit", (1, 1))
    with pytest.raises(ValueError, match="between 1 and"):
        choose_components([a, b], 4, "top_mean")


def test_fit_is_deterministic(tmp_path):
    write_features(tmp_path / "bigbird.parquet")
    a, _ = fit_from_features(tmp_path / "bigbird.parquet", mcfg(restarts=2), progress=False)
    b, _ = fit_from_features(tmp_path / "bigbird.parquet", mcfg(restarts=2), progress=False)
    for k in ("mean", "amplitude", "length_scale", "noise"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k))


def test_the_stage_writes_the_same_bytes_for_one_and_two_fit_processes(tmp_config, monkeypatch):
    """run.threads sets the GP fit's processes (pipeline/method/gp_workers.py): the bank's files
    are the same bytes for 1 and 2."""
    import hashlib

    import pipeline.method.gp_workers as gw
    from pipeline.infra.budget import cores
    from pipeline.infra.workers import can_fork

    shared = []
    real = gw.SplitStack.evaluate
    monkeypatch.setattr(gw.SplitStack, "evaluate", lambda self, *a: shared.append(self.n) or real(self, *a))
    got = {}
    for threads in (1, 2):
        cfg = tmp_config({"run": {"name": f"t{threads}", "threads": threads},
                          "models": {"classes": CLASSES, "n_components": 2, "restarts": 2},
                          "evaluate": {"n_candidates": 3, "targets": [CLASSES[0]]}})
        feat = cfg.stage_dir("features")
        write_features(feat / "bigbird.parquet", n_angles=36)
        (feat / "manifest.json").write_text(json.dumps({"stage": "features", "key": "fake"}))
        run_stage(cfg, STAGES["models"], "k", {}, device="cpu", threads=threads)
        out = cfg.stage_dir("models")
        got[threads] = {p.relative_to(out).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
                        for p in sorted(out.rglob("*")) if p.is_file() and p.name != "manifest.json"}
    assert got[1] and got[1] == got[2]
    if can_fork() and cores() >= 2:
        assert set(shared) == {2}   # the second run's fits did go to two processes


def test_bad_features_are_clear_errors(tmp_path):
    p = tmp_path / "bigbird.parquet"
    with pytest.raises(FeaturesError, match="bigbird.parquet: features file not found"):
        fit_from_features(p, mcfg(), progress=False)
    write_features(p, classes=CLASSES[:2])
    with pytest.raises(FeaturesError, match="'crystal_hot_sauce'.*no training views"):
        fit_from_features(p, mcfg(), progress=False)
    write_features(p, n_angles=6)
    with pytest.raises(FeaturesError, match="6 training views, fewer than models.min_views"):
        fit_from_features(p, mcfg(), progress=False)
    write_features(p, drop_column="u_y")
    with pytest.raises(FeaturesError, match="missing column.*u_y"):
        fit_from_features(p, mcfg(), progress=False)
    p.write_bytes(b"not parquet")
    with pytest.raises(FeaturesError, match="not a readable Parquet"):
        fit_from_features(p, mcfg(), progress=False)
    # Without output names the models still fit; names are just absent.
    write_features(p, with_names=False)
    models, _ = fit_from_features(p, mcfg(), progress=False)
    assert models.component_names is None


def test_training_targets_are_the_dropout_mean_or_the_deterministic_pass(tmp_path):
    p = tmp_path / "bigbird.parquet"
    truth = write_features(p, shift=0.2)
    comps = (1, 4)
    kw = dict(component_rule="explicit", components=comps)
    mean_models, extra = fit_from_features(p, mcfg(**kw), progress=False)
    det_models, _ = fit_from_features(p, mcfg(targets="deterministic", **kw), progress=False)
    assert extra["fit"]["targets"] == "dropout_mean"
    for c, cls in enumerate(CLASSES):
        s = truth[cls][1]
        want_mean = (s + 0.2 * (np.roll(s, 2, axis=1) - s))[:, list(comps)].T
        np.testing.assert_allclose(mean_models.Y[c], want_mean, atol=2e-6)
        np.testing.assert_allclose(det_models.Y[c], s[:, list(comps)].T, atol=2e-6)
    assert not np.allclose(mean_models.Y[0], det_models.Y[0], atol=1e-3)
    write_features(p, dropout=False)
    with pytest.raises(FeaturesError, match="bigbird.parquet: models.targets = 'dropout_mean' needs MC-dropout passes"):
        fit_from_features(p, mcfg(**kw), progress=False)
    fit_from_features(p, mcfg(targets="deterministic", **kw), progress=False)  # no passes needed

"""Classifier: weights policy (synthetic / imagenet / path, offline), safe weight files, the stage."""
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from pipeline.scoring.alexnet import IMAGENET_FILE, build_alexnet, init_for_training
from pipeline.scoring.card import card_hash, load_classifier
from pipeline.scoring.training import lr_at
from pipeline.scoring.weight_files import WeightsError, WeightsNotFoundError, load_into, load_state_dict_file, save_state_dict_npz
from loaders.synthetic.source_domain import TRAIN_STREAM, VAL_STREAM, labels_for, render, render_set

pytestmark = pytest.mark.slow  # runs real stages (make test-fast skips it)

TINY_TRAIN = {"classifier": {"input_size": 64, "training": {
    "train_images": 48, "val_images": 24, "epochs": 1, "batch_size": 16, "min_accuracy": 0.0}}}


@pytest.fixture
def hub_dir(tmp_path, monkeypatch):
    """An empty torch hub cache; any download attempt fails the test."""
    d = tmp_path / "hub"
    monkeypatch.setattr(torch.hub, "_hub_dir", str(d))

    def no_download(*a, **k):  # pragma: no cover - only hit on a regression
        raise AssertionError("viewfuse tried to download weights")
    monkeypatch.setattr(torch.hub, "download_url_to_file", no_download)
    monkeypatch.setattr(torch.hub, "load_state_dict_from_url", no_download)
    return d


@pytest.fixture(scope="module")
def imagenet_like(tmp_path_factory):
    """A torch state-dict file with ImageNet's 1000 outputs (random weights), saved the usual way."""
    d = tmp_path_factory.mktemp("ckpt")
    m = build_alexnet(1000, 0.5)
    p = d / IMAGENET_FILE
    torch.save(m.state_dict(), p)
    return p, m.state_dict()


def test_imagenet_absent_is_a_clear_offline_error(tmp_config, hub_dir, capsys):
    from stages.commands.cli import main
    from stages.framework.runner import ensure

    cfg = tmp_config({"classifier": {"weights": "imagenet"}})
    with pytest.raises(WeightsNotFoundError) as e:
        ensure(cfg, "classifier", device="cpu")
    msg = str(e.value)
    assert IMAGENET_FILE in msg and str(hub_dir / "checkpoints") in msg and "Nothing is downloaded" in msg
    assert not cfg.stage_dir("classifier").exists()
    # Through the CLI: exit status 1 and the same message, no traceback.
    rc = main(["classifier", "--config", str(cfg.source_path), "--set", f"run.artifacts=\"{cfg.run_dir.parent}\"",
               "--set", "classifier.weights=\"imagenet\""])
    err = capsys.readouterr().err
    assert rc == 1 and IMAGENET_FILE in err and "Traceback" not in err


def test_imagenet_present_is_used_with_its_class_names(tmp_config, hub_dir, imagenet_like):
    from stages.framework.runner import ensure

    src, state = imagenet_like
    (hub_dir / "checkpoints").mkdir(parents=True)
    (hub_dir / "checkpoints" / IMAGENET_FILE).symlink_to(src)
    cfg = tmp_config({"classifier": {"weights": "imagenet", "input_size": 64}})
    ensure(cfg, "classifier", device="cpu")
    folder = cfg.stage_dir("classifier")
    card = json.loads((folder / "card.json").read_text())
    assert card["num_classes"] == 1000 and len(card["output_names"]) == 1000
    assert card["output_names"][0] == "tench"  # torchvision's offline ImageNet metadata
    assert card["hash"] == card_hash(card) and card["accuracy"] is None
    model, card2 = load_classifier(folder)
    assert card2 == card
    torch.testing.assert_close(model.state_dict()["classifier.6.weight"], state["classifier.6.weight"])


def test_path_weights_accept_torch_files_and_check_the_output_size(tmp_config, imagenet_like):
    from stages.framework.runner import ensure

    src, _ = imagenet_like
    cfg = tmp_config({"classifier": {"weights": "path", "path": str(src), "input_size": 64}})
    ensure(cfg, "classifier", device="cpu")
    card = json.loads((cfg.stage_dir("classifier") / "card.json").read_text())
    assert card["num_classes"] == 1000 and card["output_names"][:2] == ["class_0", "class_1"]
    bad = tmp_config({"run": {"name": "other"}, "classifier": {"weights": "path", "path": str(src), "num_classes": 5}})
    with pytest.raises(WeightsError, match="num_classes"):
        ensure(bad, "classifier", device="cpu")


class _Evil:
    def __reduce__(self):
        return (Path.touch, (Path(self.marker),))


def test_weight_files_never_run_code_and_mismatches_name_the_file(tmp_path):
    m = build_alexnet(7, 0.5)
    p1, p2 = tmp_path / "a.npz", tmp_path / "b.npz"
    sha1, sha2 = save_state_dict_npz(m, p1), save_state_dict_npz(m, p2)
    assert sha1 == sha2                      # reproducible bytes: a fixed hash for fixed weights
    with np.load(p1, allow_pickle=False) as z:
        assert "features.0.weight" in z.files
    state = load_state_dict_file(p1)
    for k, v in m.state_dict().items():
        torch.testing.assert_close(state[k], v)
    # A pickle that would run code on load is refused by the safe loader.
    evil = _Evil()
    evil.marker = str(tmp_path / "pwned")
    torch.save({"weights": evil}, tmp_path / "evil.pth")
    with pytest.raises(WeightsError, match="evil.pth"):
        load_state_dict_file(tmp_path / "evil.pth")
    assert not (tmp_path / "pwned").exists()
    # Architecture mismatches name the file and the keys.
    del state["classifier.4.bias"]
    with pytest.raises(WeightsError, match=r"a\.npz.*missing keys \['classifier.4.bias'\]"):
        load_into(build_alexnet(7, 0.5), state, p1)
    with pytest.raises(WeightsError, match="shape mismatch"):
        load_into(build_alexnet(9, 0.5), load_state_dict_file(p1), p1)
    with pytest.raises(WeightsNotFoundError):
        load_state_dict_file(tmp_path / "nope.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(WeightsError, match="junk.npz"):
        load_state_dict_file(tmp_path / "junk.npz")


def test_synthetic_stage_trains_caches_and_enforces_min_accuracy(tmp_config):
    from loaders.synthetic.textures import CATEGORY_NAMES
    from pipeline.infra.cache import sha256_file
    from stages.framework.runner import ensure, read_manifest

    cfg = tmp_config(TINY_TRAIN)
    ensure(cfg, "classifier", device="cpu")
    folder = cfg.stage_dir("classifier")
    card = json.loads((folder / "card.json").read_text())
    assert card["weights_sha256"] == sha256_file(folder / "weights.npz")
    assert card["output_names"] == list(CATEGORY_NAMES) and card["num_classes"] == 12
    assert 0.0 <= card["accuracy"] <= 1.0 and np.array(card["confusion"]).sum() == 24
    lo, hi = card["accuracy_ci95"]  # Wilson interval over the 24 held-out images
    assert 0.0 <= lo <= card["accuracy"] <= hi <= 1.0 and hi - lo > 0.1
    assert card["training"]["train_images"] == 48 and card["hash"] == card_hash(card)
    assert set(card["timings"]) >= {"render_s", "train_s"} and set(card["cpu_seconds"]) >= {"render_s", "train_s"}
    det = card["determinism"]
    assert set(det["versions"]) >= {"torch", "torchvision", "numpy"} and det["versions"]["numpy"] == np.__version__
    assert isinstance(det["cpu_flags"], list) and "machine" in det["cross_machine"].lower()
    summary = read_manifest(cfg, "classifier")["summary"]
    assert "render" in summary and "train" in summary and "top-1" in summary
    model, _ = load_classifier(folder)
    assert model(torch.zeros(2, 3, 64, 64)).shape == (2, 12)
    assert read_manifest(cfg, "classifier")["extra"]["accuracy"] == card["accuracy"]
    # Below min_accuracy the stage fails with the number and the key, and leaves no new output.
    strict = tmp_config({**TINY_TRAIN, "run": {"name": "strict"},
                         "classifier": {**TINY_TRAIN["classifier"],
                                        "training": {**TINY_TRAIN["classifier"]["training"], "min_accuracy": 1.0}}})
    with pytest.raises(RuntimeError, match=r"below 'classifier.training.min_accuracy' = 1.0"):
        ensure(strict, "classifier", device="cpu")
    assert not strict.stage_dir("classifier").exists()


def test_source_domain_is_deterministic_balanced_and_streams_differ():
    a, ya = render_set(24, 48, 12, seed=5, stream=TRAIN_STREAM)
    b, yb = render_set(24, 48, 12, seed=5, stream=TRAIN_STREAM)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(ya, yb)
    assert a.dtype == np.uint8 and a.shape == (24, 48, 48, 3)
    assert np.bincount(ya, minlength=12).tolist() == [2] * 12
    # A subset starting later is the same images (generated per index, not per call).
    c, yc = render_set(4, 48, 12, seed=5, stream=TRAIN_STREAM, start=20)
    np.testing.assert_array_equal(c, a[20:])
    v, _ = render_set(24, 48, 12, seed=5, stream=VAL_STREAM)
    assert not any(np.array_equal(v[i], a[j]) for i in range(24) for j in range(24))
    assert not np.array_equal(labels_for(24, 12, 5, TRAIN_STREAM), labels_for(24, 12, 6, TRAIN_STREAM))
    with pytest.raises(ValueError, match="category"):
        render(12, np.random.default_rng(0), 32)


def test_parallel_rendering_gives_the_same_images_as_serial():
    from loaders.synthetic.source_domain import render_set_parallel

    a, ya = render_set(30, 40, 12, seed=2, stream=TRAIN_STREAM)
    b, yb = render_set_parallel(30, 40, 12, seed=2, stream=TRAIN_STREAM, workers=2, chunk=8)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(ya, yb)


def test_same_seed_same_machine_gives_byte_identical_weights():
    from pipeline.scoring.training import train_classifier

    x, y = render_set(24, 64, 12, seed=1, stream=TRAIN_STREAM)
    states = []
    for _ in range(2):
        m = init_for_training(build_alexnet(12, 0.5), 3)
        train_classifier(m, x, y, epochs=1, batch_size=12, lr=1e-4, weight_decay=0.0, warmup_steps=1, seed=3,
                         mean=(0.5, 0.5, 0.5), std=(0.25, 0.25, 0.25), precision="auto", progress=False)
        states.append({k: v.detach().clone() for k, v in m.state_dict().items()})
    assert all(torch.equal(states[0][k], states[1][k]) for k in states[0])


def test_lr_schedule_warms_up_then_decays_to_zero():
    lrs = [lr_at(s, 100, 1.0, 10) for s in range(100)]
    assert lrs[0] == pytest.approx(0.1) and lrs[9] == pytest.approx(1.0)
    assert all(x >= y for x, y in zip(lrs[9:], lrs[10:])) and lrs[-1] < 1e-3


def test_init_gives_live_activations():
    """He init keeps the signal alive through AlexNet (torch's default init nearly kills it)."""
    x = torch.randn(8, 3, 64, 64)
    torch.manual_seed(0)
    default = build_alexnet(12, 0.0).eval()
    he = init_for_training(build_alexnet(12, 0.0), 0).eval()
    with torch.no_grad():
        f_def = torch.flatten(default.avgpool(default.features(x)), 1).std()
        f_he = torch.flatten(he.avgpool(he.features(x)), 1).std()
    assert f_he > 5 * f_def

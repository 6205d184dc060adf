"""The classifier registry: a classifier registered from here (no product code edited) is built,
loaded and scored like the built-in ones; ``torchvision:<model>`` runs any torchvision
classification network from a pickle-free weights file with its MC-dropout site declared."""
import copy
import json

import numpy as np
import pytest
import torch
from torch import nn

from pipeline.infra.config import ConfigError, load_config, merge
from pipeline.scoring.classifiers import (Classifier, UnknownClassifier, check_config, classifier, names,
                                          register_classifier)
from pipeline.scoring.mc_dropout import MCDropoutScorer, crop_seed
from pipeline.scoring.weight_files import save_state_dict_npz
from tests.support.float_tolerance import rounding_tol


class ToyNet(nn.Module):
    """A two-layer network declaring its MC-dropout site: trunk once, (Dropout, Linear) head."""

    def __init__(self, num_classes: int, dropout: float):
        super().__init__()
        self.conv = nn.Conv2d(3, 6, 5, stride=4)
        self.pool = nn.AdaptiveAvgPool2d(1)
        self.drop = nn.Dropout(dropout)
        self.out = nn.Linear(6, num_classes)

    def trunk(self, x):
        return torch.flatten(self.pool(torch.relu(self.conv(x))), 1)

    def head_layers(self):
        return [self.drop, self.out]

    def forward(self, x):
        return self.out(self.drop(self.trunk(x)))


@register_classifier
class Toy(Classifier):
    name = "toy_from_tests"
    display = "the tests' toy network"
    architecture = "tests.toy"

    def build(self, num_classes, dropout, drop_connect=0.0):
        return ToyNet(num_classes, dropout)

    def last_linear_key(self):
        return "out.weight"


def test_registered_names_resolve_and_unknown_ones_are_named():
    assert {"alexnet", "efficientnet_lite0", "toy_from_tests", "torchvision:<model>"} <= set(names())
    assert classifier("toy_from_tests").display == "the tests' toy network"
    with pytest.raises(UnknownClassifier, match="unknown classifier architecture 'nope'.*alexnet"):
        classifier("nope")
    with pytest.raises(UnknownClassifier, match="no classification model 'resnet_unknown'"):
        classifier("torchvision:resnet_unknown")
    with pytest.raises(ValueError, match="already registered"):
        register_classifier(type("Other", (Toy,), {"name": "toy_from_tests"}))


def _cfg(tmp_path, classifier_section: dict):
    from tests.conftest import DEFAULT_CONFIG

    return load_config(DEFAULT_CONFIG, merge({"classifier": classifier_section,
                                              "run": {"artifacts": str(tmp_path / "artifacts")}}, {}))


def test_a_classifier_that_trains_nothing_is_refused_synthetic_weights(tmp_path):
    c = _cfg(tmp_path, {"arch": "toy_from_tests"}).classifier
    with pytest.raises(ConfigError, match="'toy_from_tests' trains nothing: set 'classifier.weights' = 'path'"):
        check_config(c, "c.toml")
    with pytest.raises(ConfigError, match="no local ImageNet weights"):
        check_config(_cfg(tmp_path, {"arch": "torchvision:resnet18", "weights": "imagenet"}).classifier, "c.toml")


def _stage_card(tmp_path, arch: str, net: nn.Module, size: int = 64):
    """The classifier stage on a weights file written here; returns (cfg, card, npz path)."""
    from stages.framework.runner import ensure

    npz = tmp_path / "weights.npz"
    sha = save_state_dict_npz(net, npz)
    cfg = _cfg(tmp_path, {"arch": arch, "weights": "path", "path": str(npz), "input_size": size})
    check_config(cfg.classifier, "c.toml")
    ensure(cfg, "classifier", device="cpu")
    card = json.loads((cfg.stage_dir("classifier") / "card.json").read_text())
    assert card["weights_sha256"] == sha and card["arch"] == arch
    return cfg, card


def _literal_samples(net: nn.Module, head_input: torch.Tensor, last: nn.Linear, mask: torch.Tensor) -> torch.Tensor:
    """N_s passes of the last layer on the masked head input: the literal MC-dropout definition."""
    return torch.softmax(last(head_input[:, None, :] * mask), -1)


def test_a_toy_classifier_registered_in_tests_is_carded_loaded_and_scored(tmp_path):
    from pipeline.scoring.card import load_classifier

    torch.manual_seed(0)
    net = ToyNet(4, 0.5)
    cfg, card = _stage_card(tmp_path, "toy_from_tests", net)
    assert card["num_classes"] == 4 and card["dropout"] == 0.5 and card["architecture"] == "tests.toy"
    model, _ = load_classifier(cfg.stage_dir("classifier"))
    x = torch.rand(3, 3, 64, 64, generator=torch.Generator().manual_seed(1))
    sc = MCDropoutScorer(model, onednn=False)
    seeds = [crop_seed(0, f"c{i}") for i in range(3)]
    det, mc = sc.score(x, seeds, 5)
    with torch.no_grad():
        plain, n64, x64 = torch.softmax(net.eval()(x), -1), copy.deepcopy(net).double().eval(), x.double()
        ref = _literal_samples(net, net.trunk(x), net.out, sc.draw_masks(seeds, 5)[0])
        ref64 = _literal_samples(n64, n64.trunk(x64), n64.out, sc.draw_masks(seeds, 5)[0].double())
        det64 = torch.softmax(n64(x64), -1)
    # float32 rounding of the literal routes, read off their float64 evaluation (tests/support/float_tolerance.py)
    torch.testing.assert_close(det, plain, rtol=0, atol=rounding_tol(plain, det64))
    torch.testing.assert_close(mc, ref, rtol=0, atol=rounding_tol(ref, ref64))
    assert (mc - det[:, None]).abs().amax() > 1e-4


def test_torchvision_resnet18_from_an_npz_is_scored_with_a_declared_dropout_site(tmp_path):
    from pipeline.scoring.card import load_classifier
    from pipeline.scoring.crops import CropPolicy
    from pipeline.scoring.features import CropBatch, ScoringModel, score_batch

    entry = classifier("torchvision:resnet18")
    torch.manual_seed(0)
    # random-init weights under torchvision's own state-dict keys (no Dropout: resnet has none)
    from torchvision.models import resnet18

    ref = resnet18(weights=None, num_classes=5).eval()
    assert entry.last_linear_key() == "fc.weight"
    cfg, card = _stage_card(tmp_path, "torchvision:resnet18", ref)
    assert card["num_classes"] == 5 and card["dropout"] == 0.5 and "inserted" in card["mc_dropout_site"]
    model, card = load_classifier(cfg.stage_dir("classifier"))
    head = model.head_layers()
    assert [type(m).__name__ for m in head] == ["Dropout", "Linear"] and head[1] is model.fc
    x = torch.rand(2, 3, 64, 64, generator=torch.Generator().manual_seed(2))
    with torch.no_grad():
        feats = torch.flatten(ref.avgpool(ref.layer4(ref.layer3(ref.layer2(ref.layer1(
            ref.maxpool(ref.relu(ref.bn1(ref.conv1(x))))))))), 1)
        # the same layers on the same weights and input in one process (the trunk runs the network up to
        # its head): one computation twice, so a fixed bound far above rounding cannot tip
        torch.testing.assert_close(model.trunk(x), feats, rtol=0, atol=1e-5)
    # the features stage's task: crops in, deterministic scores and N_s dropout samples out
    policy = CropPolicy(size=64, mean=tuple(cfg.classifier.mean), std=tuple(cfg.classifier.std))
    sm = ScoringModel.from_model(model, card, policy, "cpu", with_weights=True)
    crops = (np.random.default_rng(0).random((2, 64, 64, 3)) * 255).astype(np.uint8)
    seeds = [crop_seed(0, "a"), crop_seed(0, "b")]
    det, mc = score_batch(sm, CropBatch(what="avd", start=0, crops=crops, seeds=seeds, n_samples=6))
    assert det.shape == (2, 5) and mc.shape == (2, 6, 5)
    np.testing.assert_allclose(det.sum(1), 1.0, atol=1e-5)
    np.testing.assert_allclose(mc.sum(2), 1.0, atol=1e-5)
    assert np.abs(mc - det[:, None]).max() > 1e-4  # the inserted Dropout samples
    # the same weights as a tensor-only torch file load the same way (the safe loader)
    pt = tmp_path / "w.pt"
    torch.save(ref.state_dict(), pt)
    from pipeline.scoring.weight_files import load_into, load_state_dict_file

    again = load_into(entry.build(5, 0.5), load_state_dict_file(pt), pt, entry.display).eval()
    torch.testing.assert_close(again(x), ref(x), rtol=0, atol=1e-6)   # the same weights, one computation twice


def test_a_head_mc_dropout_cannot_serve_is_refused_with_the_layer_named():
    with pytest.raises(ValueError, match="head 'classifier' holds.*LayerNorm2d"):
        classifier("torchvision:convnext_tiny").build(3, 0.5)


def test_a_head_with_its_own_dropout_keeps_it_at_the_configured_p():
    net = classifier("torchvision:mobilenet_v3_small").build(3, 0.3)
    drops = [m for m in net.head_layers() if isinstance(m, nn.Dropout)]
    assert len(drops) == 1 and drops[0].p == 0.3 and drops[0] is net.classifier[2]


def test_an_entry_declares_its_card_fields_and_training_footprint(tmp_path):
    """A classifier's own card keys reach the card hash (the features stage's key) only when its
    class declares them; its training footprint is what it declares, not AlexNet's."""
    from pipeline.infra import footprints
    from pipeline.scoring.card import card_hash
    from pipeline.scoring.classifiers import unregister_classifier

    @register_classifier
    class Knobbed(Toy):
        name = "knobbed_from_tests"
        card_fields = ("knob",)
        params, activations_224 = 1e6, 2e6

    try:
        card = {"arch": "knobbed_from_tests", "architecture": "tests.knobbed", "weights_sha256": "0", "num_classes": 3}
        assert card_hash({**card, "knob": 1}) != card_hash({**card, "knob": 2})
        toy = {**card, "arch": "toy_from_tests"}
        assert card_hash({**toy, "knob": 1}) == card_hash({**toy, "knob": 2})   # not the toy's field
        c = _cfg(tmp_path, {}).classifier
        small = footprints.classifier_training(c, Knobbed.params, Knobbed.activations_224)
        assert small < footprints.classifier_training(c) == footprints.classifier_training(
            c, classifier("alexnet").params, classifier("alexnet").activations_224)
    finally:
        unregister_classifier("knobbed_from_tests")

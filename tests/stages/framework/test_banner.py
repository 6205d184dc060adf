"""The data and classifier stages' "running" line names the registered source or classifier the
config names (its label), never the built-in's words for an outside one."""
from __future__ import annotations

from types import SimpleNamespace as N

import viewfuse as vf
from stages.framework.outside import banner


class Photos(vf.TurntableSource):
    key = "banner_photos"
    label = "my turntable photographs"

    def read(self, cfg, skips):
        return {}


class Net(vf.Classifier):
    key = "banner_net"
    label = "a network of my own"
    trains = True

    def build(self, num_classes, dropout, drop_connect=0.0):
        raise NotImplementedError

    def last_linear_key(self):
        return "fc.weight"

    def for_training(self, num_classes, dropout, seed):
        raise NotImplementedError


def test_the_banner_names_the_registered_source_and_classifier():
    vf.register(Photos)
    vf.register(Net)
    try:
        data = banner(N(data=N(source="banner_photos")), "data", "help")
        assert "banner_photos" in data and "my turntable photographs" in data and "BigBIRD" not in data
        cls = banner(N(classifier=N(arch="banner_net", weights="synthetic")), "classifier", "help")
        assert cls == "train a network of my own on the synthetic source domain"
        assert "AlexNet" in banner(N(classifier=N(arch="alexnet", weights="synthetic")), "classifier", "help")
        assert banner(N(), "models", "help") == "help"
    finally:
        vf.unregister_dataset("banner_photos")
        vf.unregister_classifier("banner_net")


def test_the_data_banner_reads_the_configs_backgrounds():
    """The running line said "COIL-100's own black on both sides" (the words for a run from before the
    background keys) for every real_imagery config, clutter included: it was given an empty data table."""
    from pathlib import Path

    from pipeline.infra.config.load import load_config

    configs = Path(__file__).resolve().parents[3] / "configs"
    clutter = banner(load_config(configs / "real.toml"), "data", "help")
    assert "real AVD clutter" in clutter and "own black" not in clutter
    black = banner(load_config(configs / "real_black.toml"), "data", "help")
    assert "cut out onto black" in black and "clutter" not in black

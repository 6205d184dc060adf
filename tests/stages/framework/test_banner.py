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

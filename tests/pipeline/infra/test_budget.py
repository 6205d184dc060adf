"""The memory budget: run.memory_gb (0 = from the machine), refusals naming key, estimate and
budget, and worker / batch caps."""
from __future__ import annotations

import dataclasses
import logging

import pytest

from pipeline.infra import budget as B
from pipeline.infra import footprints
from pipeline.infra.config import Config, ConfigError


def cfg_with(memory_gb: float) -> Config:
    c = Config()
    return dataclasses.replace(c, run=dataclasses.replace(c.run, memory_gb=memory_gb))


def test_budget_is_the_setting_or_a_share_of_the_machine():
    assert B.budget(cfg_with(2.5)) == int(2.5 * B.GIB)
    auto = B.budget(cfg_with(0))
    assert auto == int(B.AUTO_SHARE * B.machine_memory())
    assert 0 < B.machine_memory() <= __import__("psutil").virtual_memory().total


def test_a_refusal_names_the_key_the_estimate_and_the_budget():
    with pytest.raises(ConfigError) as e:
        B.require("classifier.training.train_images", 10_000_000, 350 * B.GIB, B.GIB, "the training set")
    msg = str(e.value)
    assert "'classifier.training.train_images' = 10000000" in msg
    assert "350 GiB" in msg and "1.00 GiB" in msg and "run.memory_gb" in msg
    B.require("k", 1, B.GIB, B.GIB, "fits exactly")  # no error at the budget


def test_workers_are_capped_by_cores_and_by_memory(caplog):
    with caplog.at_level(logging.WARNING, "viewfuse"):
        assert B.cap_workers("data.synthetic.workers", 64, 1e6, 100 * B.GIB) == min(64, B.cores())
    assert "data.synthetic.workers = 64 capped" in caplog.text
    # 1 GiB left beside a 0.5 GiB parent, 0.2 GiB each: two workers (when the cores allow)
    assert B.cap_workers("w", 64, 0.2 * B.GIB, B.GIB, parent=0.5 * B.GIB) == min(2, B.cores())
    assert B.cap_workers("w", 64, 10 * B.GIB, B.GIB) == 1  # never below one
    assert B.cap_workers("w", 1, 1e6, 100 * B.GIB) == 1


def test_batches_are_capped_to_their_share():
    assert B.cap_batch("simulate.chunk", 100_000, 1e6, 1e8) == 100
    assert B.cap_batch("simulate.chunk", 25, 1e6, 1e9) == 25
    assert B.cap_batch("simulate.chunk", 25, 1e12, 1e9) == 1


def test_the_training_estimate_grows_with_the_images():
    c = Config().classifier
    base = footprints.classifier_training(c)
    big = dataclasses.replace(c, training=dataclasses.replace(c.training, train_images=10_000_000))
    est = footprints.classifier_training(big)
    # 10^7 uint8 images of 112 x 112 x 3 are 350 GiB on their own
    assert 350 * B.GIB < est < 360 * B.GIB and base < 3 * B.GIB

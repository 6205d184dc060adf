"""``[evaluate.statistics]``: the clustering each config declares, and the keys that conflict."""
from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.infra.config import ConfigError, load_config
from pipeline.infra.config.evaluation import cluster_of

REPO = Path(__file__).resolve().parents[4]


@pytest.mark.parametrize("name, cluster", [("synthetic.toml", "target"), ("real.toml", "target"),
                                           ("real_full.toml", "crossed"), ("real_category.toml", "category")])
def test_each_config_declares_its_design_unit(name, cluster):
    assert cluster_of(load_config(REPO / "configs" / name).evaluate) == cluster


def test_the_former_key_still_means_scans_and_conflicts_with_another_cluster():
    default = REPO / "configs" / "synthetic.toml"
    assert cluster_of(load_config(default, {"evaluate": {"resample_scans": True}}).evaluate) == "scan"
    with pytest.raises(ConfigError, match="evaluate.resample_scans.*evaluate.statistics.cluster"):
        load_config(default, {"evaluate": {"resample_scans": True, "statistics": {"cluster": "crossed"}}})
    with pytest.raises(ConfigError, match="'evaluate.statistics.cluster' = 'category' needs category targets"):
        load_config(default, {"evaluate": {"statistics": {"cluster": "category"}}})
    with pytest.raises(ConfigError, match="cluster"):
        load_config(default, {"evaluate": {"statistics": {"cluster": "objects"}}})

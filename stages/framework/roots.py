"""Where a run reads its datasets: the data stage's own folders for synthetic data, the configured
roots for real data. Every stage that reads the datasets asks here (no stage imports another)."""
from __future__ import annotations

from pathlib import Path

from pipeline.infra.datasets import dataset_source
from pipeline.infra.outputs import name as out_name


def data_roots(cfg) -> tuple[Path, Path]:
    """(BigBIRD root, AVD root): the stage's subfolders for a source that writes them, the config
    paths for one read in place (``real``)."""
    if not dataset_source(cfg.data.source).writes:
        return cfg.path("data.bigbird_root"), cfg.path("data.avd_root")
    d = cfg.stage_dir("data")
    return d / out_name("data", "bigbird"), d / out_name("data", "avd")

"""The dataset sources' registry (pipeline/infra/datasets.py): registered before the built-ins
loaded, a source still lists after them; a name twice is refused; config validation and
``data_roots`` ask the registry; and any first import (the data stage, the config, the API) works."""
from __future__ import annotations

import pytest

from tests.conftest import ROOT
from tests.support.outside_package import run_with


def test_a_source_registered_first_lists_after_the_builtins_and_is_refused_twice(tmp_path):
    code = ("import viewfuse as vf\n"
            "class Mine(vf.DatasetSource):\n    name = 'mine'\n    writes = False\n"
            "vf.register_dataset(Mine)\n"
            "print(vf.datasets())\n"
            "try:\n    vf.register_dataset(type('Other', (vf.DatasetSource,), {'name': 'mine'}))\n"
            "except ValueError as e:\n    print('twice:', e)\n"
            "vf.unregister_dataset('mine'); print(vf.datasets())\n")
    r = run_with(None, code, tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    lines = r.stdout.splitlines()
    assert lines[0] == "['real', 'real_imagery', 'synthetic', 'mine']"
    assert lines[1].startswith("twice: dataset source 'mine' is registered twice")
    assert lines[2] == "['real', 'real_imagery', 'synthetic']"


@pytest.mark.parametrize("first", ["stages.data", "pipeline.infra.datasets", "loaders.sources.synthetic",
                                   "loaders.real_imagery.turntable", "viewfuse"])
def test_any_first_import_loads_the_config(tmp_path, first):
    r = run_with(None, f"import {first}\nfrom pipeline.infra.config import load_config\n"
                       f"print(load_config({str(ROOT / 'configs' / 'real.toml')!r}).data.source)", tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == "real_imagery"


def test_a_source_that_reads_in_place_gives_its_roots_to_the_stages(tmp_config):
    import dataclasses

    from pipeline.infra.datasets import DatasetSource, register_dataset, unregister_dataset
    from stages.framework.roots import data_roots

    class InPlace(DatasetSource):
        name = "in_place_test"
        writes = False

    register_dataset(InPlace)
    try:
        cfg = tmp_config({"data": {"bigbird_root": "/x/bb", "avd_root": "/x/avd"}})
        assert data_roots(cfg)[0] == cfg.stage_dir("data") / "bigbird"          # synthetic writes its own
        cfg = dataclasses.replace(cfg, data=dataclasses.replace(cfg.data, source="in_place_test"))
        assert [str(p) for p in data_roots(cfg)] == ["/x/bb", "/x/avd"]
    finally:
        unregister_dataset("in_place_test")

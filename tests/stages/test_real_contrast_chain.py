"""The class-level contrast through the whole chain in ONE run (configs/real_contrast.toml, small: 3
categories x 3 instance folds on one real AVD scan): the models stage fits the instance arm's bank
on the same features (each class on its own instance's training azimuths), evaluate runs both
arms on the same tracks and draws, and the report's section pairs them. Skips where
../shared/realdata is absent."""
from __future__ import annotations

import json

import pyarrow.parquet as pq
import pytest

from tests.stages.test_real_category_chain import _fold, small_chain

pytestmark = pytest.mark.slow  # real stages on real data (make test-fast skips it)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return small_chain(tmp_path_factory, "real_contrast.toml", {"evaluate": {"attribution": False}})


def test_the_instance_arm_is_fitted_on_each_target_instance_alone(run):
    models = run.stage_dir("models")
    cat = json.loads((models / "index.json").read_text())
    ins = json.loads((models / "contrast" / "index.json").read_text())
    assert set(cat["training_angles_deg"]) == set(ins["training_angles_deg"]) and len(ins["training_angles_deg"]) == 9
    for cls, codes in ins["training_angles_deg"].items():
        assert {c // 360 for c in codes} == {_fold(cls)} and len(codes) == 8         # its own even azimuths
        assert {c % 360 for c in codes} == {0, 45, 90, 135, 180, 225, 270, 315}
        assert {c // 360 for c in cat["training_angles_deg"][cls]} == {1, 2, 3} - {_fold(cls)}
    assert {t: p["classes"] for t, p in cat["candidate_sets"].items()} == \
        {t: p["classes"] for t, p in ins["candidate_sets"].items()}
    assert (models / "contrast" / "dirichlet" / "index.json").is_file()


def test_both_arms_run_on_the_same_cells_and_the_report_pairs_them(run):
    from pipeline.evaluation.grid.contrast import ARM

    ev = run.stage_dir("evaluate")
    df = pq.read_table(ev / "results.parquet").to_pandas()
    keys = ["target", "track", "scan", "setting", "method", "realization", "step"]
    keys = [k for k in keys if k in df]
    a = df[df["variant"] == "default"].set_index(keys).sort_index()
    b = df[df["variant"] == ARM].set_index(keys).sort_index()
    assert len(b) and set(b.index) <= set(a.index)
    pop = json.loads((ev / "summary.json").read_text())["population"]
    block = pop["contrast"]
    assert block["cluster"] == "category" and block["over"] == ["categories", "targets", "tracks"]
    prim = [r for r in block["rows"] if r["primary"]]
    assert {r["metric"] for r in prim} == set(pop["primary_metrics"])
    for r in prim:
        d = r["difference"]
        # a few categories on one scan: under the engine's 8 units, so no CI, no verdict, the reason,
        # and no place in a Holm family
        assert d["outcome"] == "withheld" and d["withheld"] and "outcome_holm" not in d
        assert d["value"] == pytest.approx(r["instance"]["value"] - r["category"]["value"], abs=1e-9)
    html = (run.stage_dir("report") / "index.html").read_text()
    assert "Instance vs category class models" in html and "instance − category" in html

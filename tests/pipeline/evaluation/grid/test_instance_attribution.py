"""The instance term's attribution block (``ablations.instance_term``: each method with the term
against itself without it) and the per-category breakdown (``by_category``), on a category
population generated here where the term helps one category only."""
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from pipeline.evaluation.grid.population_calibration import INSTANCE_KEY, categories, population_blocks
from pipeline.evaluation.metrics.labels import comparison_key
from pipeline.evaluation.statistics.pooled_calibration import cell_sums
from pipeline.infra.config import EvaluateConfig
from pipeline.method.names import MB_INSTANCE, MODEL_BASED, SIMPLE_BAYES, WITH_UNCERTAINTY, WU_INSTANCE

METHODS = (WITH_UNCERTAINTY, MODEL_BASED, SIMPLE_BAYES, WU_INSTANCE, MB_INSTANCE)
GAIN = 0.1    # what the term adds to the correct ratio, in category cat0 only


def _population(rng, methods=METHODS, cats=4, per_cat=3, tracks=2, name="cat{c}__f{t}", variant="default"):
    rows, cells, results = [], [], []
    for c in range(cats):
        for t in range(per_cat):
            target = name.format(c=c, t=t)
            for j in range(tracks):
                base = rng.uniform(0.3, 0.7)
                values = {m: base for m in methods}
                for m in (WU_INSTANCE, MB_INSTANCE):
                    if m in values and c == 0:
                        values[m] = base + GAIN
                for m, v in values.items():
                    rows.append({"variant": variant, "method": m, "target": target, "track": j, "setting": "x",
                                 "correct_final": v, "confident_error_final": 1.0 - v})
                # posteriors of 3 realizations x 2 steps x 3 classes, for the pooled ECE
                posts = {("randomized", "x"): {m: np.log(rng.dirichlet(np.ones(3), size=(3, 2))) for m in methods}}
                cells.append(SimpleNamespace(variant=variant, target=target, track=j, truth=0))
                results.append({"calibration": cell_sums(posts, 0, 10)})
    return pd.DataFrame(rows), cells, results


def _blocks(table, cells, results, ablations=()):
    cfg = SimpleNamespace(evaluate=EvaluateConfig(bootstrap=200, ablations=tuple(ablations)))
    return population_blocks(cfg, table, cells, results, "", "default")


def test_the_instance_block_pairs_each_method_with_itself_without_the_term():
    out = _blocks(*_population(np.random.default_rng(0)))
    block = out["ablations"][INSTANCE_KEY]
    assert block["kind"] == "attribution" and set(block["methods"]) == set(METHODS)
    for a, b in ((MB_INSTANCE, MODEL_BASED), (WU_INSTANCE, WITH_UNCERTAINTY)):
        d = block["paired"][comparison_key(a, b)]["correct_final"]
        # one category of four gains GAIN in every cell: the mean over the 12 targets
        assert d["value"] == pytest.approx(GAIN / 4, abs=1e-12)
        assert d["ci_low"] <= d["value"] <= d["ci_high"]
        assert "ece_final" in block["paired"][comparison_key(a, b)]
    d = block["paired"][comparison_key(WU_INSTANCE, MB_INSTANCE)]["correct_final"]
    assert d["value"] == pytest.approx(0.0, abs=1e-12)
    # the attribution, then the goal: With Uncertainty + instance against every baseline
    assert {r["comparison"] for r in block["records"]} == {comparison_key(*c) for c in (
        (MB_INSTANCE, MODEL_BASED), (WU_INSTANCE, WITH_UNCERTAINTY), (WU_INSTANCE, MB_INSTANCE),
        (WU_INSTANCE, MODEL_BASED), (WU_INSTANCE, SIMPLE_BAYES))}
    goal = block["paired"][comparison_key(WU_INSTANCE, SIMPLE_BAYES)]["confident_error_final"]
    assert goal["value"] == pytest.approx(-GAIN / 4, abs=1e-12)
    # exploratory: outside the primary family, so no Holm fields
    assert not any("p_holm" in r for r in block["records"])
    # the main block's comparisons are untouched: the reference against every other method
    assert comparison_key(MB_INSTANCE, MODEL_BASED) not in out["main"]["paired"]
    # the final posterior's calibration covers the instance methods: pooled ECE and reliability counts
    for m in (WU_INSTANCE, MB_INSTANCE):
        ece = out["main"]["pooled"][m]["ece_final"]
        assert ece["ci_low"] <= ece["value"] <= ece["ci_high"] and m in out["main"]["reliability"]


def test_the_per_category_breakdown_says_where_the_term_helps():
    out = _blocks(*_population(np.random.default_rng(1)))
    by = out["by_category"]
    assert sorted(by) == ["cat0", "cat1", "cat2", "cat3"]
    assert by["cat0"]["targets"] == ["cat0__f0", "cat0__f1", "cat0__f2"]
    key = comparison_key(MB_INSTANCE, MODEL_BASED)
    for cat, want in (("cat0", GAIN), ("cat1", 0.0), ("cat3", 0.0)):
        d = by[cat]["paired"][key]["correct_final"]
        assert d["value"] == pytest.approx(want, abs=1e-12)
        assert d["cluster"] == "target" and d["n"]["targets"] == 3
    p = by["cat2"]["pooled"][SIMPLE_BAYES]["confident_error_final"]
    # three targets a category: too few for a calibrated interval, so none (and the reason), never a narrow one
    assert np.isnan(p["ci_low"]) and p["withheld"].startswith("3 targets") and p["over"] == ["targets", "tracks"]
    # the primary comparisons per category too (the goal is stated against every baseline)
    assert comparison_key(WITH_UNCERTAINTY, SIMPLE_BAYES) in by["cat1"]["paired"]


def test_no_instance_methods_no_block_and_no_categories_no_breakdown():
    out = _blocks(*_population(np.random.default_rng(2), methods=METHODS[:3], name="obj{c}_{t}"))
    assert INSTANCE_KEY not in out["ablations"] and out["by_category"] == {}
    assert categories(["a__f0", "a__f1"]) is None            # one category: nothing to break down
    assert categories(["a__f0", "b__f1", "loose"]) is None   # a target outside any category


def test_a_model_ablation_without_the_instance_methods_pairs_the_methods_it_ran():
    # the instance term's models follow the default bank only, so a models.* ablation runs without them
    rng = np.random.default_rng(3)
    log = "models.score_space=log"
    parts = [_population(rng), _population(rng, methods=METHODS[:3], variant=log)]
    table = pd.concat([p[0] for p in parts], ignore_index=True)
    out = _blocks(table, parts[0][1] + parts[1][1], parts[0][2] + parts[1][2], ablations=[log])
    block = out["ablations"][log]
    assert sorted(block["pooled"]) == sorted(METHODS[:3])
    assert comparison_key(WITH_UNCERTAINTY, SIMPLE_BAYES) in block["paired"]
    assert not any(WU_INSTANCE in k or MB_INSTANCE in k for k in block["paired"])
    assert comparison_key(WITH_UNCERTAINTY, WU_INSTANCE) in out["main"]["paired"]

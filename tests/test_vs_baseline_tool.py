"""tools/vs_baseline.py on a small generated results table whose truth is known: cells read the
track's final step only and count a confident error by the spec's rule; every method of every
variant is paired with the baseline of its own variant, the difference is the difference of the
pooled values (mean-pooled metrics, same cells), its interval contains it, and a method built to be
wrong far more often than the baseline is found worse while one built identical is not."""
import importlib.util
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("vs_baseline", ROOT / "tools" / "vs_baseline.py")
vs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(vs)

THRESHOLD = 0.99
N_TARGETS, N_TRACKS, N_REAL, STEPS = 12, 3, 4, 3


def results(seed=0) -> pd.DataFrame:
    """Per-realization rows: baseline 'sb' right with p 0.8; 'same' a copy of it; 'bad' right with
    p 0.2 and confidently so when wrong; step 0 (not final) is always wrong and confident."""
    rng = np.random.default_rng(seed)
    rows = []
    for variant in ("default", "models.score_space=log"):
        for t in range(N_TARGETS):
            for k in range(N_TRACKS):
                for r in range(N_REAL):
                    u = rng.random(STEPS)
                    for m in ("sb", "same", "bad"):
                        for s in range(STEPS):
                            ok = 0.0 if s == 0 else float(u[s] < (0.2 if m == "bad" else 0.8))
                            conf = 0.999 if (s == 0 or m == "bad") else 0.95
                            rows.append(dict(variant=variant, experiment="e", setting="s", scan="scan0",
                                             target=f"t{t}", track=k, method=m, realization=r, step=s,
                                             correct=ok, confidence=conf))
    return pd.DataFrame(rows)


def test_cells_take_the_final_step_and_the_confident_error_rule():
    d = results()
    cells = vs.final_cells(d, THRESHOLD)
    assert len(cells) == 2 * N_TARGETS * N_TRACKS * 3
    last = d[d["step"] == STEPS - 1]
    want = last.groupby(vs.KEY)["correct"].mean()
    got = cells.set_index(vs.KEY)["correct_final"]
    assert np.allclose(got.loc[want.index], want)
    same = cells[cells["method"] == "same"]
    assert (same["confident_error_final"] == 0).all()     # 0.95 < threshold: never a confident error
    bad = cells[cells["method"] == "bad"].set_index(vs.KEY)
    assert np.allclose(bad["confident_error_final"], 1 - bad["correct_final"])   # 0.999: every error counts
    # a threshold at the 'same' confidence makes its errors confident too
    lower = vs.final_cells(d, 0.95).set_index(vs.KEY)
    s = lower[lower.index.get_level_values("method") == "same"]
    assert np.allclose(s["confident_error_final"], 1 - s["correct_final"])


@pytest.fixture(scope="module")
def res():
    cells = vs.final_cells(results(), THRESHOLD)
    return vs.against(cells, {"default": ["sb", "same", "bad"], "models.score_space=log": ["sb", "bad"]}, "sb",
                      n_boot=400, cluster="target")


def test_every_method_of_every_variant_is_paired_with_its_own_baseline(res):
    assert set(res) == {"default", "models.score_space=log"}
    assert set(res["default"]["paired"]) == {"same-sb", "bad-sb"}
    assert set(res["models.score_space=log"]["paired"]) == {"bad-sb"}
    for r in res.values():
        for key, per in r["paired"].items():
            m = key.split("-")[0]
            for k in vs.METRICS:
                e = per[k]
                assert e["value"] == pytest.approx(r["pooled"][m][k]["value"] - r["pooled"]["sb"][k]["value"], abs=1e-12)
                assert e["ci_low"] <= e["value"] <= e["ci_high"]


def test_the_outcome_follows_the_interval(res):
    bad = res["default"]["paired"]["bad-sb"]
    assert bad["correct_final"]["outcome"] == "worse" and bad["correct_final"]["ci_high"] < 0
    assert bad["confident_error_final"]["outcome"] == "worse" and bad["confident_error_final"]["ci_low"] > 0
    same = res["default"]["paired"]["same-sb"]
    assert {e["outcome"] for e in same.values()} == {"not distinguishable"}
    assert same["correct_final"]["value"] == 0.0


def test_the_table_names_the_baseline_row_and_every_verdict(res):
    rows = vs.table(res, "sb")
    body = [r for r in rows[2:]]
    assert len(body) == 5
    assert sum("(baseline)" in r for r in body) == 2
    assert sum(r.count("worse") for r in body) == 4


def test_a_variant_without_the_baseline_is_refused_naming_it():
    cells = vs.final_cells(results(), THRESHOLD)
    with pytest.raises(SystemExit, match="models.score_space=log.*'nb'"):
        vs.against(cells, {"models.score_space=log": ["sb", "bad"]}, "nb", n_boot=50, cluster="target")

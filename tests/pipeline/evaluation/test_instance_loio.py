"""The leave-one-instance-out judgement of the instance term (pipeline/evaluation/instance_loio.py)
on generated categories whose truth is known: turntable instances drawn from m + g(θ) + h_i(θ) + ε
with b / (a + b) = 1/3. The split prior keeps every fit's b off its bounds and its split near the
truth; a held-out instance's correlated deviation is predicted better with the instance term than
by the plain class GP; the intervals contain their point values and differences are paired."""
import numpy as np
import pytest

from pipeline.evaluation.instance_loio import VARIANTS, Settings, fold_components, fold_data, judge

A, ELL, B, LAM, SN2 = 0.02, 0.7, 0.01, 3.0, 1e-3


def categories(rng, n_cat=2, n_inst=5, n_views=12, D=2):
    th = np.arange(n_views) * 2 * np.pi / n_views
    X = np.c_[np.cos(th), np.sin(th)]
    D2 = ((X[:, None] - X[None]) ** 2).sum(-1)
    Kg = A * np.exp(-D2 / (2 * ELL ** 2))
    Kh = B * np.exp(-D2 / (2 * LAM ** 2)) + SN2 * np.eye(n_views)
    data = {}
    for c in range(n_cat):
        g = np.linalg.cholesky(Kg + 1e-12 * np.eye(n_views)) @ rng.standard_normal((n_views, D))
        m = rng.uniform(0.2, 0.6, D)
        data[f"cat{c}"] = {f"cat{c}_{i}": (X, m + g + np.linalg.cholesky(Kh) @ rng.standard_normal((n_views, D)))
                           for i in range(n_inst)}
    return data


def test_folds_hold_out_one_instance_of_every_category():
    data = categories(np.random.default_rng(0), n_inst=3)
    train, held = fold_data(data, 1)
    for cat, (X, S, lab) in train.items():
        assert held[cat][0] == f"{cat}_1" and len(X) == 2 * 12 and sorted(set(lab)) == [0, 1]
        assert not any(np.array_equal(S[lab == k], held[cat][2]) for k in (0, 1))
    assert fold_components(train, 1) == {cat: [int(np.argmax(S.mean(0)))] for cat, (_, S, _) in train.items()}


@pytest.fixture(scope="module")
def result():
    st = Settings(top=2, fit=dict(restarts=1, seed=0), n_boot=400)
    out = judge(categories(np.random.default_rng(7)), st)
    assert out["own"]["bounds"]["instance_split"]["fits"] == out["all"]["bounds"]["instance_split"]["fits"]
    return out["all"]       # D = top = 2: every component is every category's own


def test_the_split_prior_keeps_the_variance_split_off_its_bounds(result):
    split = result["bounds"]["instance_split"]
    assert split["fits"] == 5 * 2 * 2       # folds x categories x components
    assert not any(k.startswith("instance_amplitude") or k.startswith("amplitude") for k in split["at_bound"]), split
    lo, med, hi = split["split_quartiles"]
    assert 0.1 < med < 0.75, split          # the truth: 1/3


def test_the_instance_term_predicts_a_held_out_instance_better_than_the_plain_gp(result):
    v = result["variants"]
    assert v["instance_split"]["lpd_per_view"]["value"] > v["plain"]["lpd_per_view"]["value"]
    for name in VARIANTS:
        for stat in ("lpd_per_view", "coverage95"):
            e = v[name][stat]
            assert e["ci_low"] <= e["value"] <= e["ci_high"]
        assert 0.0 <= v[name]["coverage95"]["value"] <= 1.0
    d = result["differences"]["instance_split - plain"]["lpd_per_view"]
    assert d["value"] == pytest.approx(v["instance_split"]["lpd_per_view"]["value"] - v["plain"]["lpd_per_view"]["value"])

"""Candidate sets per target and the component rules that depend on them."""
import numpy as np
import pytest

from pipeline.evaluation.grid.candidates import candidate_sets, own_components, plan_components
from pipeline.method.components import choose_components

POOL = [f"obj_{i:02d}" for i in range(12)]


def test_sampled_sets_hold_the_target_and_are_seeded_per_target():
    a = candidate_sets(POOL, POOL, 4, "sampled", seed=0)
    assert set(a) == set(POOL)
    for t, c in a.items():
        assert t in c and len(c) == 4 and len(set(c)) == 4 and c == sorted(c)
    assert candidate_sets(POOL, POOL, 4, "sampled", seed=0) == a          # deterministic
    assert candidate_sets(POOL, POOL, 4, "sampled", seed=1) != a          # the seed matters
    # Per-target streams: planning fewer targets does not change a target's draw.
    assert candidate_sets(POOL, POOL[3:5], 4, "sampled", seed=0) == {t: a[t] for t in POOL[3:5]}
    # The truth does not always sit at the same posterior index (argmax ties favour low indices).
    assert len({c.index(t) for t, c in a.items()}) > 1


def test_all_and_explicit_candidates():
    assert candidate_sets(POOL[:5], ["obj_02"], 4, "all", 0) == {"obj_02": POOL[:5]}
    got = candidate_sets(POOL, ["obj_02", "obj_07"], 4, ["obj_07", "obj_01"], 0)
    assert got == {"obj_02": ["obj_01", "obj_02", "obj_07"], "obj_07": ["obj_01", "obj_07"]}
    with pytest.raises(ValueError, match="'evaluate.candidates' names 'nope'"):
        candidate_sets(POOL, ["obj_02"], 4, ["nope"], 0)
    with pytest.raises(ValueError, match="not a modelled class"):
        candidate_sets(POOL, ["nope"], 4, "sampled", 0)
    with pytest.raises(ValueError, match="n_candidates' = 20"):
        candidate_sets(POOL, ["obj_02"], 20, "sampled", 0)


def test_target_informative_ranks_shared_components_by_the_target():
    # Component 0: only the target scores it; 1 and 2: every class; the target prefers 2.
    t = np.array([[0.5, 0.1, 0.3, 0.1]] * 4)
    o = np.array([[0.0, 0.6, 0.1, 0.3]] * 4)
    comps, _ = choose_components([o, t], 2, "target_informative", target=1, informative_min=0.05)
    assert comps == [2, 1]
    # With fewer eligible components than asked, the rest follow in top_min order.
    comps, _ = choose_components([o, t], 3, "target_informative", target=1, informative_min=0.05)
    assert comps == [2, 1, 3]   # 1 and 3 tie on the target (0.1): lower index first
    # A different target changes the ranking: the rule is per target.
    comps, _ = choose_components([o, t], 2, "target_informative", target=0, informative_min=0.05)
    assert comps == [1, 3]


def test_plan_and_own_components():
    rng = np.random.default_rng(0)
    scores = {c: rng.dirichlet(np.ones(6) * 0.5, size=10) for c in POOL[:4]}
    sets = candidate_sets(POOL[:4], POOL[:4], 3, "sampled", 0)
    plan = plan_components(sets, scores, 2, "top_mean")
    for t, p in plan.items():
        pooled = np.concatenate([scores[c] for c in p["classes"]]).mean(0)
        assert p["components"] == [int(i) for i in np.argsort(-pooled, kind="stable")[:2]]
    own = own_components(scores)
    assert all(own[c] == int(np.argmax(scores[c].mean(0))) for c in scores)

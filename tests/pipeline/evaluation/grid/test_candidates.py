"""Candidate sets per target and the component rules that depend on them."""
import numpy as np
import pytest

from pipeline.evaluation.grid.candidates import candidate_sets, own_components, plan_components, set_size
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


def _line_means():
    # Six classes on a line of 3-D score vectors (positions 0, 1, 2, 4, 8, 13 along it, no two
    # distances equal from c0, c3 or c5), plus "tie_a"/"tie_b" off the line, equally far from "c2".
    means = {f"c{i}": np.array([0.1 + 0.05 * x, 0.9 - 0.05 * x, 0.0]) for i, x in enumerate([0, 1, 2, 4, 8, 13])}
    means["tie_b"] = means["c2"] + np.array([0.0, -0.2, 0.2])
    means["tie_a"] = means["c2"] + np.array([0.0, 0.2, -0.2])
    return means


def test_hard_sets_are_the_nearest_classes_in_score_space():
    means = _line_means()
    pool = sorted(means)
    got = candidate_sets(pool, ["c0", "c5", "c3"], 3, "hard", seed=0, class_means=means)
    assert got == {"c0": ["c0", "c1", "c2"],      # positions 1 and 2 are nearest 0
                   "c5": ["c3", "c4", "c5"],      # 8 and 4 are nearest 13
                   "c3": ["c1", "c2", "c3"]}      # from 4: 2 (2 away) and 1 (3 away) before 8 (4 away)
    # Brute force over every target and size: the set is exactly the k nearest by distance.
    for t in pool:
        for n in range(2, len(pool) + 1):
            s = candidate_sets(pool, [t], n, "hard", 0, class_means=means)[t]
            assert t in s and len(s) == n == len(set(s)) and s == sorted(s)
            inside = max(np.linalg.norm(means[c] - means[t]) for c in s if c != t)
            outside = [np.linalg.norm(means[c] - means[t]) for c in pool if c not in s]
            assert all(inside <= d + 1e-12 for d in outside)
    # The seed plays no part; the sets are the same on every call.
    assert candidate_sets(pool, pool, 4, "hard", 7, class_means=means) == candidate_sets(pool, pool, 4, "hard", 0,
                                                                                         class_means=means)


def test_hard_sets_break_distance_ties_by_name():
    means = _line_means()
    pool = sorted(means)
    # From c2, tie_a and tie_b are both sqrt(0.08) away: exactly equal distances.
    d = {c: np.linalg.norm(means[c] - means["c2"]) for c in pool}
    assert d["tie_a"] == d["tie_b"]
    ranked = sorted((c for c in pool if c != "c2"), key=lambda c: (d[c], c))
    k = ranked.index("tie_a") + 1          # a set that has room for exactly one of the tied pair
    got = candidate_sets(pool, ["c2"], k + 1, "hard", 0, class_means=means)["c2"]
    assert "tie_a" in got and "tie_b" not in got


def test_hard_sets_need_means_and_a_pool_large_enough():
    means = _line_means()
    pool = sorted(means)
    with pytest.raises(ValueError, match="n_candidates' = 9 but only 8 classes"):
        candidate_sets(pool, ["c0"], 9, "hard", 0, class_means=means)
    with pytest.raises(ValueError, match="'hard' needs the mean score vector.*'tie_b'"):
        candidate_sets(pool, ["c0"], 3, "hard", 0, class_means={c: m for c, m in means.items() if c != "tie_b"})
    with pytest.raises(ValueError, match="'hard' needs"):
        candidate_sets(pool, ["c0"], 3, "hard", 0)


def test_all_candidates_get_at_least_one_component_each():
    # evaluate.candidates = "all": N_f grows with the candidates (the paper's N_f = N_c, section 4.4.1)
    rng = np.random.default_rng(1)
    pool = POOL[:8]
    scores = {c: rng.dirichlet(np.ones(20) * 0.3, size=6) for c in pool}
    sets = candidate_sets(pool, pool, 4, "all", 0)
    plan = plan_components(sets, scores, 4, "top_mean", per_candidate=True)
    for t, p in plan.items():
        assert len(p["classes"]) == 8 and len(p["components"]) == 8 == len(set(p["components"]))
        pooled = np.concatenate([scores[c] for c in p["classes"]]).mean(0)
        assert p["components"] == [int(i) for i in np.argsort(-pooled, kind="stable")[:8]]
    assert all(len(p["components"]) == 4 for p in plan_components(sets, scores, 4, "top_mean").values())
    assert set_size(10, 8, True) == 10 and set_size(4, 3, True) == 4 and set_size(4, 8, False) == 4
    assert set_size(2, 8, True, "explicit") == 2          # named components: the user's N_f

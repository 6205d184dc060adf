"""The test-domain fit of every model bank (``target_domain.bank_fits``): a models.*
ablation's own bank (here a log score space) gets the main bank's pooled rows, Gaussian and
Student-t, from the same crops; an evaluate.* ablation (same bank) gets none (the report's table:
tests/reports/test_domain_fit_table.py)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd

from pipeline.evaluation.domain.target_domain import TargetDomain, bank_fits
from pipeline.method.gp import GPClassModels

LOG = "models.score_space=log"
SAME = "evaluate.test_domain_variance=cross_fit"


def _scene():
    """Two classes, one scan, crops all around each object; the scores are probabilities near the
    class curve with a crop-level offset and dropout noise; a probability-space bank and a log-space
    bank fitted to the same curves (the log bank's curve is the log of the probability one)."""
    th = np.linspace(-np.pi, np.pi, 24, endpoint=False)
    X = np.stack([np.cos(th), np.sin(th)], -1)
    Y = np.stack([0.5 + 0.1 * np.sin(th), 0.3 + 0.05 * np.cos(th)])
    ones = np.ones((2, 2))
    prob = GPClassModels(["a", "b"], [0, 1], [X, X], [Y, Y], 0.4 * ones, 0.01 * ones, 0.8 * ones, 1e-3 * ones)
    logY = np.log(Y)
    log = GPClassModels(["a", "b"], [0, 1], [X, X], [logY, logY], 0.4 * ones, 0.01 * ones, 0.8 * ones,
                        1e-3 * ones, meta={"score_space": {"space": "log", "floor": 1e-6}})
    rng = np.random.default_rng(3)
    rows, scores = [], []
    for inst, obj in (("a", (0.0, 0.0)), ("b", (5.0, 0.0))):
        rows.append({"scan": "S", "instance": inst, "image": f"{inst}_det", "pass": -1, "difficulty": 1,
                     "cam_x": obj[0] + 1.0, "cam_y": obj[1]})
        scores.append(np.full(2, 0.5))
        for i in range(40):
            ang = rng.uniform(-np.pi, np.pi)
            cam = (obj[0] + 2 * np.cos(ang), obj[1] + 2 * np.sin(ang))
            mu = np.array([0.5 + 0.1 * np.sin(ang), 0.3 + 0.05 * np.cos(ang)])
            centre = mu + rng.normal(0, 0.08, 2)
            for p in range(6):
                rows.append({"scan": "S", "instance": inst, "image": f"{inst}{i}", "pass": p, "difficulty": 1,
                             "cam_x": cam[0], "cam_y": cam[1]})
                scores.append(np.clip(centre + rng.normal(0, 0.02, 2), 0.01, 0.99))
    truth = {"instances": {"a": {"position": [0.0, 0.0], "yaw_deg": 0.0},
                           "b": {"position": [5.0, 0.0], "yaw_deg": 0.0}}}
    eff = SimpleNamespace(dropout=0.2, drop_connect=0.0)
    cfg = SimpleNamespace(evaluate=SimpleNamespace(max_difficulty=4, yaw_source="truth", variance_floor=1e-6,
                                                   bootstrap=50, seed=0, test_domain_variance="none",
                                                   ablations=[LOG, SAME]),
                          classifier=SimpleNamespace(arch="efficientnet_lite0", dropout=0.5, efficientnet=eff))
    return cfg, pd.DataFrame(rows), np.array(scores), {"default": prob, LOG: log, SAME: prob}, truth


def test_each_model_ablation_gets_the_fit_rows_of_its_own_bank():
    cfg, avd, scores, banks, truth = _scene()
    main = TargetDomain(cfg, avd, scores, banks["default"], truth, {}, ["a", "b"], ["S"]).summary()
    out = bank_fits(cfg, avd, scores, banks, truth, {}, ["a", "b"], ["S"])
    assert list(out) == [LOG]                        # the evaluate.* ablation shares the main bank: no rows
    fit = out[LOG]
    assert main["score_space"] == "probability" and fit["score_space"] == "log"
    assert fit["n_crops"] == main["n_crops"] == 80   # the same crops
    for k in ("gp", "gp_plus_dropout", "gp_calibrated", "gp_t", "gp_plus_dropout_t"):
        o, m = fit[k]["overall"], main[k]["overall"]
        assert o["n"] == m["n"] == 160 and 0.0 <= o["coverage95"] <= 1.0
        assert set(fit[k]) == {"overall"}            # the per-class tables are the main bank's only
        for row in (o, m):                           # two instances: the coverage's CI is withheld, saying why
            assert row["coverage95_ci"] is None and row["coverage95_withheld"].startswith("2 instances: ")
            assert row["coverage95_units"] == {"instances": 2}
    # another space, other residuals: log stretches a residual by about 1/p (p <= 0.6 here) while both
    # banks carry the same GP variances, so the log bank's |z| are larger and its coverage lower
    for k in ("gp", "gp_plus_dropout"):
        assert fit[k]["overall"]["abs_z_p90"] > main[k]["overall"]["abs_z_p90"]
        assert fit[k]["overall"]["coverage95"] < main[k]["overall"]["coverage95"]
    assert fit["gp"]["overall"]["pit"] != main["gp"]["overall"]["pit"]



def test_a_fit_only_bank_gets_the_same_rows_loaded_once_and_marked():
    """An ``evaluate.fit_spaces`` bank: no ablation, no cell, only its loader; its rows are those the
    same bank gets as an ablation, and the entry says it is fit-only."""
    cfg, avd, scores, banks, truth = _scene()
    as_ablation = bank_fits(cfg, avd, scores, banks, truth, {}, ["a", "b"], ["S"])[LOG]
    calls = []
    cfg.evaluate.ablations = []
    out = bank_fits(cfg, avd, scores, {"default": banks["default"]}, truth, {}, ["a", "b"], ["S"],
                    fit_only={LOG: lambda: calls.append(1) or banks[LOG]})
    assert list(out) == [LOG] and len(calls) == 1
    assert out[LOG].pop("fit_only") is True and "fit_only" not in as_ablation
    assert out[LOG] == as_ablation


def test_a_clr_banks_residuals_are_the_same_read_in_row_blocks(monkeypatch):
    """clr reads each pass's whole score vector, so the crops' residuals are computed in blocks of
    rows (memory); clr is row-wise, so any block size gives the same table to the bit."""
    from pipeline.evaluation.domain import fit as D

    cfg, avd, scores, banks, truth = _scene()
    b = banks[LOG]
    clr = GPClassModels(b.classes, b.components, b.X, b.Y, b.mean, b.amplitude, b.length_scale, b.noise,
                        meta={"score_space": {"space": "clr", "floor": 1e-6}})
    poses = TargetDomain(cfg, avd, scores, clr, truth, {}, ["a", "b"], ["S"]).poses
    whole = D.crop_residuals(avd, scores, clr, poses, 4, 1e-6)
    monkeypatch.setattr(D, "CLR_BLOCK", 7)   # 480 passes: 69 blocks, the last one short
    blocks = D.crop_residuals(avd, scores, clr, poses, 4, 1e-6)
    assert len(whole) == 160 and np.isfinite(whole["obs"]).all()
    pd.testing.assert_frame_equal(blocks, whole, check_exact=True)

"""The report's test-domain fit table (reports/main/calibration.py): with the models.*
ablations' fits in ``domain_fit.by_ablation`` it gains a models (score space) column and one row
group per bank, each with its Gaussian and Student-t rows and its own 95 % coverage; without them it
keeps its columns."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from reports.main import calibration
from reports.main.calibration import DOMAIN_KINDS, DOMAIN_STATS, domain_section
from reports.shared.checks import Ledger
from reports.shared.numbers import fmt

LOG = "models.score_space=log"


def _fit(rng, space: str) -> dict:
    out = {"n_crops": 80, "score_space": space}
    for k, _ in DOMAIN_KINDS:
        q = np.sort(rng.uniform(0, 4, 3))
        out[k] = {"overall": {"n": 160, "share_gt2": float(rng.uniform(0, 0.1)),
                              "share_gt3": float(rng.uniform(0, 0.01)), "coverage95": float(rng.uniform(0.8, 1.0)), "abs_z_p90": float(q[1]),
                              "abs_z_p99": float(q[2])}}
    return out


def _render(dom: dict, ledger: Ledger | None = None):
    tables = []
    page = SimpleNamespace(paragraph=lambda *a, **k: None,
                           table=lambda header, rows, **k: tables.append((header, rows, k)))
    ctx = SimpleNamespace(population={"domain_fit": dom}, page=page, section=lambda *a: None,
                          figure=lambda *a, **k: None, ledger=Ledger() if ledger is None else ledger)
    domain_section(ctx)
    return next((h, r) for h, r, k in tables if k.get("cls") == "domain-fit")


def test_one_row_group_per_bank_with_its_own_coverage():
    rng = np.random.default_rng(0)
    dom = {**_fit(rng, "probability"), "pose_source": "sidecar", "by_ablation": {LOG: _fit(rng, "log")}}
    header, rows = _render(dom)
    assert header[0] == "models (score space)" and "95 % coverage" in header
    cov = header.index("95 % coverage")
    groups: dict = {}
    for r in rows:
        groups.setdefault(r[0], []).append(r)
    assert list(groups) == ["main (probability scores)", f"{LOG} (log scores)"]
    for (label, grp), fit in zip(groups.items(), (dom, dom["by_ablation"][LOG])):
        assert [r[1] for r in grp] == [t for _, t in DOMAIN_KINDS]          # Gaussian and Student-t rows
        assert [r[cov] for r in grp] == [fmt(fit[k]["overall"]["coverage95"]) for k, _ in DOMAIN_KINDS], label


def test_without_ablation_banks_the_table_keeps_its_columns():
    dom = {**_fit(np.random.default_rng(1), "probability"), "by_ablation": {}}
    header, rows = _render(dom)
    assert header[0] == "variance" and len(rows) == len(DOMAIN_KINDS)
    dom["by_ablation"] = {LOG: {"n_crops": 0, "note": "no crop"}}   # an empty bank adds no group
    header, rows = _render(dom)
    assert header[0] == "variance"


def test_every_number_of_every_banks_rows_is_checked_against_its_fit():
    rng = np.random.default_rng(2)
    dom = {**_fit(rng, "probability"), "by_ablation": {LOG: _fit(rng, "log")}}
    led = Ledger()
    _render(dom, led)
    assert led.problems() == []
    table = [e for e in led.entries if e.where == "domain-fit table"]
    assert len(table) == 2 * len(DOMAIN_KINDS) * len(DOMAIN_STATS)          # one entry per shown number
    assert {e.key[1] for e in table} == {"main (probability scores)", f"{LOG} (log scores)"}


def test_a_planted_mismatch_in_an_ablation_banks_row_is_caught(monkeypatch):
    rng = np.random.default_rng(3)
    dom = {**_fit(rng, "probability"), "by_ablation": {LOG: _fit(rng, "log")}}
    real = calibration.domain_rows

    def shifted(d):   # the ablation bank's Student-t row shows another coverage than its fit holds
        rows = real(d)
        if d.get("score_space") == "log":
            i = [r[0] for r in rows].index(dict(DOMAIN_KINDS)["gp_plus_dropout_t"])
            j = 1 + DOMAIN_STATS.index("coverage95")
            rows[i][j] = fmt(float(rows[i][j]) + 0.01)
        return rows

    monkeypatch.setattr(calibration, "domain_rows", shifted)
    led = Ledger()
    _render(dom, led)
    (p,) = led.problems()
    assert p.startswith(f"domain fit / {LOG} (log scores) / gp_plus_dropout_t / coverage95: evaluate/summary.json "
                        "shows") and "domain-fit table shows" in p, p


def _cover(space: str, **cov) -> dict:
    out = {"n_crops": 10, "score_space": space}
    for k, c in cov.items():
        out[k] = {"overall": {"n": 20, "share_gt2": 0.0, "share_gt3": 0.0, "coverage95": c, "abs_z_p90": 1.0,
                              "abs_z_p99": 2.0}}
    return out


def test_the_default_predictives_coverage_is_read_against_the_band_and_the_banks_inside_are_named():
    from reports.main.calibration import coverage_sentence, domain_banks

    wide = {**_cover("probability", gp=0.97, gp_plus_dropout=0.988),
            "by_ablation": {LOG: _cover("log", gp_plus_dropout=0.87, gp_t=0.95, gp_plus_dropout_t=0.944)}}
    s = coverage_sentence(domain_banks(wide))
    assert "above" in s and fmt(0.988) in s
    # those inside the band, grouped by bank; the log Gaussian (0.87) is not named
    assert "main (probability scores): GP predictive (Model Based);" in s
    assert (f"{LOG} (log scores): GP predictive as a Student-t (ν cross-fitted), "
            "+ dropout variance as a Student-t (ν cross-fitted).") in s
    assert s.count(";") == 1 and "With Uncertainty), " not in s
    fits = coverage_sentence(domain_banks(_cover("probability", gp_plus_dropout=0.95)))
    assert "inside the band" in fits and "Inside it in this run" not in fits
    narrow = coverage_sentence(domain_banks(_cover("log", gp_plus_dropout=0.80, gp=0.70)))
    assert "below" in narrow and "No bank or likelihood of this run falls inside it." in narrow


def test_a_fit_only_bank_has_its_own_rows_after_the_ablations_and_says_it_ran_no_method():
    from reports.main.calibration import FIT_ONLY, coverage_sentence, domain_banks

    rng = np.random.default_rng(2)
    clr = "models.score_space=clr"
    dom = {**_fit(rng, "probability"), "by_ablation": {clr: {**_fit(rng, "clr"), "fit_only": True},
                                                      LOG: _fit(rng, "log")}}
    header, rows = _render(dom)
    groups: dict = {}
    for r in rows:
        groups.setdefault(r[0], []).append(r)
    assert list(groups) == ["main (probability scores)", f"{LOG} (log scores)", f"clr scores ({FIT_ONLY})"]
    cov = header.index("95 % coverage")
    assert [r[cov] for r in groups[f"clr scores ({FIT_ONLY})"]] == \
        [fmt(dom["by_ablation"][clr][k]["overall"]["coverage95"]) for k, _ in DOMAIN_KINDS]
    # the coverage sentence names a fit-only bank inside the band with its label
    wide = {**_cover("probability", gp_plus_dropout=0.99),
            "by_ablation": {clr: {**_cover("clr", gp_t=0.95), "fit_only": True}}}
    assert f"clr scores ({FIT_ONLY}): GP predictive as a Student-t" in coverage_sentence(domain_banks(wide))

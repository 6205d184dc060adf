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
from reports.shared.numbers import Estimate, fmt

LOG = "models.score_space=log"


def _fit(rng, space: str) -> dict:
    out = {"n_crops": 80, "score_space": space}
    for k, _ in DOMAIN_KINDS:
        q = np.sort(rng.uniform(0, 4, 3))
        c = np.sort(rng.uniform(0.8, 1.0, 3))          # the share inside its CI
        out[k] = {"overall": {"n": 160, "share_gt2": float(rng.uniform(0, 0.1)),
                              "share_gt3": float(rng.uniform(0, 0.01)), "coverage95": float(c[1]),
                              "coverage95_ci": [float(c[0]), float(c[2])], "coverage95_over": "instances",
                              "abs_z_p90": float(q[1]), "abs_z_p99": float(q[2])}}
    return out


def _cell(o: dict) -> str:
    """The coverage cell as the page writes it: the share [95 % CI]."""
    lo, hi = o.get("coverage95_ci") or (None, None)
    return Estimate(o["coverage95"], lo, hi).text()


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
        assert [r[cov].text() for r in grp] == [_cell(fit[k]["overall"]) for k, _ in DOMAIN_KINDS], label
        assert all(" [" in r[cov].text() for r in grp)


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
            rows[i][j] = Estimate(rows[i][j].value + 0.01, rows[i][j].low, rows[i][j].high)
        return rows

    monkeypatch.setattr(calibration, "domain_rows", shifted)
    led = Ledger()
    _render(dom, led)
    (p,) = led.problems()
    assert p.startswith(f"domain fit / {LOG} (log scores) / gp_plus_dropout_t / coverage95: evaluate/summary.json "
                        "shows") and "domain-fit table shows" in p, p


def _cover(space: str, **cov) -> dict:
    """Pooled rows with coverage (share, CI low, CI high) per kind."""
    out = {"n_crops": 10, "score_space": space}
    for k, (c, lo, hi) in cov.items():
        out[k] = {"overall": {"n": 20, "share_gt2": 0.0, "share_gt3": 0.0, "coverage95": c,
                              "coverage95_ci": [lo, hi], "coverage95_over": "instances", "abs_z_p90": 1.0,
                              "abs_z_p99": 2.0}}
    return out


def test_the_default_predictives_band_verdict_is_read_off_its_ci_and_the_banks_inside_are_named():
    from reports.main.calibration import BAND_RULE, coverage_sentence, domain_banks

    wide = {**_cover("probability", gp=(0.95, 0.93, 0.97), gp_plus_dropout=(0.988, 0.982, 0.993)),
            "by_ablation": {LOG: _cover("log", gp_plus_dropout=(0.87, 0.85, 0.89), gp_t=(0.95, 0.94, 0.96),
                                        gp_plus_dropout_t=(0.944, 0.90, 0.97))}}
    s = coverage_sentence(domain_banks(wide))
    assert "above the band" in s and "0.988 [0.982, 0.993]" in s and BAND_RULE in s and "resampling instances" in s
    # inside by the CI rule, grouped by bank: the log Gaussian (CI below) and the log + dropout t (CI
    # straddles 0.92 although its share 0.944 lies in the band) are not named
    assert "main (probability scores): GP predictive (Model Based);" in s
    assert f"{LOG} (log scores): GP predictive as a Student-t (ν cross-fitted)." in s
    assert s.count(";") == 2 and "+ dropout variance as a Student-t" not in s      # the rule's ';' and one
    fits = coverage_sentence(domain_banks(_cover("probability", gp_plus_dropout=(0.95, 0.93, 0.97))))
    assert "inside the band" in fits and "Inside it by that rule" not in fits
    narrow = coverage_sentence(domain_banks(_cover("log", gp_plus_dropout=(0.80, 0.75, 0.85), gp=(0.70, 0.6, 0.8))))
    assert "below the band" in narrow and "No bank or likelihood of this run lies inside it" in narrow


def test_a_share_beyond_the_band_whose_ci_reaches_into_it_gets_no_side():
    from reports.main.calibration import coverage_sentence, domain_banks

    # the share 0.985 lies above 0.98, but its CI reaches 0.97: neither above nor inside
    s = coverage_sentence(domain_banks(_cover("probability", gp_plus_dropout=(0.985, 0.97, 0.995))))
    assert "not distinguishable from an edge of the band" in s and "above the band" not in s
    s = coverage_sentence(domain_banks(_cover("probability", gp_plus_dropout=(0.915, 0.90, 0.925))))
    assert "not distinguishable from an edge of the band" in s and "below the band" not in s


def test_without_a_ci_there_is_no_verdict_and_the_sentence_says_why():
    from reports.main.calibration import coverage_sentence, domain_banks

    dom = _cover("probability", gp_plus_dropout=(0.99, None, None))
    dom["gp_plus_dropout"]["overall"].update(coverage95_ci=None, coverage95_withheld="5 instances: too few")
    s = coverage_sentence(domain_banks(dom))
    assert "no CI, no verdict: 5 instances: too few" in s
    assert not any(w in s for w in ("above the band", "below the band", "inside the band"))
    header, rows = _render(dom)
    assert rows[0][header.index("95 % coverage")].text() == fmt(0.99)      # the share alone, no interval


def test_a_planted_ci_mismatch_is_caught_by_the_ledger(monkeypatch):
    rng = np.random.default_rng(5)
    dom = {**_fit(rng, "probability"), "by_ablation": {LOG: _fit(rng, "log")}}
    real = calibration.domain_rows

    def widened(d):   # the main bank's Gaussian row shows a CI other than its fit's
        rows = real(d)
        if d.get("score_space") == "probability":
            j = 1 + DOMAIN_STATS.index("coverage95")
            e = rows[0][j]
            rows[0][j] = Estimate(e.value, e.low - 0.001, e.high)
        return rows

    monkeypatch.setattr(calibration, "domain_rows", widened)
    led = Ledger()
    _render(dom, led)
    (p,) = led.problems()
    assert p.startswith("domain fit / main (probability scores) / gp / coverage95: evaluate/summary.json shows"), p


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
    assert [r[cov].text() for r in groups[f"clr scores ({FIT_ONLY})"]] == \
        [_cell(dom["by_ablation"][clr][k]["overall"]) for k, _ in DOMAIN_KINDS]
    # the coverage sentence names a fit-only bank inside the band with its label
    wide = {**_cover("probability", gp_plus_dropout=(0.99, 0.985, 0.995)),
            "by_ablation": {clr: {**_cover("clr", gp_t=(0.95, 0.94, 0.96)), "fit_only": True}}}
    assert f"clr scores ({FIT_ONLY}): GP predictive as a Student-t" in coverage_sentence(domain_banks(wide))

"""Every number an ablation's rows show (the ablation table, the calibration table's calibrated
rows, the attribution table) is in the page's ledger beside its source in summary.json (the
block's pooled entry, or the verdict record it is read with), so the self-check catches a cell that
is not its source's number. Blocks from the statistics engine on generated cells."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd

from pipeline.evaluation.statistics.engine import population_block
from reports.main import calibration, verdict
from reports.main.calibration import ATTRIBUTION, CALIBRATED, TABLE, attribution_section, calibration_section
from reports.main.context import ReportContext
from reports.shared.artifacts import RunArtifacts
from reports.shared.html import HtmlReport

WU, MB = "with_uncertainty", "model_based"
METRICS = ("correct_final", "confident_error_final", "msde_final", "nll_final", "log10_mgr95_final")   # ECE: not a cell metric


def _block(seed: int, shift: float = 0.1) -> dict:
    """The engine's block of 10 targets x 3 tracks x 2 settings, With Uncertainty ``shift`` better."""
    rng = np.random.default_rng(seed)
    rows = []
    for t in range(10):
        base = rng.uniform(0.3, 0.7)
        for tr in range(3):
            for s in ("a", "b"):
                for m in (WU, MB):
                    d = shift if m == WU else 0.0
                    rows.append({"target": f"t{t}", "track": tr, "setting": s, "method": m,
                                 "correct_final": float(np.clip(base + d + rng.normal(0, 0.05), 0, 1)),
                                 "confident_error_final": float(np.clip(0.2 - d / 2 + rng.normal(0, 0.03), 0, 1)),
                                 "msde_final": float(abs(rng.normal(0.3, 0.05))),
                                 "nll_final": float(abs(rng.normal(1.0, 0.2))),
                                 "log10_mgr95_final": float(rng.normal(0.5 - d, 0.2))})
    return population_block(pd.DataFrame(rows), [WU, MB], list(METRICS), [(WU, MB)], 500, seed,
                            per_target=False, loto=False)


def _ctx(tmp_path, pop: dict) -> ReportContext:
    return ReportContext(HtmlReport("t"), RunArtifacts(tmp_path, SimpleNamespace(population=pop)))


def _pop() -> dict:
    pop = _block(0)
    pop.update(confident_threshold=0.9, ece_bins=10,
               ablations={CALIBRATED: _block(1), ATTRIBUTION: {**_block(2), "kind": "attribution"},
                          "models.noise_floor=dropout": {**_block(3, 0.0), "override": {"models.noise_floor": "dropout"}}})
    return pop


def _render(tmp_path, pop):
    ctx = _ctx(tmp_path, pop)
    calibration_section(ctx)
    attribution_section(ctx)
    verdict._ablations(ctx)
    return ctx


def test_each_number_of_every_ablation_row_is_registered_with_its_source(tmp_path):
    ctx = _render(tmp_path, _pop())
    assert ctx.ledger.problems() == []
    where = {}
    for e in ctx.ledger.entries:
        where.setdefault(e.where, []).append(e)
    # the calibration table: both methods' pooled values, main and calibrated rows, each beside summary.json's
    assert len(where["calibration table"]) == 2 * 2 * len(TABLE)
    assert {e.key[:3] for e in where["calibration table"] if e.key[0] == "ablation"} == {
        ("ablation", CALIBRATED, "pooled")}
    # the attribution table: each difference beside its record; the ablation table (the calibrated and the
    # noise-floor ablation; attribution has its own section): its two number columns, and all four records
    assert len(where["attribution table"]) == 4 and len(where["ablation table"]) == 2 * 2
    assert len(where["its verdict record (evaluate/summary.json)"]) == 4 + 2 * 4


def test_a_planted_mismatch_in_an_ablation_row_is_caught(tmp_path, monkeypatch):
    pop = _pop()
    real = calibration.pooled_value

    def shifted(block, method, metric):   # the calibrated rows show another number than their block holds
        d = real(block, method, metric)
        return {**d, "value": d["value"] + 0.01} if d and block is pop["ablations"][CALIBRATED] and method == WU else d

    monkeypatch.setattr(calibration, "pooled_value", shifted)
    problems = _render(tmp_path, pop).ledger.problems()
    assert problems and all(p.startswith(f"ablation / {CALIBRATED} / pooled / {WU} /") for p in problems), problems
    shows = [p for p in problems if "evaluate/summary.json shows" in p and "calibration table shows" in p]
    assert len(shows) == len(TABLE) - 1, problems   # every shown metric of the row (ECE: not in these cells)


def test_a_planted_mismatch_in_the_ablation_table_is_caught(tmp_path, monkeypatch):
    pop = _pop()
    real = verdict.paired_value

    def shifted(block, comparison, metric):   # the ablation table's number is not its record's
        d = real(block, comparison, metric)
        return {**d, "ci_high": d["ci_high"] + 0.5} if "override" in block and metric == "correct_final" else d

    monkeypatch.setattr(verdict, "paired_value", shifted)
    (p,) = _render(tmp_path, pop).ledger.problems()
    assert p.startswith("ablation / models.noise_floor=dropout / with_uncertainty-model_based / correct_final: "
                        "its verdict record") and "ablation table shows" in p, p

"""The report's Power section (variance components of the primary comparison) and the paper's §5.5
setting (reports/main/power.py), from a population's ``power`` block and ``by_setting`` entries
(nothing recomputed)."""
from types import SimpleNamespace

import numpy as np

from pipeline.evaluation.statistics.power import power_block
from reports.main.power import paper_setting, power_section
from reports.shared.checks import Ledger
from tests.pipeline.evaluation.statistics.test_power import crossed


class Page:
    def __init__(self):
        self.items = []

    def paragraph(self, text, cls=""):
        self.items.append(("p", text))

    def table(self, header, rows, caption="", cls="", **kw):
        self.items.append(("table", header, rows, caption))


def _ctx(pop, chain_s: float | None = None):
    page = Page()
    sections = []
    ev = SimpleNamespace(summary={"timings_s": {} if chain_s is None else {"chain_total": chain_s}})
    return SimpleNamespace(page=page, population=pop, ev=ev,
                           section=lambda title, anchor: sections.append(title)), sections


def _power(**kw):
    d = crossed(np.random.default_rng(3), 100, 6, 2, 0.01, 0.005, 0.0, 1.2)
    return power_block(d, {"comparison": "with_uncertainty-model_based", "metric": "confident_error_final",
                           "setting": "all"}, **kw)


def test_the_power_section_states_power_components_and_the_config_change():
    power = _power(available={"objects": 100, "scans": 6}, tracks_per_target=8)
    ctx, sections = _ctx({"power": power})
    power_section(ctx)
    assert sections == ["Power of the primary comparison"]
    text = ctx.page.items[0][1]
    assert f"{round(100 * power['power_now'])} % at this run's size" in text and "not adjusted" in text
    assert f"evaluate.tracks_per_target = {power['change']['evaluate.tracks_per_target']} (now 8)" in text
    comps, needs = ctx.page.items[1][2], ctx.page.items[2][2]
    assert [r[0] for r in comps] == ["object", "scan", "interaction", "track"]
    shares = [int(r[3].rstrip(" %")) for r in comps]
    assert abs(sum(shares) - 100) <= 2                       # the four terms make up the variance now
    assert needs[2][2] == str(power["needed"]["tracks_per_cell"]) and needs[0][2].endswith("(100 in this run's data)")


def test_a_population_beyond_the_data_reads_not_reachable():
    d = crossed(np.random.default_rng(3), 12, 2, 4, 0.4, 0.05, 0.0, 0.1)
    power = power_block(d, {"comparison": "with_uncertainty-model_based", "metric": "correct_final",
                            "setting": "biased_randomized"}, available={"objects": 12, "scans": 2})
    ctx, _ = _ctx({"power": power})
    power_section(ctx)
    assert "Not reachable with this data" in ctx.page.items[0][1]
    assert "none suffices" in ctx.page.items[2][2][2][2]


def test_a_summary_without_components_states_no_power():
    ctx, sections = _ctx({"power": {"goal": 0.05, "comparisons": []}})
    power_section(ctx)
    assert sections == [] and ctx.page.items == []


def test_the_paper_setting_table_sits_beside_the_papers_figure_and_only_when_run():
    label = "sigma=0.3 m, bias=(-0.3, +0.2) m"
    est = lambda v: {"value": v, "ci_low": v - 0.05, "ci_high": v + 0.05}
    pop = {"methods": ["with_uncertainty", "model_based"], "scope": "15 scans, 250 targets x 990 tracks x 3 settings",
           "confident_threshold": 0.99,
           "settings": [{"experiment": "biased", "setting": "b", "sigma_m": 0.3, "bias_m": [-0.3, 0.2],
                         "realizations": 1},
                        {"experiment": "biased_randomized", "setting": label, "sigma_m": 0.3, "bias_m": [-0.3, 0.2],
                         "realizations": 20}],
           "by_setting": {label: {"pooled": {m: {"correct_final": est(0.7), "confident_error_final": est(v),
                                                 "log10_mgr95_final": est(1.0)}
                                             for m, v in (("with_uncertainty", 0.1), ("model_based", 0.25))}}}}
    ctx, sections = _ctx(pop)
    paper_setting(ctx, pop)
    assert sections == ["The paper's §5.5 setting"]
    _, header, rows, caption = ctx.page.items[0]
    assert [r[0].split(" (")[0] for r in rows] == ["With Uncertainty", "Model Based"]
    assert rows[1][3].value == 0.25 and "around 10 % of runs" in caption and "over scans, targets and tracks" in caption
    assert "N(0, 0.3 m) per axis" in caption and "told σ = 0.3 m" in caption
    assert header[2] == "wrong ≥ 10× truth, final" and "ln MGR ≥ 2.30" in caption   # the paper's event, its scale
    # the MGR percentiles over every track, with no verdict where the difference's CI spans decades
    pop["paper_55"] = {"mgr": {"biased_randomized": {
        "n_targets": 12, "n_values": {"with_uncertainty": 480, "model_based": 480},
        "methods": {m: {"p75": est(0.2), "p95": est(v)} for m, v in (("with_uncertainty", 1.0), ("model_based", 3.0))},
        "paired": {"with_uncertainty-model_based": {"p95": {"value": -2.0, "ci_low": -30.6, "ci_high": 0.0},
                                                     "verdict": None, "no_verdict": "the 95 % CI spans 30.6 decades"}}}}}
    ctx, _ = _ctx(pop)
    ctx.ledger = Ledger()
    paper_setting(ctx, pop)
    _, header, rows, caption = ctx.page.items[1]
    assert rows[2][3] == "no verdict: the 95 % CI spans 30.6 decades" and "every track and realization" in caption
    assert not ctx.ledger.problems()
    pop["settings"] = pop["settings"][:1]
    ctx, sections = _ctx(pop)
    paper_setting(ctx, pop)
    assert sections == [] and ctx.page.items == []

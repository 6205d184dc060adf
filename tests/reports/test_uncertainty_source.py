"""The report's uncertainty-source section reads summary.json's domain_fit.uncertainty_source (as
``pipeline.evaluation.domain.source`` writes it) and words it: the numbers with their CIs, the
computed reading, the source of the MC samples and whether drop-connect was scored."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd

from pipeline.evaluation.domain import source as U
from reports.main.uncertainty_source import uncertainty_source_section


class _Page:
    def __init__(self):
        self.out = []

    def section(self, title, anchor=""):
        self.out.append(("section", title))

    def paragraph(self, text, **kw):
        self.out.append(("p", text))

    def table(self, header, rows, **kw):
        self.out.append(("table", rows, kw.get("caption", "")))


def _ctx(domain_fit: dict):
    page = _Page()
    return SimpleNamespace(population={"domain_fit": domain_fit}, page=page, sections=[],
                           section=lambda t, a: page.section(t, a)), page


def test_the_section_shows_the_computed_numbers_and_the_sources():
    rng = np.random.default_rng(0)
    s = rng.uniform(0.1, 2, 200)
    crops = pd.DataFrame({"instance": [f"c{i % 8}" for i in range(200)], "spread": s,
                          "abs_z": s * rng.uniform(0.5, 2.0, 200)})
    est = U.source_summary(crops, 200, 0)
    src = {**est, "reading": U.reading(est), "source": "MC dropout (p = 0.2)",
           "drop_connect": "not scored in this run (classifier drop-connect off): no second source to measure"}
    ctx, page = _ctx({"n_crops": 200, "uncertainty_source": src})
    uncertainty_source_section(ctx)
    kinds = [o[0] for o in page.out]
    assert kinds[0] == "section" and "table" in kinds
    rows = next(o for o in page.out if o[0] == "table")[1]
    w = est["within"]
    assert rows[0][1].value == w["rho"]["value"] and rows[0][1].low == w["rho"]["ci_low"]   # within-class first
    assert "stratification" in rows[0][0] and "stratification" in rows[1][0]
    assert rows[2][1].value == est["rho"]["value"] and "pooled across classes" in rows[2][0]   # labelled as such
    assert "median" in rows[0][2] and f"{w['rho_spread']['n_classes']} classes" in rows[0][2]
    text = " ".join(o[1] for o in page.out if o[0] == "p")
    assert U.reading(est) in text and "MC dropout (p = 0.2)" in text and "Drop-connect: not scored" in text


def test_no_block_no_section_and_too_few_crops_say_so():
    ctx, page = _ctx({"n_crops": 3})
    uncertainty_source_section(ctx)
    assert page.out == []
    ctx, page = _ctx({"uncertainty_source": {"n_crops": 2, "note": "fewer than 3 labelled crops"}})
    uncertainty_source_section(ctx)
    assert page.out[-1] == ("p", "Not measured: fewer than 3 labelled crops.")

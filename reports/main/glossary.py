"""The report's glossary: every term a reviewer meets on the page, in one place."""
from __future__ import annotations

from reports.main.context import ReportContext
from reports.shared.figures import MGR_SATURATION as SATURATION
from reports.shared.figures import MGR_SCALE_NOTE
from reports.shared.numbers import plain


def terms(ctx: ReportContext) -> list[tuple[str, str]]:
    card = ctx.run.card or {}
    comps = ("the classifier's output scores, one per texture family of the synthetic source domain it was "
             "trained on (" + str(card.get("num_classes", "?")) + " families): texture families, not objects"
             if card.get("weights") == "synthetic" else
             "the classifier's output scores (e.g. ImageNet classes), not the object instances")
    return [
        ("P(truth)", "the fused posterior probability of the ground-truth class after the views seen so far."),
        ("correct ratio", "share of realizations whose most probable class is the truth (final step, or over all "
                          "steps)."),
        ("MGR", "the paper's ratio max_c P(c) / P(truth): the factor by which the most probable class beats the "
                "truth; 1 when the truth is the most likely class, large when a method is confidently wrong."),
        ("log10 MGR", "log10 of MGR: 0 when the truth wins, 3 when a wrong class is 1000 times more probable. "
                      "Percentiles (75th, 95th) over realizations say how confidently wrong a method gets. "
                      f"Figures draw it on a {MGR_SCALE_NOTE}."),
        ("MSDE", "mean squared detection error: (1/C) Σ_c (P(c) − 1[c = truth])², 0 for a certain correct answer "
                 "(paper Eq. 44); lower is better."),
        ("target", "an object instance whose class is to be recognised; each has its own candidate classes."),
        ("track", "a path of views of one target in one AVD scan (start bearing, direction and distance differ)."),
        ("setting", "one localization-error condition: the biased experiment (a fixed pose shift) or a randomized "
                    "one (pose noise N(0, σ²) per view)."),
        ("realization", "one draw of the localization noise on a track; the biased setting has one."),
        ("cell", "one (target, track, setting): its metric is computed over its realizations; paired differences "
                 "and win shares are counted per cell."),
        ("pooled value", "the mean over targets of each target's mean over its tracks (each track averaged over "
                         "its settings)."),
        ("95 % CI", "a hierarchical bootstrap over targets, then tracks within targets (per target: over its "
                    "tracks; one track gives no CI). It does not cover classifier training runs."),
        ("better / worse / not distinguishable", "the paired difference's 95 % CI lies entirely on the good side / "
                                                 "the bad side of 0 / contains 0."),
        ("ceiling / floor", "cells where both methods sit at the best (e.g. correct ratio 1) or worst possible value: "
                            "they cannot tell the methods apart."),
        ("score component", comps + "; each class gets a GP per chosen component."),
        ("component rule", "how a target's few score components are chosen (by default the "
                           "components with the highest mean score over the candidates' training views; other "
                           "rules: the highest minimum score, the most informative about the target, or a fixed list)."),
        ("NLL", "negative log-likelihood of the truth, −ln P(truth): 0 for a certain correct answer, unbounded "
                "when a method is confidently wrong."),
        ("confident-error rate", "share of posteriors whose most probable class is wrong with a probability of at "
                                 f"least {_threshold(ctx)}."),
        ("ECE", "expected calibration error: the posteriors are binned by their largest probability (the "
                "confidence); ECE is the weighted mean gap between confidence and accuracy over the bins (0 = "
                "calibrated). The reliability diagram draws the bins."),
        ("PIT", "probability integral transform: each test score's place in its model's predictive distribution; "
                "flat when the model's spread is right, U-shaped when the residuals are wider than it says."),
        ("calibrated likelihood", "the GP likelihood with one extra variance per score component, estimated on "
                                  "labelled room crops by cross-fitting: each part of the data uses the estimate "
                                  "from the other parts only."),
        ("paired difference", "method minus baseline on the same (target, track, setting) cell, pooled like the "
                              "values; pairing removes what the cells share."),
        ("ablation", "the whole evaluation rerun with one setting changed, to measure what that setting does to the "
                     "verdict."),
        ("holds / fails / inconclusive", "a claim of the paper, read as a paired difference: its 95 % CI lies on "
                                         "the claimed side of 0 / on the other side / contains 0."),
        ("supported / not supported in this setting", "the same test outside the setting where the paper made the "
                                                      "claim (a question beyond the paper): a finding about this "
                                                      "setting, not a verdict on the paper's claim."),
        ("what the baselines read", "With Uncertainty, Model Based and the view-independent Gaussian read the same "
                                    "numbers (the GP score components); Simple Bayes reads other numbers: each "
                                    "candidate's own score. Only the view-independent Gaussian isolates modelling "
                                    "the viewpoint."),
        ("MC spread vs |z|", "how well a crop's MC-sample spread ranks its distance |z| from its class model: "
                             "Spearman ρ (0 = no rank relation) and the AUROC for |z| > 2 (0.5 = chance)."),
        ("numerical saturation", f"a log10 MGR above {plain(SATURATION)}: the truth's probability is below 1e−{plain(SATURATION)} "
                                 "of the winner's, far past what the fusion's floating point resolves; read it as "
                                 "'confidently wrong', not as a measured size."),
        ("showcase track", "the one track shown in detail (paper figures), chosen by a rule the results record "
                           "(the track where the methods disagree most)."),
    ]


def _threshold(ctx: ReportContext) -> str:
    t = (ctx.population or {}).get("confident_threshold") or (ctx.config.get("evaluate") or {}).get("confident_threshold")
    return plain(t) if t is not None else "the configured threshold"


def glossary_section(ctx: ReportContext) -> None:
    ctx.section("Glossary", "glossary")
    ctx.page.definitions(terms(ctx))

"""The paper's own numbers behind the main report's claims scorecard (Feldman & Indelman 2020), and
the claims themselves: one declaration, read by ``reports.main.scorecard``.

The numbers are facts transcribed in ``shared/paper/numbers.md`` (the paper's Tables 1-2, the §5.4
text and §5.5.2); each carries the section it comes from. Where the paper reports MGR, its scale
is the natural log (§5.4: a value of 20 reads as e^20); the report's is log10, so every MGR here
is the paper's value divided by ln 10 (``log10_of_ln``), with the paper's own value kept beside it.

The paper's tables report the rendered 3-D (UnrealEngine) experiments of §5.4, not AVD: §5.5 on
AVD gives a figure and one number. So a paper number is context for our AVD-style run, never the
threshold of a verdict: the verdict is computed from our interval alone.

This module is the ONE declaration of the paper's claims: the ones the main report's scorecard tests
on a run's population (``CLAIMS``) and the §5.3 statements the simulate stage tests on simulated
realizations (``SIMULATION_CLAIMS``; their statistics are computed in
``pipeline.evaluation.simulation.claims``). Each carries its section, a short phrase quoted from the
paper (as transcribed in ``shared/paper/numbers.md``) and where the paper made it (``MADE_IN``):
the §5.3 simulation, the §5.4 rendered scenes, or §5.5 real images (localization uncertainty only,
"assuming model uncertainty negligible", instance level). A run's setting (``run_setting``) decides
whether a test is the paper's claim in the paper's setting or a question beyond the paper.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pipeline.infra.datasets import described

LN10 = math.log(10.0)
TABLES_NOTE = ("The paper's Tables 1 and 2 report the rendered 3-D (UnrealEngine) experiments of §5.4: Table 1 "
               "300 random tracks among three furniture classes, Table 2 three hand-picked tracks under pose "
               "noise. §5.5 runs the method on AVD with BigBIRD models and reports a figure and one number "
               "(Model Based confidently wrong at the last step in about 10 % of runs). So the numbers in the "
               "'paper's number' column come from other scenes than ours and set no threshold: each names its "
               "section, and the paper's MGR (natural log) is converted to log10.")


def log10_of_ln(x: float) -> float:
    """A log MGR on the paper's natural-log scale, on ours (log10)."""
    return float(x) / LN10


@dataclass(frozen=True)
class PaperNumber:
    """One number of the paper: where it is, what it says, and (when it compares our two methods)
    the difference With Uncertainty − baseline in our units."""
    section: str
    text: str
    difference: float | None = None

    def cell(self) -> str:
        diff = "" if self.difference is None else f"; difference {self.difference:+.3g}"
        return f"{self.text}{diff} ({self.section})"


def _mgr(section: str, what: str, baseline: float, ours: float) -> PaperNumber:
    b, o = log10_of_ln(baseline), log10_of_ln(ours)
    return PaperNumber(section, f"{what}: Model Based {b:.3g}, ours {o:.3g} (paper, ln: {baseline:g} vs {ours:g})",
                       o - b)


def _cr(section: str, what: str, baseline: float, ours: float) -> PaperNumber:
    return PaperNumber(section, f"{what}: Model Based {baseline:g}, ours {ours:g}", ours - baseline)


# (section, the numbers) per claim key; the texts are ours, the values the paper's.
NUMBERS: dict[str, tuple[PaperNumber, ...]] = {
    "correct_similar": (
        _cr("§5.4.1, Table 1", "correct ratio, final step, 300 rendered tracks", 0.74, 0.76),
        _cr("§5.4.2, Table 2", "correct ratio, final step, hard track", 0.66, 0.72),
        _cr("§5.4.2, Table 2", "correct ratio, final step, moderate track", 0.958, 1.0),
        PaperNumber("§6", "conclusion: correct classification rates generally similar to the baseline"),
    ),
    "fewer_confident_errors": (
        PaperNumber("§5.4.1, Fig. 8", "rendered tracks: Model Based's P(truth) stays 0 at the end of about 25 % "
                                      "of tracks"),
    ),
    "paper_55": (
        PaperNumber("§5.5.2, Fig. 17", "one AVD track: Model Based ends with a wrong class about 10 times the "
                                       "correct class's probability in around 10 % of runs at the last step; "
                                       "ours (pose sampling only) classifies correctly", -0.10),
    ),
    "milder_worst_cases": (
        _mgr("§5.4.1, Table 1", "log10 MGR, final step, 95th percentile", 629.2, 2.46),
        _mgr("§5.4.2, Table 2", "log10 MGR, final step, 95th percentile, hard track", 48.6, 1.1),
    ),
    "beats_simple_bayes": (),   # Simple Bayes appears only in the §5.3 simulation, in words
}


# Where the paper made a claim, and the run settings that match it. A run on synthetic stand-ins is the
# analogue of the §5.3 simulation and §5.4 rendered scenes (known instance classes, modelled
# uncertainty); a real-imagery run on instance classes (COIL-100) is the analogue of §5.5; a
# category-level run (ETH-80, every test object unseen) matches nothing the paper tested (§6 names it a
# limitation).
MADE_IN = {
    "simulation": ("§5.3", "the MATLAB simulation, 3 hand-specified GP classes"),
    "rendered": ("§5.4", "rendered 3-D scenes, 3 instance classes"),
    "real": ("§5.5", "one real AVD track, BigBIRD instances as classes, localization uncertainty only, "
                     "'assuming model uncertainty negligible'"),
}
SETTINGS = {
    "synthetic": ("synthetic stand-ins (instance classes, modelled uncertainty)", ("simulation", "rendered")),
    "real_instance": ("real photographs, instance-level classes", ("real",)),
    "real_category": ("real photographs, category-level classes, every test object unseen", ()),
}


def run_setting(config: dict | None) -> str:
    """The setting of a run from its resolved config, as ``data.source``'s registered source declares
    it: rendered images are synthetic; photographs with category targets (real_imagery's ETH-80)
    category level; any other photographs (COIL-100 objects, BigBIRD instances on AVD, a source
    of one's own that declares neither) instance level."""

    data = (config or {}).get("data") or {}
    source = described(data.get("source") or "synthetic")
    if source.rendered:
        return "synthetic"
    return "real_category" if source.category_targets(data) else "real_instance"


def setting_label(setting: str) -> str:
    return SETTINGS[setting][0]


@dataclass(frozen=True)
class Claim:
    """One claim of the paper (in our words) and the paired comparison that tests it. ``reading``
    is "directional" (the CI of method − baseline on the claimed side of 0) or "equivalence" (the
    CI within ± the margin ``report.equivalence_margin_correct``: the paper's "similar").
    ``section`` and ``quote`` say where the paper says it (a short phrase; empty where the paper
    says it only in figures), ``made_in`` the settings of ``MADE_IN`` it was shown in (empty: the
    paper never claims it, so it is always a question beyond the paper), ``question`` how the row
    reads as a question outside those settings."""
    key: str
    text: str
    method: str
    baseline: str
    metric: str
    reading: str        # "directional" | "equivalence"
    how: str            # how we test it, for the page
    section: str = ""
    quote: str = ""
    made_in: tuple[str, ...] = ()
    question: str = ""
    unclaimed: str = ""     # why a claim with no ``made_in`` is not the paper's
    setting: str = "all"    # the localization setting its test reads ("all": every setting of the run)
    over_tracks: bool = False   # an MGR percentile read over every track (grid/paper55.py), not per cell

    @property
    def paper(self) -> tuple[PaperNumber, ...]:
        return NUMBERS.get(self.key, ())

    def in_setting(self, setting: str) -> bool:
        """Was the claim made in a setting this run's setting matches?"""
        return any(m in SETTINGS[setting][1] for m in self.made_in)

    def where(self) -> str:
        """Where the paper made it, in words ("" for a claim the paper does not make)."""
        return "; ".join(f"{MADE_IN[m][0]} {m}" for m in self.made_in)


CLAIMS = (
    Claim("correct_similar",
          "Modelling model and localization uncertainty keeps the correct-classification rate similar to Model "
          "Based's.", "with_uncertainty", "model_based", "correct_final", "equivalence",
          "paired difference of the correct ratio at the final step, With Uncertainty − Model Based, within "
          "± {margin:g} (equivalence: the whole 95 % CI inside the margin; the margin is viewfuse's choice, "
          "report.equivalence_margin_correct: the paper states none)",
          section="§5.4 Tables 1–2; §5.5.2 Fig. 17; §6", quote="generally similar",
          made_in=("rendered", "real"),
          question="Is the correct rate still similar to Model Based's here?"),
    Claim("fewer_confident_errors",
          "It is less often confidently wrong than Model Based, which trusts the pose estimate.",
          "with_uncertainty", "model_based", "confident_error_final", "directional",
          "paired difference of the confident-error rate at the final step, < 0",
          section="§5.3 Figs. 3, 5; §5.4.1 Fig. 8", quote="e^20 times higher probability assigned to wrong class",
          made_in=("simulation", "rendered"),
          question="Is it less often confidently wrong than Model Based here?"),
    Claim("paper_55",
          "On real images with model uncertainty assumed negligible, pose sampling alone (Eq. 42) ends with a wrong "
          "class 10 times the truth less often than Model Based.",
          "with_uncertainty_poses_only", "model_based", "wrong10_final", "directional",
          "paired difference of the share of runs ending with a wrong class at least 10 times the truth (log10 MGR "
          "≥ 1 at the final step; ln MGR ≥ 2.30 on the paper's scale), poses-only variant − Model Based, in the "
          "biased-plus-randomized setting, < 0",
          section="§5.5.2, Fig. 17", quote="in most cases both methods eventually deduce the correct class",
          made_in=("real",), setting="biased_randomized",
          question="Does pose sampling alone end with a ten-times wrong class less often than Model Based here?"),
    Claim("milder_worst_cases",
          "Its worst cases are milder: a lower MGR (how far a wrong class beats the truth) than Model Based.",
          "with_uncertainty", "model_based", "log10_mgr95_final", "directional",
          "paired difference of the 95th percentile of log10 MGR at the final step over every track and realization "
          "of each method, < 0; no verdict where its 95 % CI spans more than one decade",
          section="§5.4 Tables 1–2 (MGR, Eq. 45)", quote="e^20 times higher probability assigned to wrong class",
          made_in=("simulation", "rendered"), over_tracks=True,
          question="Are its worst cases milder than Model Based's here?"),
    Claim("beats_simple_bayes",
          "Modelling the viewpoint dependence beats the view-independent Simple Bayes baseline.",
          "with_uncertainty", "simple_bayes", "correct_final", "directional",
          "paired difference of the correct ratio at the final step, With Uncertainty − Simple Bayes, > 0",
          section="§5.3 text (Figs. 3, 5) only", quote="inverse",
          question="Does modelling the viewpoint beat Simple Bayes here?",
          unclaimed="the paper runs Simple Bayes only in the §5.3 simulation, where it drops at the 'inverse' "
                    "view and does well under a bias; it makes no claim on the correct ratio, and Simple Bayes "
                    "reads other numbers (each candidate's own score)"),
)


@dataclass(frozen=True)
class SimulationClaim:
    """One §5.3 statement of the paper (our wording of it, short phrases quoted), the statistic the
    simulate stage computes for it on simulated realizations, and the threshold it must pass."""
    key: str
    scenario: str               # "model_uncertainty" | "localization_bias"
    statement: str
    statistic: str              # what is computed, in words ("{step}", "{conf}" filled in)
    op: str                     # value <op> threshold = holds
    threshold: float
    section: str
    made_in: tuple[str, ...] = ("simulation",)


_MU, _LB = "model_uncertainty", "localization_bias"
SIMULATION_CLAIMS: tuple[SimulationClaim, ...] = (
    SimulationClaim("mb_low_at_step", _MU,
                    "model uncertainty, step 15: in more than 20 % of runs Model Based's P(truth) is below 0.2",
                    "share of realizations with Model Based's P(truth) < 0.2 at step {step}", ">", 0.20,
                    "§5.3, Fig. 3"),
    SimulationClaim("ours_p20_at_step", _MU,
                    "model uncertainty, step 15: our method's 20th percentile of P(truth) is above 0.33",
                    "20th percentile of With Uncertainty's P(truth) at step {step}", ">", 0.33, "§5.3, Fig. 3"),
    SimulationClaim("ours_more_correct", _MU,
                    "model uncertainty: our method chooses the correct class more often than Model Based",
                    "overall correct ratio, With Uncertainty − Model Based (mean over realizations of the "
                    "per-realization share of correct steps)", ">", 0.0, "§5.3, Fig. 3"),
    SimulationClaim("sb_poor_at_inverse", _MU,
                    "model uncertainty: Simple Bayes performs poorly where the \"inverse\" view is, around step 15",
                    "20th percentile of Simple Bayes' P(truth) at step {step} (poor: below 0.2)", "<", 0.20,
                    "§5.3, Fig. 3"),
    SimulationClaim("ours_graceful_bias", _LB,
                    "localization bias: our method accumulates evidence gracefully",
                    "share of realizations in which With Uncertainty makes a confident error (max P ≥ {conf:g} "
                    "on a wrong class) at some step (graceful: at most 5 %)", "<=", 0.05, "§5.3, Fig. 5"),
    SimulationClaim("sb_well_bias", _LB,
                    "localization bias: Simple Bayes performs well",
                    "Simple Bayes' correct ratio at the final step (well: at least 0.9)", ">=", 0.90,
                    "§5.3, Fig. 5"),
)

"""The file names each stage writes into its folder, declared once.

Every module that writes or reads a stage's output takes the name from here (``name("evaluate",
"results")``) instead of retyping it; ``stages.registry`` attaches the table to the stage specs.
It lives on the bottom floor so that ``reports/`` and ``pipeline/`` can use it too.
"""
from __future__ import annotations

OUTPUTS: dict[str, dict[str, str]] = {
    "data": {"roots": "roots.json", "truth": "truth.json", "bigbird": "bigbird", "avd": "avd"},
    "classifier": {"card": "card.json", "weights": "weights.npz"},
    "features": {"bigbird": "bigbird.parquet", "avd": "avd.parquet"},
    "models": {"index": "index.json", "dirichlet": "dirichlet"},  # dirichlet/: index.json + theta.npz
    "evaluate": {"results": "results.parquet", "summary": "summary.json", "track": "track.json",
                 "gp_models": "gp_models.npz", "bias_maps": "bias_maps.npz"},
    "report": {"html": "index.html"},
    "simulate": {"results": "results.parquet", "example": "example.parquet", "summary": "summary.json",
                 "models": "models", "html": "index.html"},
}

MANIFEST = "manifest.json"  # written by the stage runner beside every stage's outputs


def name(stage: str, key: str) -> str:
    """The file (or folder) name of output ``key`` of ``stage``; KeyError names what exists."""
    try:
        return OUTPUTS[stage][key]
    except KeyError:
        known = ", ".join(OUTPUTS.get(stage, {})) or "none"
        raise KeyError(f"stage {stage!r} declares no output {key!r} (declared: {known})") from None

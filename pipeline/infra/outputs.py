"""The data catalog: every artifact a stage writes, declared once with its reader and writer.

Every module that writes or reads a stage's output takes the name from here (``name("evaluate",
"results")``, ``path(folder, "evaluate", "results")``) instead of retyping it; the stage runner
(``stages.framework.runner``) refuses a stage whose folder holds a file that no entry here declares, and
``tests/test_catalog.py`` fails on a literal artifact file name anywhere else in the packages.

An entry's ``name`` is a file or folder name, or a glob pattern for a family (``*.png`` figures,
one ``.npz`` per class). ``writer`` and ``reader`` name the one function that writes and the one
that reads the artifact (``module:function``; the test imports each). This module sits in the
infrastructure room and imports nothing of the project, so every floor can use it.
"""
from __future__ import annotations

import fnmatch
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class Artifact:
    name: str                 # file or folder name, or a glob pattern
    format: str               # json | parquet | npz | folder | html | png | text
    writer: str               # "module:function" that writes it
    reader: str | None        # "module:function" that reads it (None: read by people only)
    doc: str = ""

    @property
    def pattern(self) -> bool:
        return any(c in self.name for c in "*?[")


_JSON_W = "pipeline.infra.cache:write_json"
_JSON_R = "pipeline.infra.outputs:read"
_RESULTS_W = "pipeline.evaluation.metrics.results:write_results"
_STREAM_W = "pipeline.evaluation.metrics.results:ResultsWriter"   # streamed one cell at a time
_RESULTS_R = "reports.shared.artifacts:read_result_table"
_BANK_W = "pipeline.method.gp_files:save_bank"
_BANK_R = "pipeline.method.gp_files:load_bank"

CATALOG: dict[str, dict[str, Artifact]] = {
    "data": {
        "roots": Artifact("roots.json", "json", _JSON_W, "stages.framework.roots:data_roots", "where the datasets are"),
        "truth": Artifact("truth.json", "json", _JSON_W, "pipeline.evaluation.grid.population:truth_entry",
                          "synthetic ground truth: instance positions and yaws per scan"),
        "bigbird": Artifact("bigbird", "folder", "loaders.synthetic.bigbird_writer:write_bigbird_object",
                            "loaders.bigbird:BigBirdObject", "BigBIRD on-disk format"),
        "avd": Artifact("avd", "folder", "loaders.synthetic.avd_writer:write_avd_scan", "loaders.avd:AVDScan",
                        "AVD on-disk format"),
    },
    "classifier": {
        "card": Artifact("card.json", "json", _JSON_W, "pipeline.scoring.card:read_card",
                         "architecture, weights hash, output names, held-out accuracy"),
        "weights": Artifact("weights.npz", "npz", "pipeline.scoring.weight_files:save_state_dict_npz",
                            "pipeline.scoring.card:load_classifier", "state dict, no pickles"),
    },
    "features": {
        "bigbird": Artifact("bigbird.parquet", "parquet", "pipeline.scoring.features:write_table",
                            "pipeline.scoring.features:read_features", "BigBIRD view scores"),
        "avd": Artifact("avd.parquet", "parquet", "pipeline.scoring.features:write_table",
                        "pipeline.scoring.features:read_features", "AVD box scores"),
    },
    "models": {
        "index": Artifact("index.json", "json", _BANK_W, _BANK_R, "a model bank's index"),
        "bank": Artifact("*.npz", "npz", _BANK_W, _BANK_R, "one GP class model per file"),
        "ablations": Artifact("ablations", "folder", _BANK_W, _BANK_R, "one model bank per ablation"),
        "contrast": Artifact("contrast", "folder", _BANK_W, _BANK_R,
                             "the instance arm of the class-level contrast (data.real_imagery.contrast): its "
                             "model bank and its methods' own models"),
        # one folder per model provider a registered method needs (pipeline/method/provider.py), named by its key
        "provided": Artifact("*", "folder", "pipeline.method.provider:ModelProvider.save",
                             "pipeline.method.provider:ModelProvider.load", "a method's own models, one folder each"),
    },
    "evaluate": {
        "results": Artifact("results.parquet", "parquet", _STREAM_W, _RESULTS_R,
                            "one row per (cell, setting, realization, step, method)"),
        "summary": Artifact("summary.json", "json", _JSON_W, _JSON_R, "population statistics and verdict"),
        "track": Artifact("track.json", "json", _JSON_W, _JSON_R, "the detailed track"),
        "gp_models": Artifact("gp_models.npz", "npz", "stages.evaluate:single_track", "reports.shared.artifacts:read_npz",
                              "GP rasters of the detailed track's candidates"),
        "bias_maps": Artifact("bias_maps.npz", "npz", "stages.evaluate:single_track", "reports.shared.artifacts:read_npz",
                              "single-view posteriors under a grid of biases"),
        "planning": Artifact("planning.parquet", "parquet", "pipeline.planning.evaluation:write_table",
                             "pipeline.planning.evaluation:read_table",
                             "view planning: one row per (target, start, setting, planner, step)"),
    },
    "report": {
        "html": Artifact("index.html", "html", "reports.main.page:build_main_report", None),
        "figures": Artifact("*.png", "png", "reports.shared.figures:save", None),
    },
    "simulate": {
        "results": Artifact("results.parquet", "parquet", _RESULTS_W, _RESULTS_R,
                            "one row per (scenario, realization, step, method)"),
        "example": Artifact("example.parquet", "parquet", _RESULTS_W, _RESULTS_R, "the example realization"),
        "summary": Artifact("summary.json", "json", _JSON_W, _JSON_R, "tables, findings, GP fits"),
        "models": Artifact("models", "folder", _BANK_W, _BANK_R, "the fitted simulation GPs"),
        "html": Artifact("index.html", "html", "reports.simulate.page:build_simulate_report", None),
        "figures": Artifact("*.png", "png", "reports.shared.figures:save", None),
    },
    # Not a stage: ``viewfuse compare`` writes its page into <first run>/compare/ (or --out).
    "compare": {
        "html": Artifact("index.html", "html", "reports.compare.page:write_page", None,
                         "finished runs side by side (config diff, pooled metrics, verdicts)"),
    },
    # Not a stage: ``viewfuse study`` writes these into <run>/study/ beside the seed folders.
    "study": {
        "summary": Artifact("summary.json", "json", _JSON_W, _JSON_R, "per-seed results side by side"),
        "html": Artifact("index.html", "html", "reports.study.page:render_html", None),
        "seeds": Artifact("seed-*", "folder", "stages.commands.study:run_study", None, "one run folder per seed"),
    },
}

MANIFEST = "manifest.json"  # written by the stage runner beside every stage's outputs

# The name tables, for code that only needs names.
OUTPUTS: dict[str, dict[str, str]] = {s: {k: a.name for k, a in arts.items()} for s, arts in CATALOG.items()}


def artifact(stage: str, key: str) -> Artifact:
    """The declaration of output ``key`` of ``stage``; KeyError names what exists."""
    try:
        return CATALOG[stage][key]
    except KeyError:
        known = ", ".join(CATALOG.get(stage, {})) or "none"
        raise KeyError(f"stage {stage!r} declares no output {key!r} (declared: {known})") from None


def name(stage: str, key: str) -> str:
    """The file (or folder) name of output ``key`` of ``stage``."""
    a = artifact(stage, key)
    if a.pattern:
        raise KeyError(f"output {key!r} of stage {stage!r} is a family ({a.name}), not one name")
    return a.name


def path(folder: str | Path, stage: str, key: str) -> Path:
    """``folder / name(stage, key)``: where output ``key`` of ``stage`` lies in its stage folder."""
    return Path(folder) / name(stage, key)


def declared(stage: str, relpath: str) -> bool:
    """Whether a file at ``relpath`` (posix, relative to the stage folder) is a declared output:
    its top-level component matches an entry (a folder entry covers everything inside it)."""
    top = relpath.split("/", 1)[0]
    for a in CATALOG.get(stage, {}).values():
        inside = "/" in relpath
        if inside and a.format != "folder" or a.format == "folder" and a.pattern and not inside:
            continue   # a file entry holds nothing; a family of folders declares no top-level file
        if fnmatch.fnmatchcase(top, a.name):
            return True
    return top == MANIFEST and "/" not in relpath


def undeclared(stage: str, relpaths) -> list[str]:
    """The paths among ``relpaths`` that no catalog entry of ``stage`` declares."""
    return sorted(p for p in relpaths if not declared(stage, p))


class ArtifactError(ValueError):
    """An artifact that cannot be read as its entry says (not UTF-8, not valid JSON); the message
    starts with the file's path."""

    def __init__(self, path: str | Path, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{path}: {problem}")


_RAISE = object()


def read_json(p: str | Path, *, missing: Any = _RAISE, invalid: Any = _RAISE) -> Any:
    """The one reader of a JSON artifact or manifest: its parsed content. An absent file raises
    ``FileNotFoundError`` (or gives ``missing``), one that is not UTF-8 JSON ``ArtifactError``
    naming it (or gives ``invalid``: a caller for which such a file counts as not written)."""
    p = Path(p)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        if missing is _RAISE:
            raise
        return missing
    except UnicodeDecodeError:
        if invalid is _RAISE:
            raise ArtifactError(p, "not valid JSON: not UTF-8 text") from None
        return invalid
    except OSError as e:  # a failed read() (EIO) names no file (as cache.naming; cache imports this module)
        if e.errno is None or e.filename:
            raise
        raise OSError(e.errno, e.strerror, str(p)) from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        if invalid is _RAISE:
            raise ArtifactError(p, f"not valid JSON: {e}") from None
        return invalid


def read(folder: str | Path, stage: str, key: str, **kw) -> Any:
    """JSON output ``key`` of ``stage`` from its stage ``folder``, by ``read_json`` (same keywords)."""
    a = artifact(stage, key)
    if a.format != "json":
        raise KeyError(f"output {key!r} of stage {stage!r} is {a.format}, not JSON: read it with {a.reader}")
    return read_json(path(folder, stage, key), **kw)


def read_manifest(folder: str | Path, **kw) -> Any:
    """The manifest the stage runner wrote in a stage ``folder``, by ``read_json`` (same keywords)."""
    return read_json(Path(folder) / MANIFEST, **kw)


def number(x: Any, null: float | None = math.nan, bad: float | None = math.nan, *,
           finite: bool = False) -> float | None:
    """The one reader of a number in a JSON artifact. JSON has no infinity or NaN (the writer,
    ``pipeline.infra.cache.write_json``, stores them as null), so a null reads as ``null`` (the
    caller knows what it stands for: an unbounded interval end is +-inf, a missing value NaN or
    None); anything that is no number, NaN included (and with ``finite`` an infinity: a figure
    cannot draw it), reads as ``bad``."""
    if x is None:
        return null
    try:
        v = float(x)
    except (TypeError, ValueError):
        return bad
    return bad if math.isnan(v) or (finite and math.isinf(v)) else v

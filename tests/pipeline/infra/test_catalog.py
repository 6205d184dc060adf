"""The data catalog (pipeline/infra/outputs.py): every artifact declared once, with a reader and a
writer that exist, and no artifact file name typed anywhere else in the packages."""
import importlib
import re
from pathlib import Path

import pytest

from pipeline.infra import outputs
from stages.framework.registry import STAGES

ROOT = Path(__file__).resolve().parents[3]
PACKAGES = ("pipeline", "stages", "reports", "loaders")


def _resolve(ref: str):
    module, _, attr = ref.partition(":")
    obj = importlib.import_module(module)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


def test_every_reader_and_writer_exists():
    for stage, arts in outputs.CATALOG.items():
        for key, a in arts.items():
            assert callable(_resolve(a.writer)), (stage, key, a.writer)
            if a.reader is not None:
                assert callable(_resolve(a.reader)), (stage, key, a.reader)
            assert a.format in ("json", "parquet", "npz", "folder", "html", "png", "text"), (stage, key)


def test_every_stage_has_catalog_entries_and_names_resolve():
    assert set(STAGES) <= set(outputs.CATALOG)
    assert outputs.name("evaluate", "results") == "results.parquet"
    assert outputs.path("/r/evaluate", "evaluate", "summary") == Path("/r/evaluate/summary.json")
    with pytest.raises(KeyError, match="declares no output 'nope'.*declared: results"):
        outputs.name("evaluate", "nope")
    with pytest.raises(KeyError, match="is a family"):
        outputs.name("report", "figures")


def test_declared_matches_names_patterns_and_folders():
    assert outputs.declared("evaluate", "results.parquet") and outputs.declared("report", "track.png")
    assert outputs.declared("models", "ablations/top_min/index.json") and outputs.declared("models", "syrup.npz")
    assert outputs.declared("data", "bigbird/obj/NP1_0.jpg")
    assert not outputs.declared("evaluate", "scratch.txt")
    assert not outputs.declared("evaluate", "results.parquet/x")      # a file entry holds nothing inside
    assert outputs.undeclared("evaluate", ["summary.json", "tmp.bin"]) == ["tmp.bin"]


def _literal_hits(names, root=ROOT):
    pat = re.compile(r"""(["'])(%s)\1""" % "|".join(re.escape(n) for n in sorted(names)))
    hits = []
    for pkg in PACKAGES:
        for f in sorted((root / pkg).rglob("*.py")):
            if f == root / "pipeline" / "infra" / "outputs.py":
                continue
            for i, line in enumerate(f.read_text().splitlines(), 1):
                if pat.search(line):
                    hits.append(f"{f.relative_to(root)}:{i}: {line.strip()}")
    return hits


def test_no_literal_artifact_file_name_outside_the_catalog():
    names = {a.name for arts in outputs.CATALOG.values() for a in arts.values()
             if not a.pattern and a.format != "folder"} | {outputs.MANIFEST}
    assert _literal_hits(names) == []


def test_the_literal_name_check_catches_a_planted_name(tmp_path):
    for pkg in PACKAGES:
        (tmp_path / pkg).mkdir()
    (tmp_path / "stages" / "x.py").write_text('p = d / "results.parquet"\nq = "results.parquet is fine in prose"\n')
    (tmp_path / "pipeline" / "infra").mkdir()
    (tmp_path / "pipeline" / "infra" / "outputs.py").write_text('n = "results.parquet"\n')
    assert _literal_hits({"results.parquet"}, tmp_path) == ['stages/x.py:1: p = d / "results.parquet"']


def test_the_one_json_number_reader():
    """null stands for what the caller says (an unbounded end, a missing value); a non-number and
    NaN are 'bad'; with ``finite`` an infinity is too."""
    import math

    from pipeline.infra.outputs import number

    assert number(None, -math.inf) == -math.inf and number(None, None) is None and math.isnan(number(None))
    assert number("0.25") == 0.25 and number(3) == 3.0 and number(math.inf) == math.inf
    assert number("x", bad=None) is None and number([1], bad=7.0) == 7.0 and number(math.nan, bad=None) is None
    assert number(math.inf, bad=0.0, finite=True) == 0.0 and number(-1.5, finite=True) == -1.5


# Where JSON text may be parsed outside the catalog's one reader: strings inside Parquet metadata,
# the compare command's size-bounded reader of runs it did not write, and the datasets' own files.
JSON_PARSERS = {"pipeline/infra/outputs.py", "pipeline/banks/model_bank.py", "reports/shared/artifacts.py",
                "reports/compare/read.py", "loaders/avd.py", "loaders/real_imagery/scans.py"}


def test_artifacts_are_read_through_the_catalog_only():
    hits = [f"{f.relative_to(ROOT)}:{i}" for pkg in PACKAGES for f in sorted((ROOT / pkg).rglob("*.py"))
            if str(f.relative_to(ROOT)) not in JSON_PARSERS
            for i, line in enumerate(f.read_text().splitlines(), 1) if re.search(r"\bjson\.loads?\(", line)]
    assert not hits, f"parse artifacts with pipeline.infra.outputs.read / read_json: {hits}"


def test_the_one_json_reader_names_the_file_and_says_what_is_missing(tmp_path):
    p = outputs.path(tmp_path, "evaluate", "summary")
    with pytest.raises(FileNotFoundError):
        outputs.read(tmp_path, "evaluate", "summary")
    assert outputs.read(tmp_path, "evaluate", "summary", missing=None) is None
    p.write_text("{not json")
    with pytest.raises(outputs.ArtifactError, match=r"summary\.json: not valid JSON"):
        outputs.read(tmp_path, "evaluate", "summary", missing=None)
    assert outputs.read(tmp_path, "evaluate", "summary", invalid={}) == {}
    p.write_text('{"a": null}')
    assert outputs.read(tmp_path, "evaluate", "summary") == {"a": None}
    with pytest.raises(KeyError, match="parquet, not JSON"):
        outputs.read(tmp_path, "evaluate", "results")

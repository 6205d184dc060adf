"""Repository rules: test-only helpers live in tests/, comments cite files inside the repository."""
from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_test_only_helpers_are_not_in_the_package():
    import pipeline.scoring.mc_dropout
    import pipeline.scoring.features
    import pipeline.method.fusion
    import pipeline.evaluation.metrics.spec
    import pipeline.evaluation.simulation.scenarios
    import pipeline.evaluation.grid.track
    import pipeline.infra.executor

    assert not (ROOT / "pipeline" / "methods.py").exists()
    for mod, name in ((pipeline.scoring.mc_dropout, "full_passes_with_masks"), (pipeline.method.fusion, "fuse_with_uncertainty_sampled"),
                      (pipeline.evaluation.metrics.spec, "summary_table"), (pipeline.scoring.features, "meta_columns"),
                      (pipeline.evaluation.grid.track, "select_track"), (pipeline.evaluation.simulation.scenarios, "conditional"),
                      (pipeline.infra.executor, "preload")):
        assert not hasattr(mod, name), f"{mod.__name__}.{name}"
    import stages.framework.runner
    assert not hasattr(stages.framework.runner, "StageNotImplemented")


def test_no_citations_of_files_outside_the_repository():
    import re

    bad = []
    files = [ROOT / "README.md", *(ROOT / "configs").glob("*.toml")]
    for d in ("pipeline", "loaders", "stages", "reports", "tests"):
        files += sorted((ROOT / d).rglob("*.py"))
    outside = re.compile(r"DESIGN §|/work/shared|(?<![\w/])formats/")
    for path in files:
        for no, line in enumerate(path.read_text().splitlines(), start=1):
            if outside.search(line) and "outside = re.compile" not in line:
                bad.append(f"{path.relative_to(ROOT)}:{no}: {line.strip()}")
    assert not bad, "citations of files outside the repository:\n" + "\n".join(bad)
    for cited in ("docs/design.md", "docs/formats/avd.md", "docs/formats/bigbird.md",
                  "docs/formats/avd_instance_id_map.txt"):
        assert (ROOT / cited).is_file(), cited

"""What the report says of the data is the dataset source's declaration, not a comparison with the
built-ins' names: a package outside the repository adds two sources through ``viewfuse.datasets``
(one that renders its images, one of photographs whose targets are unseen categories), and the
report's "What was evaluated" sentence, its limits, the scorecard's setting and the check of
``evaluate.statistics.cluster = 'category'`` follow what each declares (docs/extending.md, "A dataset")."""
from __future__ import annotations

import json

import pytest

from tests.support.outside_package import run_with, write_package

MODULE = '''
import dataclasses

import viewfuse as vf


@dataclasses.dataclass(frozen=True)
class ShelfConfig:                 # [data.outside_photos], its fields of the public vf.setting
    unseen: bool = vf.setting(False, doc="every scored object is one no class model has seen")


class RenderedShelf(vf.DatasetSource):
    name = "outside_rendered"
    label = "rendered shelves of a test package (no photographs)"
    badge = "rendered test data"
    rendered = True


class ShelfPhotos(vf.DatasetSource):
    name = "outside_photos"
    doc = "shelf photographs of a test package"
    config = ShelfConfig

    def category_targets(self, data):
        return bool((data.get("outside_photos") or {}).get("unseen"))
'''

ENTRY_POINTS = {"viewfuse.datasets": {"outside_rendered": "vf_sources:RenderedShelf",
                                      "outside_photos": "vf_sources:ShelfPhotos"}}

PROBE = '''
import json
from types import SimpleNamespace
from pipeline.evaluation.metrics.paper import run_setting
from pipeline.infra.config import ConfigError, load_config
from reports.main.context import ReportContext
from reports.main.reviewer import limitations
from reports.main.verdict import context_sentence

RENDERED = "The images are synthetic stand-ins rendered"
out = {}
for name, data in (("outside_rendered", {}), ("outside_photos", {}), ("outside_photos", {"unseen": True}),
                   ("synthetic", {})):
    config = {"data": {"source": name, name: data}}
    ctx = ReportContext(page=None, config=config, run=SimpleNamespace(
        manifests={"data": {"extra": {}}}, card=None, run_dir=".", evaluate=SimpleNamespace(population=None, target="t")))
    out[name + ("_unseen" if data else "")] = {
        "what": context_sentence(ctx), "badge": ctx.source.badge,
        "rendered_note": any(line.startswith(RENDERED) for line in limitations(ctx)), "setting": run_setting(config)}
refused = {}
for name, own in (("outside_rendered", {}), ("outside_photos", {}), ("outside_photos_unseen", {"unseen": True})):
    source = name.replace("_unseen", "")
    try:
        load_config(SMOKE, {"data": {"source": source, **({source: own} if own else {})},
                            "evaluate": {"statistics": {"cluster": "category"}}})
        refused[name] = ""
    except ConfigError as e:
        refused[name] = str(e)
out["refused"] = refused
print("PROBE " + json.dumps(out))
'''


@pytest.fixture(scope="module")
def probe(tmp_path_factory) -> dict:
    from tests.conftest import ROOT

    tmp = tmp_path_factory.mktemp("outside_sources")
    site = write_package(tmp / "site", "vf_sources", MODULE, ENTRY_POINTS)
    r = run_with(site, f"SMOKE = {str(ROOT / 'configs' / 'smoke.toml')!r}\n" + PROBE, tmp)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(next(line for line in r.stdout.splitlines() if line.startswith("PROBE "))[6:])


def test_the_report_says_what_each_source_declares(probe):
    rendered, photos = probe["outside_rendered"], probe["outside_photos"]
    assert "What was evaluated: rendered shelves of a test package (no photographs);" in rendered["what"]
    assert "What was evaluated: shelf photographs of a test package;" in photos["what"]   # its doc, no label
    assert rendered["badge"] == "rendered test data" and photos["badge"] == ""
    # the note that the paper's numbers are not expected: for rendered images, whatever the source's name
    assert rendered["rendered_note"] and not photos["rendered_note"] and probe["synthetic"]["rendered_note"]


def test_the_scorecards_setting_follows_the_declared_properties(probe):
    assert probe["outside_rendered"]["setting"] == "synthetic"
    assert probe["outside_photos"]["setting"] == "real_instance"
    assert probe["outside_photos_unseen"]["setting"] == "real_category"


def test_a_category_cluster_needs_a_source_that_declares_category_targets(probe):
    assert "'evaluate.statistics.cluster' = 'category' needs category targets" in probe["refused"]["outside_rendered"]
    assert "'evaluate.statistics.cluster' = 'category' needs category targets" in probe["refused"]["outside_photos"]
    assert probe["refused"]["outside_photos_unseen"] == ""      # [data.outside_photos] unseen = true declares them

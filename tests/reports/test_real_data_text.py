"""The report's data lines for real imagery: the background of each side and the uniform box fit,
read from the data stage's manifest (what the writer measured), never a fixed sentence."""
from __future__ import annotations

from types import SimpleNamespace

from loaders.sources.real_imagery import backgrounds
from reports.main.reviewer import box_fit_text
from reports.main.verdict import context_sentence


def _ctx(dataset="eth80", extra=None, **ri):
    return SimpleNamespace(data_source="real_imagery",
                           config={"data": {"real_imagery": {"dataset": dataset, **ri}}},
                           run=SimpleNamespace(manifests={"data": {"extra": extra or {}}}))


def background_text(ctx) -> str:
    return backgrounds(ctx.config["data"]["real_imagery"], ctx.run.manifests["data"]["extra"])


def test_each_side_background_is_named_and_a_mismatch_said():
    assert background_text(_ctx("coil")) == "backgrounds: COIL-100's own black on both sides"
    same = _ctx(extra={"background": {"frames": "avd_frames", "training": "avd_frames"}})
    assert background_text(same) == "backgrounds: frames and training views alike cut out onto real AVD clutter"
    cloth = background_text(_ctx(extra={"background": {"frames": "black", "training": "original"}}))
    assert "frames cut out onto black" in cloth and "blue cloth" in cloth and "deliberate mismatch" in cloth
    # an older manifest without the record: the config's keys
    assert "alike cut out onto black" in background_text(_ctx(background="black", train_background="same"))
    # COIL cut out over clutter, the training photographs extended with it
    coil = background_text(_ctx("coil", extra={"background": {"frames": "avd_frames", "training": "avd_frames",
                                                              "train_pad": "surround"}}))
    assert coil.startswith("backgrounds: frames and training views alike cut out onto real AVD clutter")
    assert "no training crop is padded" in coil


def _sentence(source: str, **data) -> str:
    from reports.main.context import ReportContext

    ctx = ReportContext(page=None, run=SimpleNamespace(manifests={"data": {"extra": {}}}, card=None,
                                                       evaluate=SimpleNamespace(population=None, target="t")),
                        config={"data": {"source": source, **data}})
    return context_sentence(ctx)


def test_what_was_evaluated_is_the_sources_own_wording():
    coil = _sentence("real_imagery", real_imagery={"dataset": "coil"})
    assert "COIL-100 photographs" in coil and coil.count("backgrounds: COIL-100's own black") == 1
    eth = _sentence("real_imagery", real_imagery={"dataset": "eth80", "class_level": "category"})
    assert "ETH-80 photographs" in eth and "no class model has seen" in eth and "backgrounds: frames" in eth
    assert "stand-ins rendered in the BigBIRD and AVD formats" in _sentence("synthetic")
    assert "backgrounds" not in _sentence("synthetic") and "real data (BigBIRD + AVD)" in _sentence("real")
    assert "data source 'gone'" in _sentence("gone")       # a source not registered here: named


def test_box_fit_line_reads_the_measured_distribution():
    assert box_fit_text(_ctx()) is None
    bf = {"frames": 309, "fill": {"median": 0.2987, "p5": 0.1505, "p95": 0.5781},
          "scale": {"median": 0.3828, "p5": 0.2445, "p95": 1.0054}, "share_fill_below_0_5": 0.822}
    text = box_fit_text(_ctx(extra={"box_fit": bf}))
    assert "over 309 frames" in text and "median 0.2987" in text and "0.1505-0.5781" in text and "82 %" in text
    assert "never stretched" in text

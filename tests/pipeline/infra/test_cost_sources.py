"""The cost model for every dataset source (pipeline/infra/cost.py, ``DatasetSource.work``): the
data and features estimates come from the views and crops the source says its config makes, so a
real-imagery config too large for ``run.max_minutes`` is refused before the data stage, naming the
keys; a source that says nothing is logged "not estimated", never a silent 0. None of these reads
real data (the refusal comes before it)."""
from __future__ import annotations

import dataclasses
import logging

import pytest

from pipeline.infra import cost
from pipeline.infra.config import load_config
from stages.commands.cli import main
from tests.conftest import ROOT

REAL = sorted((ROOT / "configs").glob("real*.toml"))


@pytest.mark.parametrize("path", REAL, ids=lambda p: p.name)
def test_every_real_config_passes_at_the_default_limit_and_is_estimated(path):
    cfg = load_config(path)
    assert cfg.run.max_minutes == 120
    for stage in cost.ESTIMATORS:
        cost.check(cfg, stage)                      # not refused
    data, feats = cost.estimate(cfg, "data"), cost.estimate(cfg, "features")
    assert not [t for t in data.terms + feats.terms if "not estimated" in t.what]
    assert data.seconds > 10 and feats.seconds > 30     # photographs written and scored: not 0


def test_real_full_is_estimated_near_what_it_took():
    # measured (docs/results.md): data 4.3 min, features 10.8 min (2,830 views + 12,440 crops)
    cfg = load_config(ROOT / "configs" / "real_full.toml")
    assert 60 < cost.estimate(cfg, "data").seconds < 20 * 60
    assert 3 * 60 < cost.estimate(cfg, "features").seconds < 40 * 60


def test_the_counts_follow_the_keys():
    cfg = load_config(ROOT / "configs" / "real.toml")
    ri = cfg.data.real_imagery

    def views(**kw):
        c = dataclasses.replace(cfg, data=dataclasses.replace(cfg.data, real_imagery=dataclasses.replace(ri, **kw)))
        return cost.source_work(c)

    assert views().training_views == 12 * 36                     # 12 objects every 10 degrees
    assert views(train_step_deg=20).training_views == 12 * 18
    eth = views(dataset="eth80", categories=("apple", "cup", "dog"), instances=(1, 2, 3, 4))
    assert eth.training_views == 3 * 4 * 16                       # the equatorial ring's 16 azimuths
    assert views(dataset="eth80", categories=("apple", "cup", "dog"), instances=(1, 2, 3, 4),
                 view_split="alternate").training_views == 3 * 4 * 8
    assert views(frames="all").test_crops > views().test_crops
    more = dataclasses.replace(cfg, data=dataclasses.replace(cfg.data, scans=cfg.data.scans * 3))
    assert cost.source_work(more).test_crops == 3 * views().test_crops
    assert cost.estimate(more, "features").seconds > 2 * cost.estimate(cfg, "features").seconds


@pytest.mark.parametrize("stage, sets, keys", [
    ("data", {"run.max_minutes": 1}, ("data.real_imagery.objects", "data.real_imagery.train_step_deg", "data.scans")),
    ("features", {"features.n_samples": 1000}, ("features.n_samples", "data.scans", "data.real_imagery.frames")),
], ids=["data", "features"])
def test_an_over_budget_real_imagery_config_is_refused_before_the_data_stage(tmp_path, capsys, stage, sets, keys):
    args = ["features", "--config", str(ROOT / "configs" / "real_full.toml"), "--set", f"run.artifacts={tmp_path}",
            "--set", "data.coil_root='/nonexistent/coil'", "--set", "data.avd_root='/nonexistent/avd'"]
    for k, v in sets.items():
        args += ["--set", f"{k}={v}"]
    rc = main(args)
    err = capsys.readouterr().err
    assert rc == 2, err
    line = [ln for ln in err.splitlines() if "config error" in ln][0]
    assert f"the {stage} stage would take about" in line and "'run.max_minutes' = " in line
    for k in keys:
        assert f"'{k}' = " in line, (k, line)
    assert not (tmp_path / "real_full" / "data").exists()      # refused before any stage ran


def test_a_source_that_says_nothing_is_logged_not_estimated(caplog):
    import viewfuse as vf
    from pipeline.infra.datasets import unregister_dataset

    @vf.register_dataset
    class Quiet(vf.DatasetSource):
        name = "quiet_source"

        def write(self, ctx):   # pragma: no cover - never run here
            return ""

    try:
        cfg = load_config(ROOT / "configs" / "synthetic.toml", {"data": {"source": "quiet_source"}})
        cost._UNESTIMATED.clear()
        with caplog.at_level(logging.INFO, logger="viewfuse"):
            data, feats = cost.check(cfg, "data"), cost.check(cfg, "features")
        # nothing but each stage's fixed work (cost.FIXED_S)
        assert data.seconds == cost.FIXED_S["data"] and feats.seconds == cost.FIXED_S["features"]
        said = [t.what for t in data.terms[1:] + feats.terms[1:]]
        assert len(said) == 3 and all("not estimated (data.source = 'quiet_source'" in w for w in said)
        logged = [r.getMessage() for r in caplog.records if "not estimated" in r.getMessage()]
        assert len(logged) == 3 and logged[0].startswith("data stage: writing the run data")
        # the boxes the features stage finds replace the unknown count
        found = cost.estimate(cfg, "features", cost.Counts(avd_crops=500))
        assert any(t.what.startswith("scoring 500 AVD boxes") and t.seconds > 0 for t in found.terms)
    finally:
        unregister_dataset("quiet_source")


def test_the_models_estimate_follows_the_views_a_source_fits_a_class_on():
    import viewfuse as vf
    from pipeline.infra.datasets import unregister_dataset

    class Declared(vf.DatasetSource):
        name = "views_per_class_source"
        per_class = None                 # set below; None: work() says nothing at all

        def work(self, cfg):
            return None if self.per_class is None else vf.Work(None, None, views_per_class=self.per_class)

    source = Declared()
    vf.register_dataset(source)
    try:
        cfg = load_config(ROOT / "configs" / "synthetic.toml", {"data": {"source": "views_per_class_source"}})

        def fit(per_class):
            source.per_class = per_class
            return next(t for t in cost.models_terms(cfg) if t.what.startswith("the GP fits"))

        sixteen, thirty_two, undeclared = fit(16), fit(32), fit(None)
        assert " x 16 views x " in sixteen.what and " x 120 views x " in undeclared.what   # BigBIRD's ring
        # a GP fit grows as its views^MODEL_FIT_VIEWS_POWER (measured): 16 views a class against BigBIRD's 120
        p = cost.MODEL_FIT_VIEWS_POWER
        assert thirty_two.seconds == pytest.approx(2 ** p * sixteen.seconds)
        assert sixteen.seconds == pytest.approx(undeclared.seconds * (16 / 120) ** p) and sixteen.seconds > 0
    finally:
        unregister_dataset("views_per_class_source")
    # the built-ins declare theirs: COIL every 10 degrees trains 36 views a class, the stand-ins their ring
    assert " x 36 views x " in cost.models_terms(load_config(ROOT / "configs" / "real.toml"))[0].what
    syn = load_config(ROOT / "configs" / "synthetic.toml")
    assert f" x {360 // syn.data.synthetic.angle_step_deg} views x " in cost.models_terms(syn)[0].what

"""The one cost model (pipeline/infra/cost.py): every setting that multiplies a stage's work feeds
one estimate, checked before any stage of a command runs; a refusal exits 2 within seconds naming
the keys, and nothing is written. The shipped configs all fit."""
from __future__ import annotations

import dataclasses
import os
import resource
import subprocess
import sys
import time

import pytest

from pipeline.infra import cost
from pipeline.infra.budget import GIB
from pipeline.infra.config import Config, load_config
from stages.commands.cli import main
from tests.conftest import ROOT

# (stage, --set values, keys the refusal must name): the audit's case first, then variants it did not name
PLANTED = [
    ("evaluate", {"evaluate.sensitivity.realizations": 2000, "evaluate.sensitivity.n_loc_samples": 100000},
     ("evaluate.sensitivity.realizations", "evaluate.sensitivity.n_loc_samples")),
    ("evaluate", {"plan.starts": 1000, "plan.eig_samples": 100000}, ("plan.starts", "plan.eig_samples")),
    ("evaluate", {"evaluate.randomized.realizations": 20000, "evaluate.tracks_per_target": 200},
     ("evaluate.randomized.realizations", "evaluate.tracks_per_target")),
    ("evaluate", {"evaluate.experiments": '["biased", "biased_randomized"]',
                  "evaluate.biased_randomized.realizations": 100000, "evaluate.biased_randomized.n_loc_samples": 1000},
     ("evaluate.biased_randomized.realizations", "evaluate.biased_randomized.n_loc_samples")),
    ("simulate", {"simulate.sweep": '"full"', "simulate.sweep_full_realizations": 100000},
     ("simulate.sweep_full_realizations",)),
    ("simulate", {"simulate.realizations": 20000, "simulate.n_loc_samples": 5000},
     ("simulate.realizations", "simulate.n_loc_samples")),
    ("classifier", {"classifier.training.epochs": 200, "classifier.training.train_images": 100000},
     ("classifier.training.epochs", "classifier.training.train_images")),
    ("features", {"features.bigbird_samples": 1000, "data.synthetic.bigbird_cameras": "[1, 2, 3, 4, 5]",
                  "features.bigbird_cameras": "[1, 2, 3, 4, 5]"}, ("features.bigbird_samples", "features.bigbird_cameras")),
]


@pytest.mark.parametrize("stage, sets, keys", PLANTED, ids=[f"{s}:{','.join(k)}" for s, _, k in PLANTED])
def test_a_planted_knob_is_refused_before_any_stage_runs(tmp_path, capsys, stage, sets, keys):
    from pipeline.infra.config import merge, parse_override
    from stages.framework.runner import closure

    args = [stage, "--set", f"run.artifacts={tmp_path}", "--set", "run.memory_gb=0"]
    over: dict = {}
    for k, v in sets.items():
        args += ["--set", f"{k}={v}"]
        over = merge(over, parse_override(f"{k}={v}"))
    cfg = load_config(ROOT / "configs" / "synthetic.toml", over)
    # the model refuses it (checked first, so a miss fails here instead of running the chain)
    assert [s for s in closure(stage) if _refused(cfg, s)] == [stage]
    t0 = time.perf_counter()
    rc = main(args)
    took = time.perf_counter() - t0
    err = capsys.readouterr().err
    assert rc == 2, err
    line = [ln for ln in err.splitlines() if "config error" in ln][0]
    assert "'run.max_minutes' = 120" in line and "about" in line
    for k in keys:
        assert f"'{k}' = " in line, (k, line)
    assert took < 30          # a formula, not a run (generous: the machine is shared)
    run = tmp_path / "synthetic"
    assert not run.exists() or not [p for p in run.iterdir() if not p.name.startswith(".")]


def _refused(cfg, stage) -> bool:
    try:
        cost.check(cfg, stage)
    except ValueError:
        return True
    return False


def test_the_audit_case_names_its_estimate_in_hours():
    cfg = dataclasses.replace(Config(), evaluate=dataclasses.replace(
        Config().evaluate, sensitivity=dataclasses.replace(Config().evaluate.sensitivity, realizations=2000,
                                                            n_loc_samples=100000)))
    est = cost.estimate(cfg, "evaluate")
    sens = next(t for t in est.terms if t.what.startswith("the sensitivity sweep"))
    # 5 sigmas x 2000 x 100000 = 1e9 trajectories at 32,000/s (K = 9, C = 4): 8.7 h
    assert sens.seconds == pytest.approx(1e9 / 32_000, rel=1e-3)   # plus the rows of 10,000 realizations
    with pytest.raises(ValueError, match=r"evaluate stage would take about 8\.\d h"):
        cost.check(cfg, "evaluate")


@pytest.mark.parametrize("path", sorted((ROOT / "configs").glob("*.toml")), ids=lambda p: p.name)
def test_every_shipped_config_fits_the_limits(path):
    cfg = load_config(path)
    for stage in cost.ESTIMATORS:
        est = cost.estimate(cfg, stage)
        assert est.seconds < 60 * cfg.run.max_minutes / 4, (stage, est.seconds)   # far from a refusal
        assert est.peak < 4 * GIB, (stage, est.peak)


def test_each_term_grows_with_its_keys():
    base = Config()

    def with_(section, **kw):
        ev = base.evaluate
        return dataclasses.replace(base, evaluate=dataclasses.replace(
            ev, **{section: dataclasses.replace(getattr(ev, section), **kw)}))

    def term(cfg, start):
        return next(t for t in cost.estimate(cfg, "evaluate").terms if t.what.startswith(start))
    s1 = term(base, "the sensitivity sweep").seconds
    assert term(with_("sensitivity", realizations=200), "the sensitivity sweep").seconds == pytest.approx(2 * s1, rel=0.01)
    g1 = term(base, "the population grid").seconds
    assert term(with_("randomized", realizations=40), "the population grid").seconds > 1.8 * g1
    p1 = term(base, "view planning").seconds
    more = dataclasses.replace(base, plan=dataclasses.replace(base.plan, starts=8))
    assert term(more, "view planning").seconds == pytest.approx(2 * p1, rel=0.01)
    off = dataclasses.replace(base, plan=dataclasses.replace(base.plan, enabled=False))
    assert not [t for t in cost.estimate(off, "evaluate").terms if t.what.startswith("view planning")]


def test_an_up_to_date_stage_is_not_refused_but_a_forced_one_is(tmp_config, monkeypatch):
    import stages.framework.runner as runner
    from tests.support import stage_fakes

    calls = stage_fakes.install(monkeypatch, {"a": (), "b": ("a",)})
    # stage 'a' costs a day by the model (its key ignores the limit, as every stage's does)
    monkeypatch.setitem(cost.ESTIMATORS, "a", lambda cfg, counts: [cost.Term("a day of work", ("run.max_minutes",),
                                                                            seconds=86400)])
    runner.ensure(tmp_config({"run": {"max_minutes": 0}}), "b")
    assert calls == ["a", "b"]
    cfg = tmp_config()
    calls.clear()
    runner.ensure(cfg, "b")                  # up to date: it will not run, so it is not refused
    assert calls == []
    with pytest.raises(ValueError, match=r"the a stage would take about 24\.0 h"):
        runner.ensure(cfg, "a", force=True)
    with pytest.raises(ValueError, match="a day of work"):
        runner.ensure(tmp_config({"run": {"name": "other"}}), "b")   # a new run folder: 'a' would run
    assert calls == []


@pytest.mark.parametrize("stage", ["features", "evaluate", "classifier"])
def test_a_memory_budget_below_the_stage_process_is_refused(tmp_path, capsys, stage):
    rc = main([stage, "--set", f"run.artifacts={tmp_path}", "--set", "run.memory_gb=0.2"])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "'run.memory_gb' = 0.2" in err and "process alone" in err and "0.20 GiB" in err
    assert not (tmp_path / "synthetic" / "data").exists()    # refused before the data stage ran


def _under_limit(argv: list[str], limit_gib: float) -> subprocess.CompletedProcess:
    """``python argv`` in a child whose address space is limited (RLIMIT_AS, as ``ulimit -v``)."""
    limit = int(limit_gib * GIB)

    def pre():
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    return subprocess.run([sys.executable, *argv], env={**os.environ, "PYTHONPATH": str(ROOT)}, cwd=ROOT,
                          capture_output=True, text=True, preexec_fn=pre, timeout=300)


def test_the_budget_reads_the_address_space_limit():
    out = _under_limit(["-c", "from pipeline.infra import budget as B; import resource; "
                              "from pipeline.infra.config import Config; "
                              "print(B.machine_memory(), resource.getrlimit(resource.RLIMIT_AS)[0], B.budget(Config()))"],
                       3)
    assert out.returncode == 0, out.stderr
    have, limit, auto = map(int, out.stdout.split())
    assert limit == 3 * GIB and 0 < have < limit and auto == pytest.approx(0.8 * have, rel=0.05)


def test_a_stage_that_cannot_map_its_libraries_under_ulimit_v_is_refused_naming_it(tmp_path):
    # torch alone maps ~3.5 GiB: under a 2 GiB address-space limit the classifier would fail deep in
    # an allocation ("DefaultCPUAllocator: can't allocate memory"); it is refused before it starts
    t0 = time.perf_counter()
    out = _under_limit(["-m", "stages.commands.cli", "classifier", "--progress", "off",
                        "--set", f"run.artifacts={tmp_path}"], 2)
    assert out.returncode == 2, out.stderr[-2000:]
    assert "the address-space limit (ulimit -v, RLIMIT_AS) of 2.00 GiB" in out.stderr
    assert "classifier" in out.stderr and not (tmp_path / "synthetic" / "classifier").exists()
    assert time.perf_counter() - t0 < 120


def test_an_explicit_budget_above_the_address_space_limit_is_lowered_with_a_warning():
    out = _under_limit(["-c", "import logging; logging.basicConfig(); import dataclasses; "
                              "from pipeline.infra import budget as B; from pipeline.infra.config import Config; "
                              "c = Config(); print(B.budget(dataclasses.replace(c, run=dataclasses.replace(c.run, "
                              "memory_gb=100))))"], 3)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout) < 3 * GIB
    assert "run.memory_gb = 100 is more than this process may use" in out.stderr and "RLIMIT_AS" in out.stderr


def test_under_ulimit_v_each_byte_counts_once_and_the_advice_works():
    # the process's own bytes are in what it may hold (held now + may still map), not taken off
    # the limit and then added again by each estimate; the advice for a need it can meet raises
    # run.memory_gb (and that setting then gives a budget that holds it), beyond it the limit
    code = ("import dataclasses, math, psutil, resource; from pipeline.infra import budget as B; "
            "from pipeline.infra.config import Config; p = psutil.Process().memory_info(); "
            "soft = resource.getrlimit(resource.RLIMIT_AS)[0]; have = B.machine_memory(); "
            "need = 0.9 * have; c = Config(); "
            "cfg = dataclasses.replace(c, run=dataclasses.replace(c.run, memory_gb=math.ceil(need / B.GIB * 100) / 100)); "
            "print(have, soft - p.vms, p.rss, B.budget(cfg) >= need); print(B.more_memory(need)); "
            "print(B.more_memory(have + B.GIB))")
    out = _under_limit(["-c", code], 3)
    assert out.returncode == 0, out.stderr
    first, small, big = out.stdout.splitlines()
    have, left, rss, fits = first.split()
    assert int(have) == pytest.approx(int(left) + int(rss), abs=64 << 20) and fits == "True"
    assert small.startswith("raise run.memory_gb to at least")
    assert big.startswith("raise the address-space limit (ulimit -v) by at least")


def test_a_stage_whose_libraries_do_not_fit_the_address_space_is_refused():
    # the features stage's own work is small; torch's mappings are not
    out = _under_limit(["-c", "from pipeline.infra import cost; from pipeline.infra.config import Config\n"
                              "try:\n    cost.check(Config(), 'features')\nexcept ValueError as e:\n    print(e)\n"], 2)
    assert "the features stage needs about" in out.stdout and "more address space" in out.stdout, out
    assert "RLIMIT_AS) of 2.00 GiB" in out.stdout


def test_the_features_stage_checks_again_with_the_avd_boxes_it_found():
    c = Config()
    cfg = dataclasses.replace(c, features=dataclasses.replace(c.features, n_samples=1000))
    cost.check(cfg, "features")                                   # no box known before the data: a lower bound
    few = cost.estimate(cfg, "features", cost.Counts(avd_crops=1000)).seconds
    assert cost.estimate(cfg, "features", cost.Counts(avd_crops=2000)).seconds > 1.5 * few
    with pytest.raises(ValueError, match=r"scoring 20000 AVD boxes x \(1 \+ 1000 MC-dropout passes\): about .*"
                                         r"'features.n_samples' = 1000"):
        cost.check(cfg, "features", cost.Counts(avd_crops=20000), base=False)

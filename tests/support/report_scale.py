"""A full-scale-shaped fake run for the report's benchmark and its parallel-route test: the fake run of
``tests/support/report_fixtures.py`` with as many targets, tracks, methods and settings as the real
chains have (configs/real_category.toml: ~75 targets, ~200 tracks, 4–6 methods, several settings).

The fixture's module constants are swapped for the duration of the write only (``scaled``), so the
tests that use the small fake run are unaffected."""
from __future__ import annotations

import contextlib
from pathlib import Path
from unittest import mock

from pipeline.method.methods.dirichlet import DIRICHLET
from pipeline.method.names import (MODEL_BASED, SIMPLE_BAYES, WITH_UNCERTAINTY, WU_DROPOUT_ONLY,
                                   WU_POSES_ONLY)
from tests.support import report_fixtures as rf
from tests.support import report_population as rp

METHODS = (WITH_UNCERTAINTY, MODEL_BASED, SIMPLE_BAYES, DIRICHLET, WU_POSES_ONLY, WU_DROPOUT_ONLY)
SETTINGS = ((0.3, (0.0, 0.0)), (0.3, (-0.3, 0.2)), (0.5, (0.0, 0.0)), (0.5, (0.3, -0.2)))


@contextlib.contextmanager
def scaled(n_targets: int, n_methods: int, n_settings: int):
    """The fixture's constants for ``n_targets`` targets, ``n_methods`` methods and ``n_settings``
    randomized settings (the first five targets keep their names: the detailed track is the first's)."""
    names = rf.INSTANCES + tuple(f"object_{i:03d}" for i in range(max(0, n_targets - len(rf.INSTANCES))))
    methods = METHODS[:n_methods]
    drift = {m: rf.DRIFT.get(m, 0.35 + 0.03 * i) for i, m in enumerate(methods)}
    noise = {m: rf.NOISE.get(m, 0.7 + 0.1 * i) for i, m in enumerate(methods)}
    comps = tuple((methods[0], b) for b in methods[1:])
    with mock.patch.multiple(rf, INSTANCES=names, METHODS=methods, DRIFT=drift, NOISE=noise,
                             RANDOMIZED=SETTINGS[:n_settings]), \
            mock.patch.multiple(rp, METHODS=methods, COMPARISONS=comps,
                                LABEL={m: m.replace("_", " ").title() for m in methods}):
        yield


def write_scaled_run(run_dir: Path, *, targets: int = 75, tracks: int = 3, methods: int = 5, settings: int = 3,
                     K: int = 8, R: int = 4, n_boot: int = 200, seed: int = 0) -> dict:
    """``write_fake_run`` at the given scale; returns its facts."""
    with scaled(targets, methods, settings):
        return rf.write_fake_run(run_dir, T=targets, tracks=tracks, K=K, R=R, methods=rf.METHODS, n_boot=n_boot,
                                 seed=seed)

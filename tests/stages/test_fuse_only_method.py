"""A method with only ``fuse`` (docs/api.md's MajorityVote: no single_view, no fuse_with_extras,
no simulate) runs through the smoke chain's evaluate and report, registered both ways docs/api.md
documents, in one run as a user starts it: one through the launcher script (guarded, as the docs
write it), one through an entry point of the group ``viewfuse.methods`` of a distribution found
on the path (a dist-info written here; this one also leaves out label, short, colour and note)."""
from __future__ import annotations

import json
import textwrap

import pytest

from tests.support.outside_package import write_package
from tests.support.shared_upstream import copy_upstream, run_evaluate, smoke_upstream

pytestmark = pytest.mark.slow  # runs the evaluate and report stages on the smoke upstream

VOTE = '''
import numpy as np
import viewfuse as vf


@vf.register
class MajorityVote(vf.FusionMethod):
    key = "launcher_vote"
    label = "Majority vote (launcher)"
    short = "Vote (launcher)"
    note = "each view votes for its top-scoring candidate"
    needs = frozenset({"scores"})
    uses_poses = False

    def fuse(self, t):
        top = t.own.mean(axis=1).argmax(axis=1)
        votes = np.cumsum(np.eye(t.own.shape[-1])[top], axis=0) + 1.0
        return np.log(votes / votes.sum(axis=1, keepdims=True))
'''

BARE = '''
import numpy as np
from viewfuse import FusionMethod, register


@register
class Flat(FusionMethod):
    key = "entry_flat"
    needs = frozenset({"scores"})
    uses_poses = False

    def fuse(self, t):
        K, C = t.own.shape[0], t.own.shape[-1]
        return np.full((K, C), -np.log(C))
'''


def _plant(tmp_path):
    """The launcher with its method module, and a distribution with an entry point, on a path of their own."""
    mine, dist = tmp_path / "mine", tmp_path / "site"
    mine.mkdir()
    (mine / "launcher_vote.py").write_text(VOTE)
    (mine / "launch.py").write_text(textwrap.dedent('''
        import sys
        import launcher_vote                      # registers the method
        from stages.commands.cli import main

        if __name__ == "__main__":
            sys.exit(main())
    '''))
    write_package(dist, "entry_flat_pkg", BARE, {"viewfuse.methods": {"entry_flat": "entry_flat_pkg"}})
    return mine / "launch.py", dist


def test_a_fuse_only_method_runs_through_evaluate_from_the_launcher_and_an_entry_point(tmp_path_factory, tmp_path):
    art = copy_upstream(smoke_upstream(tmp_path_factory), tmp_path / "artifacts")
    launcher, dist = _plant(tmp_path)
    r = run_evaluate(art, [str(launcher)], dist)
    assert r.returncode == 0, r.stderr[-3000:]
    run = art / "smoke"
    pop = json.loads((run / "evaluate" / "summary.json").read_text())["population"]
    for key in ("launcher_vote", "entry_flat"):
        assert key in pop["methods"] and key in pop["pooled"], key
        assert f"with_uncertainty-{key}" in pop["paired"]
        assert key not in pop["difficulty"]["summary"]          # no single_view: no difficulty row
    assert "with_uncertainty" in pop["difficulty"]["summary"]
    flat = pop["pooled"]["entry_flat"]["prob_truth_final"]["value"]
    assert flat == pytest.approx(1 / 3, abs=1e-9)                  # three candidates, a flat posterior
    report = (run / "report" / "index.html").read_text()
    assert "Majority vote (launcher)" in report and "entry_flat" in report

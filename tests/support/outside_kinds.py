"""The test package of every kind but a dataset (docs/extending.md): one module with a fusion
method, a classifier, a planner and a metric, and the entry points that name them in viewfuse's
groups. tests/test_extending.py uses each through the public API; tests/stages/test_outside_kinds_chain.py
runs them through the stages from the CLI. Written to disk by ``outside_package.write_package``."""

PACKAGE = "vf_outside"

MODULE = '''
import numpy as np
import viewfuse as vf


@vf.register                       # imported through viewfuse.methods' entry point
class OutsideVote(vf.FusionMethod):
    key = "outside_vote"
    label = "Outside vote (test package)"
    short = "Outside vote"
    color = "#999933"
    note = "the running product of each candidate's own mean score (a test package's method)"
    needs = frozenset({"scores"})
    uses_poses = False

    def fuse(self, t):
        log = np.cumsum(np.log(t.own.mean(axis=1)), axis=0)
        return log - np.logaddexp.reduce(log, axis=1, keepdims=True)


@vf.register_classifier            # imported through viewfuse.classifiers' entry point
class Tiny(vf.Classifier):
    name = "outside_tiny"
    display = "a test package's tiny network"
    architecture = "outside.tiny"

    def build(self, num_classes, dropout, drop_connect=0.0):
        import torch                       # inside: checking a config does not load torch
        from torch import nn

        class TinyNet(nn.Module):          # torchvision's layout: features -> avgpool -> flatten | classifier
            def __init__(self):
                super().__init__()
                self.features = nn.Sequential(nn.Conv2d(3, 4, 5, stride=4), nn.ReLU())
                self.avgpool = nn.AdaptiveAvgPool2d(1)
                self.classifier = nn.Sequential(nn.Dropout(dropout), nn.Linear(4, num_classes))

            def forward(self, x):
                return self.classifier(torch.flatten(self.avgpool(self.features(x)), 1))

        return TinyNet()

    def last_linear_key(self):
        return "classifier.1.weight"


class FirstInNameOrder(vf.Planner):   # no decorator: the entry point names the class
    name = "outside_first"

    def choose(self, belief, candidates, rng):
        return sorted(candidates)[0]


def _square_mean(p, params):
    return (p ** 2).mean(axis=-1)


# no call: the entry point names the Metric, registered under the entry point's name
P_TRUTH_SQUARED = vf.Metric("P(truth) squared, final step", "P(truth)^2, final", True, "p_truth", "final",
                            _square_mean, best=1.0, worst=0.0)
'''

ENTRY_POINTS = {"viewfuse.methods": {"outside_vote": "vf_outside"},
                "viewfuse.classifiers": {"outside_tiny": "vf_outside"},
                "viewfuse.planners": {"outside_first": "vf_outside:FirstInNameOrder"},
                "viewfuse.metrics": {"p_truth_squared_final": "vf_outside:P_TRUTH_SQUARED"}}

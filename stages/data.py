"""Stage ``data``: what ``data.source`` names (a registered dataset source,
``pipeline.infra.datasets``) writes the run's data, or checks the roots read in place.

The built-ins (``loaders/sources/``): ``synthetic`` renders the stand-ins and writes, under the
stage folder, ``bigbird/<object>/...`` (BigBIRD object folders), ``avd/instance_id_map.txt`` and
``avd/<scan>/...`` for every scan of ``data.scans`` (an AVD root), and ``truth.json``;
``real_imagery`` writes the same folders and ``truth.json`` from COIL-100 or ETH-80 photographs and
real AVD scan metadata (docs/real_data.md); ``real`` only checks that the configured roots hold
what the readers need and writes ``roots.json``. A source of your own writes the same layout
(docs/extending.md). ``data_roots(cfg)`` tells later stages where the BigBIRD and AVD roots are.
"""
from __future__ import annotations

# The built-in sources, named so that this stage's code key covers them and what they import (a
# source from outside enters the key through stages/framework/outside.py).
from loaders.sources import real, real_imagery, synthetic  # noqa: F401
from pipeline.infra.datasets import dataset_source
from stages.framework.roots import data_roots  # noqa: F401 - the stage's public helper

DIGEST_MEMO = real.DIGEST_MEMO


def extra_key(cfg) -> str:
    """The source's fingerprint of inputs read in place (``real``: the roots' content, so edits to
    them rerun the pipeline and a moved or copied dataset does not); '' for the other built-ins. A
    source's own ``[data.<name>]`` section is in the ``data`` section's hash like every key."""
    return dataset_source(cfg.data.source).input_key(cfg)


def run(ctx) -> str:
    return dataset_source(ctx.cfg.data.source).write(ctx)

"""The evaluation protocol, one sub-room per concern:

- ``grid``: candidate sets, tracks, localization settings, the population grid (experiments, cells,
  their reduction) and the population's summary and calibration blocks; the showcase tracks.
- ``metrics``: the one metric specification (``spec``), calibration, the results tables and their one
  writer, method and comparison labels.
- ``statistics``: the statistics engine (one resampler, interval, outcome rule and verdict record for every population, ablation and seed pool).
- ``domain``: the test domain (residuals of labelled crops, cross-fitted test-domain variance).
- ``simulation``: the paper's section 5.3 scenarios, the claims checked on them, the regime sweep.

Inside: ``metrics`` imports no other sub-room; ``statistics`` may import ``metrics``; ``grid`` and
``simulation`` may import ``metrics`` and ``statistics``; ``domain`` may import ``grid`` and ``metrics``.

May import: ``pipeline.method``, ``pipeline.scoring``, ``pipeline.infra``.
"""

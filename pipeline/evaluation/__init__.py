"""The evaluation protocol: candidate classes and the model bank fitted for them, tracks,
localization settings, the population grid (experiments, cells) and its summary, the one metric
specification (``metrics``) and the statistics (bootstrap CIs, paired differences, verdicts),
the results tables and their one writer, the paper's 5.3 simulation, and method labels for people.

May import: ``pipeline.method``, ``pipeline.scoring``, ``pipeline.infra``.
"""

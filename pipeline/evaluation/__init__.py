"""The evaluation protocol: candidate classes, tracks, localization settings, the population
grid (experiments, cells), metrics and their statistics (bootstrap CIs, paired differences,
verdicts), the results tables, the paper's 5.3 simulation, and method labels for people.

May import: ``pipeline.method``, ``pipeline.scoring``, ``pipeline.infra``.
"""

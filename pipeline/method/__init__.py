"""The paper's method: per-class GP models of the classifier's scores over the viewing direction
(kernel, fit, hyperpriors), the unit-circle geometry of viewpoints and localization samples, the
score-component rule, and the fusion engines (With Uncertainty, Model Based, Simple Bayes), plus the
view-independent Dirichlet class models and their posterior-cloud fusion (Tchuiev & Indelman 2018).

May import: ``pipeline.infra``. Nothing here knows about datasets, stages or the evaluation
protocol.
"""

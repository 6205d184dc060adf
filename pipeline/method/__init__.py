"""The paper's method: per-class GP models of the classifier's scores over the viewing direction
(kernel, fit, hyperpriors), the unit-circle geometry of viewpoints and localization samples, the
score-component rule, and the fusion engines (With Uncertainty, Model Based, Simple Bayes); the
method registry and what a method with a model of its own declares (``provider``); the other
methods' models live beside their method files.

May import: ``pipeline.infra``. Nothing here knows about datasets, stages or the evaluation
protocol.
"""

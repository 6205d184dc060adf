"""The classifier and what it measures: the classifier registry, one entry per ``classifier.arch``
(``classifiers``), the dropout AlexNet (``alexnet``), EfficientNet-Lite0 (``efficientnet_lite``), weight files without
pickles (``weight_files``), the classifier card (``card``), training on the source domain
(``training``), MC-dropout scoring (``mc_dropout``), crop preparation (``crops``) and the feature
tables (per-view score vectors) the features stage writes (``features``).

May import: ``pipeline.infra``.
"""

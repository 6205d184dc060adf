"""The classifier and what it measures: the dropout AlexNet, MC-dropout scoring, crop
preparation, and the feature tables (per-view score vectors) the features stage writes.

May import: ``pipeline.infra``.
"""

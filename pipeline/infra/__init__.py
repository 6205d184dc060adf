"""Plumbing shared by every stage: configuration (schema, loading, checks), content-addressed
caching and atomic writes, artifact names, executors (local and Ray), device and thread choice,
progress reporting.

May import: nothing else inside ``pipeline``.
"""

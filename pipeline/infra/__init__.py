"""Plumbing shared by every stage: configuration (schema, loading, checks), content-addressed
caching and atomic writes, the data catalog (every artifact's name, reader and writer), executors (local and Ray), device and thread choice,
the allocator setting that keeps freed blocks during a torch loop (``memory``), progress reporting.

May import: nothing else inside ``pipeline``.
"""

"""Scene geometry of a scan, below both the dataset readers and the evaluation protocol: which
images share a grid point (``viewpoints``), rays through box centres, the grid step and facing
error (``rays``), and where an instance stands, refused when its rays do not meet (``location``).

May import: ``pipeline.infra``. Nothing here knows about datasets, stages or the evaluation
protocol.
"""

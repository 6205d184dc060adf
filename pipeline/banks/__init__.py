"""Model banks: which GP class models the evaluation needs (the default candidate plan
and each model ablation), fitted from the feature tables by ``pipeline.method``'s fitters and
written in the bank format (``pipeline.method.gp_files``).

May import: ``pipeline.evaluation``, ``pipeline.method``, ``pipeline.scoring``, ``pipeline.infra``.
"""

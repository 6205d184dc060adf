"""One cell's result reduced to what the evaluate stage keeps of it, so that the grid streams.

``population.run_cell`` returns every log posterior of a cell: (R, K, C) per setting and method,
about 2 MB per cell at paper grade (configs/paper_grade.toml) and ten times that as result rows.
``reduce_cell`` turns it, as soon as the cell is done, into its cell-table rows (metrics over the
realizations, at the run's ``spec.Params``), its calibration bin sums (``pooled_calibration.cell_sums``), the single-track
tables the showcase needs (``experiments.summarize``, default variant only), the difficulty and
the methods' extras, and its results-file blocks, which the stage writes at once. Each
``metrics.step_values`` is computed once and serves the rows, the metrics and the tables.
"""
from __future__ import annotations

import numpy as np

from pipeline.evaluation.metrics import spec as M
from pipeline.evaluation.statistics.pooled_calibration import cell_sums
from pipeline.evaluation.metrics.results import cell_metrics, result_block


def reduce_cell(cell, res: dict, params: M.Params, *, tables: bool = False) -> tuple[dict, list[dict]]:
    """(the kept summary of ``run_cell``'s result ``res``, its result blocks in setting order).

    The summary: ``rows`` (one dict per (setting, method): the cell's identity and
    ``results.cell_metrics``), ``calibration`` (``cell_sums``), ``difficulty``, ``extras``: {method:
    the extras it returned, with ``posterior0``, its posterior (K, C) of the cell's first setting,
    realization 0} for the methods that returned any; with ``tables``, ``tables``: {(experiment, label): the
    ``experiments.summarize`` tables} and ``final_mgr``: {label: {method: final-step log10 MGR per
    realization}}."""
    by_label = {(s.experiment, s.label): s for s in cell.settings}
    rows, blocks, summaries, final_mgr = [], [], {}, {}
    for key, posts in res["posts"].items():
        experiment, label = key
        values = {m: M.step_values(lp, cell.truth, is_log=True) for m, lp in posts.items()}
        for method, lp in posts.items():
            base = M.scalars(values[method], params=params)
            rows.append({"variant": cell.variant, "target": cell.target, "track": cell.track, "scan": cell.scan,
                         "experiment": experiment, "setting": label, "method": method,
                         **cell_metrics(lp, cell.truth, params, base=base)})
            if tables:
                summaries.setdefault(key, {})[method] = {**M.with_mgr_ratios(base), "n_realizations": int(lp.shape[0])}
                # every realization's final log10 MGR: percentiles over every track (grid/paper55.py)
                final_mgr.setdefault(label, {})[method] = np.asarray(values[method]["log10_mgr"][:, -1], float)
        s = by_label[key]
        blocks.append(result_block(posts, cell.truth, values=values, variant=cell.variant, experiment=s.experiment,
                                   setting=s.label, sigma_m=float(s.sigma), bias_x=float(s.bias[0]),
                                   bias_y=float(s.bias[1]), scan=cell.scan, target=cell.target, track=cell.track,
                                   candidates=",".join(cell.classes), truth=cell.truth))
    kept = {"rows": rows, "calibration": cell_sums(res["posts"], cell.truth, params.ece_bins), "difficulty": res["difficulty"]}
    if tables:
        kept["tables"] = summaries
        kept["final_mgr"] = final_mgr
    first = next(iter(res["posts"].values()), {})
    kept["extras"] = {m: {**x, "posterior0": np.exp(first[m][0])} if m in first else dict(x)
                      for m, x in res.get("extras", {}).items()}
    return kept, blocks

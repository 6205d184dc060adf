"""Table rows and facts for the main report: hyperparameters, component names, skips, seeds,
packages, the resolved config. Pure functions of what ``reports.shared.artifacts`` read."""
from __future__ import annotations

import json
import platform
from importlib import metadata as importlib_metadata
from typing import Any

from reports.shared.numbers import MISSING

PACKAGES = ("numpy", "scipy", "scikit-learn", "torch", "torchvision", "pandas", "pyarrow", "matplotlib",
            "h5py", "opencv-python-headless")

_HP_NAMES = {"mean": "prior mean m", "amplitude": "amplitude a", "length_scale": "length scale ℓ",
             "noise": "noise σn²", "log_marginal_likelihood": "log marg. lik.", "n_train": "N train",
             "component_name": "component name", "train_std": "score std over views"}
_HP_PREFERRED = ("mean", "train_std", "amplitude", "length_scale", "noise", "log_marginal_likelihood", "n_train")
# Bookkeeping of the optimizer, not hyperparameters: left out of the table.
_HP_HIDDEN = {"warnings", "at_bound", "init", "restarts", "random_state"}


def _str_list(v) -> list[str]:
    """A JSON field that holds one string or a list of them, as a list of strings."""
    v = v or []
    return [v] if isinstance(v, str) else [str(x) for x in v]


def fit_diagnostics(index: dict) -> list[dict]:
    """Per-(class, component) fit dicts from models/index.json ("diagnostics" or "fits"; else the
    bare "hyperparameters" table)."""
    fits = index.get("fits") or index.get("diagnostics") or []
    if isinstance(fits, dict):
        fits = [dict(v, fit=k) if isinstance(v, dict) else {"fit": k, "value": v} for k, v in fits.items()]
    if not fits and isinstance(index.get("hyperparameters"), dict):
        fits = [dict(hp, **{"class": cls, "component": comp})
                for cls, per in index["hyperparameters"].items() if isinstance(per, dict)
                for comp, hp in per.items() if isinstance(hp, dict)]
    return [f for f in fits if isinstance(f, dict)]


def hyperparameter_table(index: dict) -> tuple[list[str], list[list], list[str]]:
    """Header, rows and one line per fit warning (bound hits and optimizer messages)."""
    fits = fit_diagnostics(index)
    id_keys = [k for k in ("fit", "class", "component", "component_name")
               if any(f.get(k) not in (None, "") for f in fits)]
    skip = set(id_keys) | _HP_HIDDEN
    scalar = set()
    for f in fits:
        scalar |= {k for k, v in f.items() if k not in skip and isinstance(v, (int, float, str, bool))}
    cols = [k for k in _HP_PREFERRED if k in scalar] + sorted(scalar - set(_HP_PREFERRED))
    header = [_HP_NAMES.get(k, k) for k in id_keys + cols] + ["at a bound / warnings"]
    rows, warns = [], []
    for f in fits:
        at_bound, messages = (_str_list(f.get(key)) for key in ("at_bound", "warnings"))
        ident = " / ".join(str(f.get(k)) for k in id_keys if f.get(k) is not None)
        warns += [f"{ident}: {x}" for x in at_bound + messages]
        cell = at_bound + messages
        rows.append([f.get(k) for k in id_keys] + [f.get(k) for k in cols] + ["; ".join(cell) or MISSING])
    warns += [str(w) for w in (index.get("warnings") or [])]
    return header, rows, warns


def bound_counts(index: dict) -> dict[str, int]:
    """How many fits have any hyperparameter at a bound, and how many have the noise at its lower one."""
    fits = fit_diagnostics(index)
    flags = [_str_list(f.get("at_bound")) for f in fits]
    return {"fits": len(fits), "at_bound": sum(1 for a in flags if a),
            "noise_lower": sum(1 for a in flags if any("noise" in x and "lower" in x for x in a))}


def component_labels(index: dict | None, gp: dict | None, target: str = "") -> list[str]:
    """'name (score k)' per component of the detailed track's candidate set."""
    index = index or {}
    cset = ((index.get("candidate_sets") or {}).get(target) or {}) if target else {}
    comps = cset.get("components") if cset else None
    names = cset.get("component_names") if cset else None
    if comps is None and index.get("components") is not None:
        comps, names = index["components"], index.get("component_names")
    if comps is None and gp is not None and "components" in gp:
        comps = [int(c) for c in gp["components"]]
    names = list(names or [])
    return [f"{names[i]} (score {k})" if i < len(names) and names[i] not in (None, "") else f"score {k}"
            for i, k in enumerate(comps or [])]


def component_legend(card: dict | None, example: tuple[str, int] = ("chevron", 4)) -> str:
    """One line saying what a component name is, for the classifier that produced the scores;
    ``example`` is (name, output index) of one of this run's components."""
    name, k = example
    weights = (card or {}).get("weights")
    if weights == "synthetic":
        n = (card or {}).get("num_classes")
        return (f"A component such as '{name} (score {k})' is output {k} of the classifier: its score for "
                f"the texture family '{name}' of the synthetic source domain it was trained on"
                f"{f' ({n} families)' if n else ''}. Texture families are not object classes; the GP "
                "models learn how each object's scores on them change with the viewing direction.")
    if weights == "imagenet":
        return (f"A component such as '{name} (score {k})' is output {k} of the ImageNet AlexNet: its score "
                f"for the ImageNet class '{name}'. ImageNet classes are not the object instances; the GP "
                "models learn how each object's scores on them change with the viewing direction.")
    return ("A component 'name (score k)' is output k of the classifier, named by the classifier's "
            "output names; the GP models learn how each object's scores change with the viewing direction.")


def skip_rows(skipped: dict[str, Any]) -> list[list]:
    """[stage, what, count, reasons] rows from manifests' extra.skipped entries (any nesting the
    stages use: a SkipLog summary, a dict of them, or a plain count)."""
    rows = []
    for stage, entry in skipped.items():
        items = entry.items() if isinstance(entry, dict) and "skipped" not in entry else [("", entry)]
        for what, e in items:
            if e is None:
                rows.append([stage, what or MISSING, 0, MISSING])
            elif isinstance(e, dict):
                reasons = "; ".join(f"{r} ({n})" for r, n in (e.get("reasons") or {}).items())
                rows.append([stage, what or MISSING, int(e.get("skipped") or 0), reasons or MISSING])
            elif isinstance(e, (int, float)):
                rows.append([stage, what or MISSING, int(e), MISSING])
            elif isinstance(e, list):
                rows.append([stage, what or MISSING, len(e), "; ".join(map(str, e[:5])) or MISSING])
    return rows


def dump_toml(d: dict, prefix: str = "") -> str:
    """TOML-style text of a nested dict (for reading, not for re-parsing)."""
    scal = {k: v for k, v in d.items() if not isinstance(v, dict)}
    subs = {k: v for k, v in d.items() if isinstance(v, dict)}
    lines = []
    if prefix and scal:
        lines.append(f"[{prefix}]")
    for k, v in scal.items():
        lines.append(f"{k} = {json.dumps(v, ensure_ascii=False)}")
    if scal:
        lines.append("")
    for k, v in subs.items():
        lines.append(dump_toml(v, f"{prefix}.{k}" if prefix else k))
    return "\n".join(lines)


def find_seeds(d: Any, prefix: str = "") -> dict[str, Any]:
    """Every key named 'seed' in a nested dict, by dotted path."""
    out = {}
    if isinstance(d, dict):
        for k, v in d.items():
            p = f"{prefix}.{k}" if prefix else k
            if k == "seed" and not isinstance(v, dict):
                out[p] = v
            else:
                out.update(find_seeds(v, p))
    return out


def package_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for dist in PACKAGES:
        try:
            out[dist] = importlib_metadata.version(dist)
        except importlib_metadata.PackageNotFoundError:
            out[dist] = "not installed"
    return out

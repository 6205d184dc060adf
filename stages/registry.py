"""The stage graph: what each stage reads (config sections, code, upstream stages) and writes.

A stage's cache key is the hash of its config sections, its code and its upstream stages'
outputs, DVC-style: editing one config section reruns the stages that declare it and those
downstream of them, nothing else. The code a stage depends on is not listed by hand: it is every
project module the stage module imports, transitively, found by parsing the imports (also those
inside functions) — so an edit anywhere a stage can reach reruns it.
"""
from __future__ import annotations

import ast
import functools
import hashlib
import importlib.util
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.infra.cache import source_fingerprint

PACKAGES = ("pipeline", "loaders", "stages", "reports")   # the project's import floors


@dataclass(frozen=True)
class StageSpec:
    name: str
    module: str                          # has run(ctx) -> str (one-line summary)
    upstream: tuple[str, ...] = ()
    sections: tuple[str, ...] = ()       # config sections hashed into the key
    help: str = ""
    after: tuple[str, ...] = field(default=())  # stages run right after this one by the CLI


STAGES: dict[str, StageSpec] = {s.name: s for s in (
    StageSpec("data", "stages.data", (), ("data",),
              help="render the synthetic BigBIRD/AVD stand-ins, or validate the real dataset paths"),
    StageSpec("classifier", "stages.classifier", (), ("classifier",),
              help="resolve the dropout AlexNet weights (train the synthetic source-domain model)"),
    StageSpec("features", "stages.features", ("data", "classifier"), ("features",),
              help="crop every needed view and score it (deterministic pass + MC dropout) -> Parquet"),
    StageSpec("models", "stages.models", ("features",),
              ("models", "evaluate.targets", "evaluate.n_candidates", "evaluate.candidates",
               "evaluate.candidate_seed", "evaluate.ablations"),
              help="choose feature components and fit one GP per (class, component)"),
    StageSpec("evaluate", "stages.evaluate", ("data", "features", "models"), ("evaluate",),
              help="the population evaluation (targets x tracks x localization settings x methods, CIs, "
                   "verdict) and the detailed track's experiments", after=("report",)),
    StageSpec("report", "stages.report", ("models", "evaluate"), ("report",),
              help="render the HTML + PNG report from existing results"),
    StageSpec("simulate", "stages.simulate", (), ("simulate",),
              help="simulation scenarios of the paper's section 5.3 (synthetic GP measurements)"),
)}

ORDER = ("data", "classifier", "features", "models", "evaluate", "report", "simulate")


# ------------------------------------------------------------------------------------------------
# Code dependencies, from the imports

def _module_file(name: str) -> Path | None:
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None
    if spec is None or spec.origin is None or not spec.origin.endswith(".py"):
        return None
    return Path(spec.origin)


def _is_project(name: str) -> bool:
    return name.split(".")[0] in PACKAGES


def _imports_of(name: str, path: Path) -> set[str]:
    """Project modules imported anywhere in one file (top level and inside functions)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parts = parts[: len(parts) - (node.level - 1)]
                base = ".".join(parts + ([base] if base else []))
            found.add(base)
            # "from pipeline import experiments": the name may itself be a module
            found.update(f"{base}.{a.name}" for a in node.names if _module_file(f"{base}.{a.name}"))
    out: set[str] = set()
    for mod in found:
        if not _is_project(mod):
            continue
        parts = mod.split(".")
        out.update(".".join(parts[:i]) for i in range(1, len(parts) + 1))  # packages run __init__ too
    return {m for m in out if _module_file(m) is not None}


@functools.lru_cache(maxsize=None)
def _deps_cached(module: str, mtimes: tuple) -> tuple[str, ...]:
    seen: set[str] = set()
    todo = [module]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        path = _module_file(name)
        if path is None:
            continue
        seen.add(name)
        todo.extend(_imports_of(name, path) - seen)
    return tuple(sorted(seen))


def code_deps(module: str) -> tuple[str, ...]:
    """``module`` and every project module it imports, transitively, sorted."""
    files = sorted(p for pkg in PACKAGES for p in _package_files(pkg))
    stamp = tuple((str(p), p.stat().st_mtime_ns) for p in files)
    return _deps_cached(module, stamp)


def _package_files(pkg: str) -> list[Path]:
    f = _module_file(pkg)
    return sorted(f.parent.rglob("*.py")) if f is not None else []


def code_version(spec: StageSpec) -> tuple[str, dict[str, str]]:
    """(hash, {module: fingerprint of its code}) over the stage's derived code modules
    (``pipeline.infra.cache.source_fingerprint``: comments and docstrings do not count)."""
    mods = set(code_deps(spec.module))
    per: dict[str, str] = {}
    for m in sorted(mods):
        if _module_file(m) is None and importlib.util.find_spec(m) is not None:
            from pipeline.infra.cache import code_hash  # a package name listed by hand: all its files
            per[m] = code_hash([m])
            continue
        path = _module_file(m)
        if path is not None:
            per[m] = source_fingerprint(path)
    h = hashlib.sha256("".join(f"{k}={v}\n" for k, v in sorted(per.items())).encode()).hexdigest()
    return h, per

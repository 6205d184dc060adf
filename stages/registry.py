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
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.infra.outputs import OUTPUTS

PACKAGES = ("pipeline", "loaders", "stages", "reports")   # the project's import floors
ROOT = Path(__file__).resolve().parents[1]                 # the source tree they live in


@dataclass(frozen=True)
class StageSpec:
    name: str
    module: str                          # has run(ctx) -> str (one-line summary)
    upstream: tuple[str, ...] = ()
    sections: tuple[str, ...] = ()       # config sections hashed into the key
    code: tuple[str, ...] = ()           # extra modules hashed into the key (besides the derived ones)
    help: str = ""
    after: tuple[str, ...] = field(default=())  # stages run right after this one by the CLI

    @property
    def outputs(self) -> dict[str, str]:
        return OUTPUTS.get(self.name, {})


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
              help="build the AVD track and run the localization-error experiments", after=("report",)),
    StageSpec("report", "stages.report", ("models", "evaluate"), ("report",),
              help="render the HTML + PNG report from existing results"),
    StageSpec("simulate", "stages.simulate", (), ("simulate",),
              help="simulation scenarios of the paper's section 5.3 (synthetic GP measurements)"),
)}

ORDER = ("data", "classifier", "features", "models", "evaluate", "report", "simulate")


def output_name(stage: str, key: str) -> str:
    """File name of a stage output, from the one declaration in ``pipeline.infra.outputs``."""
    from pipeline.infra.outputs import name
    return name(stage, key)


def output_path(cfg, stage: str, key: str) -> Path:
    """Final path of a stage output in the run folder."""
    return cfg.stage_dir(stage) / output_name(stage, key)


# ------------------------------------------------------------------------------------------------
# Code dependencies, from the imports

def _module_file(name: str) -> Path | None:
    """The source file of project module ``name``, found by path in the source tree: ``a/b.py`` or
    ``a/b/__init__.py`` under the repository root. Nothing is imported (``importlib.util.find_spec``
    would import the parent packages, and with them torch), so ``viewfuse status`` stays fast."""
    if not name or not _is_project(name):
        return None
    parts = name.split(".")
    if not all(p.isidentifier() for p in parts):
        return None
    base = ROOT.joinpath(*parts)
    for cand in (base.with_name(parts[-1] + ".py"), base / "__init__.py"):
        if cand.is_file():
            return cand
    return None


def _is_project(name: str) -> bool:
    return name.split(".")[0] in PACKAGES


def _imports_of(name: str, path: Path) -> set[str]:
    """Project modules imported anywhere in one file (top level and inside functions)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for level, base, names in _source(path).imports:
        if level:
            parts = package.split(".")
            parts = parts[: len(parts) - (level - 1)]
            base = ".".join(parts + ([base] if base else []))
        found.add(base)
        # "from pipeline import experiments": the name may itself be a module
        found.update(f"{base}.{a}" for a in names if _module_file(f"{base}.{a}"))
    out: set[str] = set()
    for mod in found:
        if not _is_project(mod):
            continue
        parts = mod.split(".")
        out.update(".".join(parts[:i]) for i in range(1, len(parts) + 1))  # packages run __init__ too
    return {m for m in out if _module_file(m) is not None}


@dataclass(frozen=True)
class _Source:
    """What the registry needs of one source file, from one parse."""
    fingerprint: str                                        # see source_fingerprint
    imports: tuple[tuple[int, str, tuple[str, ...]], ...]   # (level, module, names) per import
    top_level: frozenset[str]                               # names bound at the top level


def _source(path: Path) -> _Source:
    st = path.stat()
    return _parse(str(path), st.st_size, st.st_mtime_ns)


@functools.lru_cache(maxsize=1024)
def _parse(path: str, size: int, mtime_ns: int) -> _Source:
    # Parsed once per (file, size, mtime): every stage's dependency walk visits most project
    # modules, and ``viewfuse status`` computes every stage's key.
    data = Path(path).read_bytes()
    try:
        tree = ast.parse(data, filename=path)
    except (SyntaxError, ValueError):
        return _Source(hashlib.sha256(data).hexdigest(), (), frozenset())
    imports: list[tuple[int, str, tuple[str, ...]]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imports.extend((0, a.name, ()) for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            imports.append((node.level, node.module or "", tuple(a.name for a in node.names)))
        body = getattr(node, "body", None)
        if (isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and body
                and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    top: set[str] = set()
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            top.add(node.name)
        elif isinstance(node, ast.Assign):
            top.update(t.id for t in node.targets if isinstance(t, ast.Name))
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            top.update((a.asname or a.name).split(".")[0] for a in node.names)
    fp = hashlib.sha256(ast.dump(tree, include_attributes=False).encode()).hexdigest()
    return _Source(fp, tuple(imports), frozenset(top))


def source_fingerprint(path: str | Path) -> str:
    """sha256 of a Python file's syntax tree without comments and docstrings: editing what code
    says about itself does not make a stage stale; editing what it does does. A file that does
    not parse is hashed as bytes."""
    return _source(Path(path)).fingerprint


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
    """(hash, {module: fingerprint of its code}) over the stage's derived and extra code modules
    (``source_fingerprint``: comments and docstrings do not count)."""
    mods = set(code_deps(spec.module)) | set(spec.code)
    per: dict[str, str] = {}
    for m in sorted(mods):
        path = _module_file(m)
        if path is None:
            raise ValueError(f"stage {spec.name!r}: code module {m!r} is not a project module")
        per[m] = source_fingerprint(path)
    h = hashlib.sha256("".join(f"{k}={v}\n" for k, v in sorted(per.items())).encode()).hexdigest()
    return h, per


def defines(module: str, name: str) -> bool | None:
    """Whether project module ``module`` defines ``name`` at its top level, read off its source
    without importing it (``viewfuse status`` must not import torch through a stage module); None
    when the module is not a file of the source tree."""
    path = _module_file(module)
    return None if path is None else name in _source(path).top_level

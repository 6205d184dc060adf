"""The stage graph: what each stage reads (config sections, code, upstream stages) and writes.

A stage's cache key is the hash of its config sections, its code and its upstream stages'
outputs, DVC-style: editing one config section reruns the stages that declare it and those
downstream of them, nothing else. The code a stage depends on is not listed by hand: it is every
project module the stage module imports, transitively, found by parsing the imports (also those
inside functions) — so an edit anywhere a stage can reach reruns it.
"""
from __future__ import annotations

import ast
import dis
import functools
import re
from dataclasses import dataclass, field
from pathlib import Path

from pipeline.infra.cache import sha256_bytes, sha256_stream
from stages.framework.declarations import declares_settings, without_declarations

PACKAGES = ("pipeline", "loaders", "stages", "reports")   # the project's import floors
ROOT = Path(__file__).resolve().parents[2]                 # the source tree they live in


@dataclass(frozen=True)
class StageSpec:
    name: str
    module: str                          # has run(ctx) -> str (one-line summary)
    upstream: tuple[str, ...] = ()
    sections: tuple[str, ...] = ()       # config sections hashed into the key
    help: str = ""
    after: tuple[str, ...] = field(default=())  # stages run right after this one by the CLI
    methods: bool = False                # the fusion methods registered from outside enter the key
    defaults: bool = False               # every setting's default enters the key (the stage writes them)


STAGES: dict[str, StageSpec] = {s.name: s for s in (
    StageSpec("data", "stages.data", (), ("data", "models.min_views"),
              help="write the run's data from the source data.source names (its own words when it runs), or validate the real dataset paths"),
    StageSpec("classifier", "stages.classifier", (), ("classifier",),
              help="resolve the weights of the network classifier.arch names (train it on the synthetic source domain, or load a weights file)"),
    StageSpec("features", "stages.features", ("data", "classifier"), ("features",),
              help="crop every needed view and score it (deterministic pass + MC dropout) -> Parquet"),
    StageSpec("models", "stages.models", ("data", "features"),
              ("models", "evaluate.targets", "evaluate.n_candidates", "evaluate.candidates",
               "evaluate.candidate_seed", "evaluate.candidate_folds", "evaluate.ablations",
               "evaluate.fit_spaces"),
              help="choose feature components and fit one GP per (class, component)"),
    StageSpec("evaluate", "stages.evaluate", ("data", "features", "models"), ("evaluate", "plan"), methods=True,
              help="the population evaluation (targets x tracks x localization settings x methods, CIs, "
                   "verdict) and the detailed track's experiments", after=("report",)),
    StageSpec("report", "stages.report", ("models", "evaluate"), ("report",), defaults=True,
              help="render the HTML + PNG report from existing results"),
    StageSpec("simulate", "stages.simulate", (), ("simulate",), methods=True,
              help="simulation scenarios of the paper's section 5.3 (synthetic GP measurements)"),
)}

ORDER = ("data", "classifier", "features", "models", "evaluate", "report", "simulate")


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
    top_level: frozenset[str]                               # names the module's top level uses


def _source(path: Path) -> _Source:
    st = path.stat()
    return _parse(str(path), st.st_size, st.st_mtime_ns, declares_settings(path, ROOT))


# Import statements, found in the source text: ``import a.b as c, d`` and ``from .x import (y, z)``
# at any indentation (imports inside functions count). Faster than building the syntax tree, and
# tests/test_status_imports.py checks it finds exactly what the tree holds in every project file;
# an import-like line inside a string can only add a dependency, never lose one.
_IMPORT_RE = re.compile(r"(?:^|;)[ \t]*(?:from[ \t]+(\.*)[ \t]*([\w.]*)[ \t]+import[ \t]+"
                        r"(\([^)]*\)|[^\n#;\\]*(?:\\\n[^\n#;\\]*)*)"
                        r"|import[ \t]+([^\n#;\\]*(?:\\\n[^\n#;\\]*)*))", re.M)


def scan_imports(text: str) -> tuple[tuple[int, str, tuple[str, ...]], ...]:
    """(level, module, imported names) of every import statement in a source text."""
    out: list[tuple[int, str, tuple[str, ...]]] = []
    for m in _IMPORT_RE.finditer(text):
        if m.group(4) is not None:
            for part in _names(m.group(4)):
                out.append((0, part, ()))
        else:
            out.append((len(m.group(1)), m.group(2), tuple(_names(m.group(3)))))
    return tuple(out)


def _names(text: str) -> list[str]:
    text = re.sub(r"#[^\n]*", "", text).replace("\\\n", " ").strip().strip("()")
    names = [t.split(" as ")[0].strip() for t in text.split(",")]
    return [n for n in names if _DOTTED.fullmatch(n)]


_DOTTED = re.compile(r"[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*")


@functools.lru_cache(maxsize=1024)
def _parse(path: str, size: int, mtime_ns: int, settings: bool = False) -> _Source:
    # Read once per (file, size, mtime): every stage's dependency walk visits most project
    # modules, and ``viewfuse status`` computes every stage's key.
    data = Path(path).read_bytes()
    try:
        # optimize=2 leaves docstrings out of the code (and assert statements, which the project
        # does not use); the byte code never holds comments or line numbers outside the tables
        # _code_digest skips.
        code = compile(data, path, "exec", dont_inherit=True, optimize=2)
    except (SyntaxError, ValueError):
        return _Source(sha256_bytes(data), (), frozenset())
    h = sha256_stream()
    # A config module (``settings``): its settings' declarations enter the key as resolved values,
    # not as code (stages.framework.declarations).
    _code_digest(compile(without_declarations(ast.parse(data, path)), path, "exec", dont_inherit=True, optimize=2)
                 if settings else code, h)
    return _Source(h.hexdigest(), scan_imports(data.decode("utf-8", "replace")), frozenset(code.co_names))


def _code_digest(co, h) -> None:
    """What a code object does: its byte code, names, argument layout and constants (recursively),
    not where it sits in the file (line tables, first line, file name)."""
    code = co.co_code
    # The NOPs stand for lines without code (a docstring left out): what the code says about
    # itself, not what it does. Instructions are 2-byte units; inline caches are never NOPs.
    h.update(b"".join(code[i:i + 2] for i in range(0, len(code), 2) if code[i] != _NOP))
    h.update(co.co_exceptiontable)
    h.update(repr((co.co_name, co.co_names, co.co_varnames, co.co_freevars, co.co_cellvars, co.co_argcount,
                   co.co_posonlyargcount, co.co_kwonlyargcount, co.co_flags)).encode())
    for c in co.co_consts:
        if hasattr(c, "co_code"):
            _code_digest(c, h)
        else:
            h.update(_const_repr(c).encode())


_NOP = dis.opmap["NOP"]


def _const_repr(c) -> str:
    # frozenset constants ("x in {'a', 'b'}") print in hash order, which varies between processes
    if isinstance(c, frozenset):
        return "frozenset(" + ",".join(sorted(_const_repr(x) for x in c)) + ")"
    if isinstance(c, tuple):
        return "(" + ",".join(_const_repr(x) for x in c) + ")"
    return f"{type(c).__name__}:{c!r}"


def source_fingerprint(path: str | Path) -> str:
    """sha256 of what a Python file's code does (its compiled byte code and constants) without
    comments, docstrings or line numbers: editing what code says about itself does not make a
    stage stale; editing what it does does. In the config package the settings' declarations are
    left out too (their resolved values are in the keys: ``stages.framework.declarations``). A
    file that does not compile is hashed as bytes."""
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
    """(hash, {module: fingerprint of its code}) over the stage's derived code modules
    (``source_fingerprint``: comments and docstrings do not count)."""
    mods = set(code_deps(spec.module))
    per: dict[str, str] = {}
    for m in sorted(mods):
        path = _module_file(m)
        if path is None:
            raise ValueError(f"stage {spec.name!r}: code module {m!r} is not a project module")
        per[m] = source_fingerprint(path)
    h = sha256_bytes("".join(f"{k}={v}\n" for k, v in sorted(per.items())).encode())
    return h, per


def defines(module: str, name: str) -> bool | None:
    """Whether project module ``module`` may define ``name`` at its top level (its top-level code
    uses the name), read off its compiled source without importing it (``viewfuse status`` must not
    import torch through a stage module); None when the module is not a file of the source tree."""
    path = _module_file(module)
    return None if path is None else name in _source(path).top_level

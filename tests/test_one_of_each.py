"""One of each: a concept the product code needs in several places is written in one place and
used from there. Each rule is a walk over the product code (``PRODUCT``) with a planted violation
proving it catches one. (Seed derivations: tests/pipeline/infra/test_seeds.py; number formats on
the pages: tests/reports/test_number_format.py; in-function imports: tests/test_inline_imports.py.)

- sha256 of bytes, files, JSON and trees: ``pipeline/infra/cache.py``; digests of arrays:
  ``bank_index.content_digest``; the crop seeds' blake2b: ``pipeline/infra/seeds.py``. No other
  module imports ``hashlib``, and none feeds an array's bytes to a digest of its own.
- Path containment (a resolved path inside a resolved root): ``cache.within``.
- A private number formatter (a ``_``-function returning a number and its unit, or named ``_fmt``):
  none; console spans of time are ``pipeline.infra.progress.duration``, page numbers
  ``reports.shared.numbers``.
- The predictive covariance of a GP at test points (the prior kernel plus the test noise minus
  the whitened Gram): ``pipeline.method.gp.predictive_covariance``.
- Discovery of built-in modules and entry points: ``pipeline.infra.registry.Registry``."""
from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = ("pipeline", "loaders", "reports", "stages", "viewfuse")
HASH_HOMES = {"pipeline/infra/cache.py", "pipeline/method/bank_index.py", "pipeline/infra/seeds.py"}
CONTAINMENT_HOME = {"pipeline/infra/cache.py"}
# viewfuse/_check.py runs before any project package may be imported (it checks that they are
# this project's): it cannot import the helper it would be checking.
CONTAINMENT_EXEMPT = {"viewfuse/_check.py"}
NUMBER_HOMES = {"reports/shared/numbers.py", "pipeline/infra/progress.py"}
COVARIANCE_HOME = ("pipeline/method/gp.py", "predictive_covariance")
DISCOVERY_HOME = {"pipeline/infra/registry.py"}
NUMERIC_SPEC = re.compile(r"\.\d|[eEfFgG%]$")


_PARSED: dict[tuple[str, int], ast.Module] = {}


def _files(root: Path):
    for d in PRODUCT:
        for p in sorted((root / d).rglob("*.py")):
            key = (str(p), p.stat().st_mtime_ns)
            if key not in _PARSED:
                _PARSED[key] = ast.parse(p.read_text())
            yield p.relative_to(root).as_posix(), _PARSED[key]


def _dotted(node) -> str:
    if isinstance(node, ast.Attribute):
        return f"{_dotted(node.value)}.{node.attr}"
    return node.id if isinstance(node, ast.Name) else ""


def digest_offences(root: Path) -> list[str]:
    out = []
    for rel, tree in _files(root):
        if rel in HASH_HOMES:
            continue
        for n in ast.walk(tree):
            if isinstance(n, ast.Import) and any(a.name == "hashlib" for a in n.names) or \
                    isinstance(n, ast.ImportFrom) and n.module == "hashlib":
                out.append(f"{rel}:{n.lineno}: imports hashlib (cache.sha256_* / bank_index.content_digest)")
            if isinstance(n, ast.Call) and _dotted(n.func).endswith(".update") and any(
                    isinstance(c, ast.Call) and _dotted(c.func).endswith(".tobytes") for a in n.args for c in ast.walk(a)):
                out.append(f"{rel}:{n.lineno}: digests an array's bytes itself (bank_index.content_digest)")
    return out


def containment_offences(root: Path) -> list[str]:
    out = []
    for rel, tree in _files(root):
        if rel in CONTAINMENT_HOME | CONTAINMENT_EXEMPT:
            continue
        for n in ast.walk(tree):
            if isinstance(n, ast.Call) and _dotted(n.func).split(".")[-1] in ("commonpath", "is_relative_to",
                                                                             "commonprefix"):
                out.append(f"{rel}:{n.lineno}: {_dotted(n.func)} (path containment: cache.within)")
    return out


def _returns_formatted_number(fn) -> bool:
    rets = [r.value for r in ast.walk(fn) if isinstance(r, ast.Return) and r.value is not None]

    def number(e) -> bool:
        if isinstance(e, ast.IfExp):
            return number(e.body) and number(e.orelse)
        if not isinstance(e, ast.JoinedStr):
            return False
        # a number and its unit: every field numeric, the text around them a few characters
        fields = [v for v in e.values if isinstance(v, ast.FormattedValue)]
        text = "".join(v.value for v in e.values if isinstance(v, ast.Constant))
        return bool(fields) and len(text) <= 8 and all(
            v.format_spec is not None and NUMERIC_SPEC.search(
                "".join(c.value for c in v.format_spec.values if isinstance(c, ast.Constant))) for v in fields)
    return bool(rets) and all(number(e) for e in rets)


def formatter_offences(root: Path) -> list[str]:
    out = []
    for rel, tree in _files(root):
        if rel in NUMBER_HOMES:
            continue
        for n in ast.walk(tree):
            if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) and n.name.startswith("_") and not n.name.startswith("__") \
                    and (re.search(r"fmt|format", n.name) or _returns_formatted_number(n)):
                out.append(f"{rel}:{n.lineno}: {n.name}, a private number formatter "
                           f"(reports.shared.numbers on the pages, pipeline.infra.progress.duration on the console)")
    return out


def covariance_offences(root: Path) -> list[str]:
    """A function other than the home that adds a GP's ``test_noise`` onto a matrix in place (the
    covariance's diagonal) and also builds the prior kernel (``np.exp``) assembles the joint
    predictive covariance again. (Pointwise variances, ``a + σ² - k H k``, are not this rule's.)"""
    out = []
    for rel, tree in _files(root):
        for fn in ast.walk(tree):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)) or (rel, fn.name) == COVARIANCE_HOME:
                continue
            inner = [x for x in ast.walk(fn) if x is not fn]
            reads = any(isinstance(x, ast.AugAssign) and any(
                isinstance(y, ast.Attribute) and y.attr == "test_noise" for y in ast.walk(x.value)) for x in inner)
            exp = any(isinstance(x, ast.Call) and _dotted(x.func) in ("np.exp", "numpy.exp") for x in inner)
            nested = any(isinstance(x, (ast.FunctionDef, ast.AsyncFunctionDef)) for x in inner)
            if reads and exp and not nested:
                out.append(f"{rel}:{fn.lineno}: {fn.name} assembles a predictive covariance (gp.predictive_covariance)")
    return out


def discovery_offences(root: Path) -> list[str]:
    out = []
    for rel, tree in _files(root):
        if rel in DISCOVERY_HOME:
            continue
        for n in ast.walk(tree):
            if isinstance(n, ast.Call) and _dotted(n.func).split(".")[-1] in ("iter_modules", "walk_packages", "entry_points"):
                out.append(f"{rel}:{n.lineno}: {_dotted(n.func)} (discovery: pipeline.infra.registry.Registry)")
    return out


RULES = (digest_offences, containment_offences, formatter_offences, covariance_offences, discovery_offences)


def test_each_concept_is_written_once():
    found = [o for rule in RULES for o in rule(ROOT)]
    assert not found, "one of each:\n" + "\n".join(found)


PLANTED = {
    digest_offences: ("import hashlib\n", "h = cache.sha256_stream()\nh.update(a.tobytes())\n"),
    containment_offences: ("ok = os.path.commonpath([real, root]) == root\n", "ok = Path(p).resolve().is_relative_to(r)\n"),
    formatter_offences: ("def _fmt(v):\n    return fmt(v)\n",
                         "def _dur(s):\n    return f'{s:.0f} s' if s < 120 else f'{s / 60:.1f} min'\n"),
    covariance_offences: ("def joint(m, c, f, D2, S):\n    k = m.amplitude[c, f] * np.exp(-D2)\n"
                          "    k[0, 0] += m.test_noise[c, f]\n    return k - S\n",),
    discovery_offences: ("for m in pkgutil.iter_modules(__path__):\n    importlib.import_module(m.name)\n",
                         "eps = importlib.metadata.entry_points(group='viewfuse.methods')\n"),
}


def test_each_walk_catches_a_planted_violation(tmp_path):
    for d in PRODUCT:
        (tmp_path / d).mkdir()
    for rule, cases in PLANTED.items():
        for code in cases:
            f = tmp_path / "stages" / "planted.py"
            f.write_text(code)
            assert [o for o in rule(tmp_path) if o.startswith("stages/planted.py:")], (rule.__name__, code)
    (tmp_path / "stages" / "planted.py").write_text(
        "from pipeline.infra.cache import within, sha256_bytes\nok = within(real, root)\n"
        "def _label(v):\n    return f'{v} views'\ndef var(m, c):\n    return m.amplitude[c] + m.test_noise[c]\n")
    assert [o for rule in RULES for o in rule(tmp_path)] == []

"""The lists of built-in methods, planners and metrics (and their counts) in docs/api.md, README.md
and configs/synthetic.toml, written from the registries between marker comments:

    <!-- generated: NAME -->  ...  <!-- /generated -->        (Markdown)
    # generated: NAME  ...  # /generated                     (TOML)

    python tools/gen_docs.py           # exit 1 and name the blocks that differ from the registries
    python tools/gen_docs.py --write   # rewrite them

Only the built-ins are listed (a plugin installed in a contributor's environment changes nothing);
tests/test_generated_docs.py fails when a block drifts. ``builtins()`` is the one place that
reads the registries.
"""
from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FILES = ("README.md", "docs/api.md", "configs/synthetic.toml")
COMMAND = "python tools/gen_docs.py --write"
MD = re.compile(r"(<!-- generated: (\w+) -->\n)(.*?)(<!-- /generated -->)", re.S)
TOML = re.compile(r"(# generated: (\w+)[^\n]*\n)(.*?)(# /generated)", re.S)


def builtins() -> dict[str, list[str]]:
    """{kind: built-in keys in registry order} for methods, planners and metrics."""
    sys.path.insert(0, str(ROOT))
    import viewfuse as vf
    from pipeline.evaluation.metrics.spec import METRICS
    from pipeline.method import registry
    from pipeline.planning.planners import PLANNERS

    methods = [k for k in vf.methods() if type(registry.get(k)).__module__.startswith("pipeline.")]
    return {"methods": methods, "planners": [k for k in PLANNERS if PLANNERS.is_builtin(k)],
            "metrics": [k for k in METRICS if METRICS.is_builtin(k)]}


def _keys(keys: list[str]) -> str:
    return ", ".join(f"`{k}`" for k in keys)


def _wrap(text: str, prefix: str = "", width: int = 100) -> str:
    lines, line = [], prefix
    for word in text.split(" "):
        if len(line) + len(word) + 1 > width and line.strip(prefix.strip() or " "):
            lines.append(line.rstrip())
            line = prefix
        line += word + " "
    lines.append(line.rstrip())
    return "\n".join(lines) + "\n"


def blocks(lists: dict[str, list[str]]) -> dict[str, str]:
    """The text of each named block (Markdown; the TOML ones are these as comments)."""
    m, p, x = lists["methods"], lists["planners"], lists["metrics"]
    return {
        "methods": _wrap(f"`vf.methods()` lists the keys of the {len(m)} built-in methods: {_keys(m)}, "
                         "then any you register."),
        "builtins": _wrap(f"Built in: {len(m)} fusion methods ({_keys(m)}), {len(p)} view planners "
                          f"({_keys(p)}) and {len(x)} metrics ({_keys(x)}); each kind takes more "
                          "from outside ([docs/extending.md](docs/extending.md))."),
        "planners_metrics": _wrap(f"The {len(p)} built-in planners: {_keys(p)}. The {len(x)} built-in "
                                  f"metrics: {_keys(x)}."),
        "evaluate": _wrap(f"The {len(m)} built-in methods: {', '.join(m)} (each where its inputs exist).", "# "),
        "plan": _wrap(f"The {len(p)} built-in planners: {', '.join(p)}.", "# "),
    }


def render(text: str, toml: bool, texts: dict[str, str], path: str) -> str:
    def one(mt):
        name = mt.group(2)
        if name not in texts:
            raise SystemExit(f"{path}: unknown generated block {name!r} (known: {', '.join(texts)})")
        return mt.group(1) + texts[name] + mt.group(4)
    return (TOML if toml else MD).sub(one, text)


def rendered(root: Path = ROOT, lists: dict[str, list[str]] | None = None) -> list[tuple[Path, str, str]]:
    """(file, its text, its text with every generated block from the registries) of each file."""
    texts = blocks(lists or builtins())
    out = []
    for rel in FILES:
        old = (root / rel).read_text()
        out.append((root / rel, old, render(old, rel.endswith(".toml"), texts, rel)))
    return out


def drift(root: Path = ROOT, lists: dict[str, list[str]] | None = None) -> list[str]:
    """The files whose generated blocks differ from the registries."""
    return [p.relative_to(root).as_posix() for p, old, new in rendered(root, lists) if new != old]


def write(root: Path = ROOT, lists: dict[str, list[str]] | None = None) -> list[str]:
    changed = []
    for p, old, new in rendered(root, lists):
        if new != old:
            p.write_text(new)
            changed.append(p.relative_to(root).as_posix())
    return changed


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="rewrite the generated blocks")
    args = ap.parse_args(argv)
    if args.write:
        print("\n".join(f"rewrote {f}" for f in write()) or "nothing to rewrite")
        return 0
    stale = drift()
    if stale:
        print(f"generated blocks out of date in: {', '.join(stale)}; run: {COMMAND}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Rewrite module paths after a move: ``python tools/rewrite_imports.py MOVES FILE...``.

MOVES is a text file of ``old.module new.module`` lines (a moved top-level name may be given as
``old.module.name new.module.name``). One pass per line, so a new name is never rewritten again:
``from a.b import c`` lines are mapped as a whole (the module ``a.b.c`` or the package ``a.b`` moved),
and every other dotted name (``a.b.c.attr``: monkeypatch targets, docs) or source path
(``a/b/c.py``) by its longest moved prefix.
"""
from __future__ import annotations

import re
import sys
from pathlib import Path

ROOTS = r"(?:pipeline|reports|stages|loaders|tests)"
FROM = re.compile(r"^(?P<ind>[ \t]*)from (?P<pkg>[\w.]+) import (?P<name>\w+)(?P<alias> as \w+)?(?P<rest>[ \t]*(#.*)?)$")
FROM_ANY = re.compile(r"^(?P<ind>[ \t]*)from (?P<pkg>[\w.]+) import ")
DOTTED = re.compile(rf"(?<![\w./]){ROOTS}(?:\.\w+)+")
PATH = re.compile(rf"(?<![\w./]){ROOTS}(?:/\w+)+\.py\b")


def read_moves(path: str) -> dict[str, str]:
    out = {}
    for line in Path(path).read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            old, new = line.split()
            out[old] = new
    return out


def map_name(dotted: str, moves: dict[str, str]) -> str:
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        head = ".".join(parts[:i])
        if head in moves:
            return ".".join([moves[head]] + parts[i:])
    return dotted


def rewrite_line(line: str, moves: dict[str, str]) -> str:
    m = FROM.match(line)
    if m:
        full = f"{m['pkg']}.{m['name']}"
        new = map_name(full, moves)
        if full in moves:
            npkg, _, nname = new.rpartition(".")
            alias = m["alias"] or ("" if nname == m["name"] else f" as {m['name']}")
            return f"{m['ind']}from {npkg} import {nname}{alias}{m['rest']}"
        npkg = map_name(m["pkg"], moves)
        return f"{m['ind']}from {npkg} import {m['name']}{m['alias'] or ''}{m['rest']}"
    m = FROM_ANY.match(line)
    if m:
        return f"{m['ind']}from {map_name(m['pkg'], moves)} import " + line[m.end():]
    line = DOTTED.sub(lambda t: map_name(t.group(0), moves), line)

    def path_sub(t: re.Match) -> str:
        dotted = t.group(0)[:-3].replace("/", ".")
        new = map_name(dotted, moves)
        return t.group(0) if new == dotted else new.replace(".", "/") + ".py"
    return PATH.sub(path_sub, line)


def rewrite(text: str, moves: dict[str, str]) -> str:
    return "".join(rewrite_line(ln[:-1] if ln.endswith("\n") else ln, moves) + ("\n" if ln.endswith("\n") else "")
                   for ln in text.splitlines(keepends=True))


def main(argv: list[str]) -> int:
    moves = read_moves(argv[0])
    for f in argv[1:]:
        p = Path(f)
        old = p.read_text()
        new = rewrite(old, moves)
        if new != old:
            p.write_text(new)
            print(f"rewrote {f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

"""The documentation holds together: every relative markdown link in README.md and docs/ points to
a file or folder of the repository, and the README stays a user's guide (at most 150 lines;
measurements and findings live in docs/benchmarks.md and docs/results.md)."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README_MAX_LINES = 150
# [text](target) and [text](<target with spaces>); images too. Not inside code spans or fences.
LINK = re.compile(r"!?\[[^\]]*\]\(\s*(<[^>]*>|[^)\s]+)(?:\s+\"[^\"]*\")?\s*\)")
FENCE = re.compile(r"^\s*(```|~~~)")


def documents(root: Path) -> list[Path]:
    return [root / "README.md", *sorted((root / "docs").rglob("*.md"))]


def links(text: str) -> list[tuple[int, str]]:
    """(line number, target) of every markdown link outside fenced blocks and code spans."""
    out, fenced = [], False
    for no, line in enumerate(text.splitlines(), start=1):
        if FENCE.match(line):
            fenced = not fenced
            continue
        if fenced:
            continue
        line = re.sub(r"`[^`]*`", "", line)
        out += [(no, m.group(1).strip("<>")) for m in LINK.finditer(line)]
    return out


def file_links(doc: Path) -> list[tuple[int, str, Path]]:
    """(line number, target, resolved path) of ``doc``'s links to files: URLs (https:, mailto:) and
    anchors in the page left out."""
    return [(no, t, (doc.parent / t.split("#", 1)[0]).resolve()) for no, t in links(doc.read_text())
            if not re.match(r"^[a-z][a-z0-9+.-]*:", t, re.IGNORECASE) and not t.startswith("#")]


def broken_links(root: Path) -> list[str]:
    bad = []
    for doc in documents(root):
        for no, target, resolved in file_links(doc):
            if not resolved.exists():
                bad.append(f"{doc.relative_to(root)}:{no}: {target} (no {resolved})")
            elif root.resolve() not in resolved.parents and resolved != root.resolve():
                bad.append(f"{doc.relative_to(root)}:{no}: {target} leaves the repository")
    return bad


def test_every_relative_link_in_the_docs_resolves():
    bad = broken_links(ROOT)
    assert not bad, "broken links:\n" + "\n".join(bad)


def linked_files(doc: Path) -> set[Path]:
    return {resolved for _, _, resolved in file_links(doc)}


def test_the_readme_is_a_short_guide_that_links_the_docs():
    readme = ROOT / "README.md"
    n = len(readme.read_text().splitlines())
    assert n <= README_MAX_LINES, f"README.md has {n} lines (at most {README_MAX_LINES}: detail goes to docs/)"
    linked = linked_files(readme)
    for doc in ("docs/usage.md", "docs/api.md", "docs/design.md", "docs/results.md", "docs/benchmarks.md", "docs/formats/avd.md",
                "docs/formats/bigbird.md"):
        assert (ROOT / doc).resolve() in linked, f"README.md does not link {doc}"
    formats = (ROOT / "docs" / "formats").resolve()
    assert any(formats in p.parents for p in linked_files(ROOT / "docs" / "design.md")), \
        "docs/design.md does not link docs/formats/"


def test_the_link_check_catches_a_planted_broken_link(tmp_path):
    root = tmp_path / "repo"                               # elsewhere.md beside it, outside the repository
    (root / "docs").mkdir(parents=True)
    (root / "docs" / "design.md").write_text("see [fusion](../pipeline/method/fusion.py)\n")
    (root / "README.md").write_text(
        "[ok](docs/design.md) [web](https://example.org) [here](#top)\n"
        "`[not a link](nowhere.md)`\n"
        "```\n[in a fence](nowhere.md)\n```\n"
        "[gone](docs/missing.md#part)\n"
        "[outside](../elsewhere.md)\n")
    (tmp_path / "elsewhere.md").write_text("x")
    bad = broken_links(root)
    assert len(bad) == 3, bad
    assert any("docs/design.md:1: ../pipeline/method/fusion.py" in b for b in bad)
    assert any("README.md:6: docs/missing.md#part" in b for b in bad)
    assert any("README.md:7: ../elsewhere.md leaves the repository" in b for b in bad)

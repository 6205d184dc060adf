"""Numbers on the pages are formatted only by reports/shared/numbers.py, and a missing value has
one spelling (``numbers.MISSING``): a walk over reports/ that fails on a format specification
(``f"{x:.3f}"``, ``"{:g}".format``, ``"%.2f" %``) or another spelling of a missing value
("n/a", "nan", an en dash) anywhere else."""
import ast
import re
from pathlib import Path

import pytest

from reports.shared.numbers import MISSING, fmt, percent, plain

ROOT = Path(__file__).resolve().parents[2]
OWN = ROOT / "reports" / "shared" / "numbers.py"
NUMERIC_SPEC = re.compile(r"\.\d|[eEfFgG%]$|^[^{}]*,")
FORMAT_FIELD = re.compile(r"\{[^{}]*:[^{}]*(\.\d|[eEfFgG%])\}")
PERCENT_FORMAT = re.compile(r"%[-+ 0#]*\d*(\.\d+)?[eEfFgG]")
OTHER_MISSING = {"n/a", "N/A", "nan", "NaN", "–"}


def _spec_text(spec: ast.JoinedStr) -> str:
    return "".join(v.value for v in spec.values if isinstance(v, ast.Constant))


def offences(path: Path, root: Path = ROOT) -> list[str]:
    tree, out = ast.parse(path.read_text(), str(path)), []
    # float("nan") is a value, and text between the fields of an f-string ("{a}–{b}") a range
    skip = {id(a) for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "float"
            for a in n.args}
    skip |= {id(v) for n in ast.walk(tree) if isinstance(n, ast.JoinedStr) for v in n.values}
    for n in ast.walk(tree):
        where = f"{path.relative_to(root)}:{getattr(n, 'lineno', '?')}"
        if isinstance(n, ast.FormattedValue) and n.format_spec is not None:
            spec = _spec_text(n.format_spec)
            if NUMERIC_SPEC.search(spec):
                out.append(f"{where}: format spec ':{spec}'")
        elif isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and n.func.attr == "format" \
                and isinstance(n.func.value, ast.Constant) and isinstance(n.func.value.value, str) \
                and FORMAT_FIELD.search(n.func.value.value):
            out.append(f"{where}: str.format with a number format")
        elif isinstance(n, ast.BinOp) and isinstance(n.op, ast.Mod) and isinstance(n.left, ast.Constant) \
                and isinstance(n.left.value, str) and PERCENT_FORMAT.search(n.left.value):
            out.append(f"{where}: %-formatting of a number")
        elif isinstance(n, ast.Constant) and n.value in OTHER_MISSING and id(n) not in skip:
            out.append(f"{where}: {n.value!r} for a missing value (use numbers.MISSING)")
    return out


def test_reports_format_numbers_only_through_the_numbers_module():
    files = [p for p in sorted((ROOT / "reports").rglob("*.py")) if p != OWN]
    found = [o for p in files for o in offences(p)]
    assert not found, "format numbers with reports.shared.numbers (fmt, percent, plain, Estimate):\n" + "\n".join(found)


@pytest.mark.parametrize("code", ['f"{x:.3f}"', 'f"{x:g}"', 'f"{100 * s:.0f} %"', 'f"{x:+.2f}"', 'f"{n:,}"',
                                  '"{:.2f}".format(x)', '"%.1f MiB" % x', 'cell = "n/a"', 'x or "–"'])
def test_the_walk_catches_each_way_of_formatting(tmp_path, code):
    f = tmp_path / "m.py"
    f.write_text(code + "\n")
    assert offences(f, tmp_path)


def test_the_walk_lets_plain_text_through(tmp_path):
    f = tmp_path / "ok.py"
    f.write_text('f"{name:>10} {count} {fmt(x)} {percent(s)}"\nv = float("nan")\n"{}/{}".format(a, b)\n')
    assert offences(f, tmp_path) == []


def test_missing_values_read_the_same_everywhere():
    from reports.shared.html import format_cell

    assert fmt(None) == fmt(float("nan")) == percent(None) == plain(float("nan")) == MISSING
    assert format_cell(None)[0] == MISSING

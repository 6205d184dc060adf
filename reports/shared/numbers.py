"""One number format for every report table, caption, sentence and the compare page.

``Estimate.text`` rounds a value and its 95 % interval to the place the interval's width allows
(``ci_digits``); ``fmt`` gives ``sig`` significant digits and keeps trailing zeros so a column reads ``1.00`` next
to ``0.886`` (not ``1`` next to ``0.8856``). Plain decimals from 1e-4 up to 1e5 (``-0.000793``
next to ``-0.00657``, not ``-7.93e-04``); a short exponent outside (``9.50e-6``, ``3.30e5``); below
1e-6 in size a value is shown as ``< 1e-6`` (``> −1e-6`` when negative): such digits are
bootstrap noise around 0, not information. MGR values reach the reports as log10 already.
A missing value (None, NaN) reads ``MISSING`` everywhere; ``plain`` writes a setting as configured
(``0.9``, ``1e-06``) and ``percent`` a share. Nothing in ``reports/`` formats a number itself
(tests/reports/test_number_format.py walks the code).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Mapping

from pipeline.infra.outputs import number

SIG = 3
TINY = 1e-6        # below this in size: "< 1e-6"
HUGE = 1e5         # from this up: exponent notation
SMALL = 1e-4       # below this (down to TINY): a short exponent, 9.50e-6, not 0.00000950
MINUS = "−"        # typographic minus, as everywhere on the pages
MISSING = "—"      # the one spelling of a missing value, in tables and sentences alike


def fmt(value: Any, sig: int = SIG, *, signed: bool = False) -> str:
    """A float with ``sig`` significant digits; None/NaN as ``MISSING``, infinities as ∞."""
    if value is None:
        return MISSING
    try:
        v = float(value)
    except (TypeError, ValueError):
        return str(value)
    if math.isnan(v):
        return MISSING
    if math.isinf(v):
        return "∞" if v > 0 else MINUS + "∞"
    if v == 0:
        return f"{0:.{sig - 1}f}"
    a = abs(v)
    sign = MINUS if v < 0 else ("+" if signed else "")
    if a < TINY:
        return f"> {MINUS}1e-6" if v < 0 else ("< +1e-6" if signed else "< 1e-6")
    if a >= HUGE or a < SMALL:
        mant, exp = f"{a:.{sig - 1}e}".split("e")
        return f"{sign}{mant}e{int(exp)}"
    # Decimals for sig significant digits (the rounding may carry into one more integer digit).
    mag = math.floor(math.log10(a))
    digits = max(sig - 1 - mag, 0)
    # integers past sig digits are rounded too: 1836 -> 1840, 32591 -> 32600
    text = f"{a:.{digits}f}" if digits else f"{round(a, sig - 1 - mag):.0f}"
    if digits and len(text.replace(".", "").lstrip("0")) > sig:  # 9.996 -> 10.00: drop one decimal
        text = f"{a:.{digits - 1}f}"
    return sign + text


@dataclass(frozen=True)
class Estimate:
    """A value with its 95 % confidence interval; renders as 'value [lo, hi]'."""
    value: float | None
    low: float | None = None
    high: float | None = None
    signed: bool = False   # differences: '+0.18 [+0.01, +0.32]'

    @classmethod
    def of(cls, d: Mapping | None, signed: bool = False) -> "Estimate":
        """From a contract entry {"value", "ci_low", "ci_high"} (None when absent)."""
        d = d or {}
        return cls(d.get("value"), d.get("ci_low"), d.get("ci_high"), signed)

    def text(self, sig: int | None = None, signed: bool | None = None) -> str:
        """'value [lo, hi]'. By default the digits follow the interval's width (``ci_digits``): a
        value is shown to the place its uncertainty allows; ``sig`` forces that many significant
        digits instead."""
        signed = self.signed if signed is None else signed
        if _missing(self.low) and _missing(self.high):  # no interval (e.g. one track): the value alone
            return fmt(self.value, sig or SIG, signed=signed)
        texts = None if sig is not None else ci_digits(self.value, self.low, self.high, signed)
        if texts is None:
            s = sig or SIG
            texts = tuple(fmt(x, s, signed=signed) for x in (self.value, self.low, self.high))
        return f"{texts[0]} [{texts[1]}, {texts[2]}]"

    def excludes_zero(self) -> bool:
        return (self.low is not None and self.high is not None
                and (float(self.low) > 0 or float(self.high) < 0))


def ci_digits(value, low, high, signed: bool = False) -> tuple[str, str, str] | None:
    """Value and interval ends rounded to one decimal place: the one that keeps two significant
    digits of the interval's width (0.181 [0.0139, 0.319] -> 0.18 [0.01, 0.32]). An end that this
    rounding would turn into 0 (or whose sign it would hide) keeps two significant digits of its own,
    so an interval that excludes 0 never reads as touching it. None where the rule does not apply
    (an infinite or missing end, no width, or values that ``fmt`` writes with an exponent)."""
    try:
        v, lo, hi = float(value), float(low), float(high)
    except (TypeError, ValueError):
        return None
    xs = (v, lo, hi)
    if not all(math.isfinite(x) for x in xs) or hi - lo <= 0:
        return None
    if any(abs(x) >= HUGE or 0 < abs(x) < SMALL for x in xs):
        return None
    place = math.floor(math.log10(hi - lo)) - 1          # two significant digits of the width
    out = []
    for x in xs:
        r = round(x, -place)
        if x != 0 and (r == 0 or (r > 0) != (x > 0)):
            out.append(fmt(x, 2, signed=signed))
            continue
        text = f"{abs(r):.{max(-place, 0)}f}"
        sign = MINUS if r < 0 else ("+" if signed and r > 0 else "")
        out.append(sign + text if float(text) != 0 else text)
    return tuple(out)


def percent(share: Any, decimals: int = 0) -> str:
    """A share in the page's one percent style: '8 %' (a space before the sign), ``MISSING`` when missing."""
    if _missing(share):
        return MISSING
    return f"{100 * float(share):.{decimals}f} %".replace("-", MINUS)


def plain(value: Any, *, signed: bool = False) -> str:
    """A setting as it was configured, in its shortest form (``0.9``, ``0.25``, ``1e-06``, ``+0.3``):
    thresholds, sigmas, grid values; ``MISSING`` when missing."""
    if _missing(value):
        return MISSING
    v = float(value)
    if math.isinf(v):
        return fmt(v)
    text = f"{v:+g}" if signed else f"{v:g}"
    return MINUS + text[1:] if text.startswith("-") else text


def _missing(x: Any) -> bool:
    return math.isnan(number(x))


_DECIMAL = re.compile(r"(?<![\w.])([-+−]?)(\d+\.\d+(?:e[-+]?\d+)?|\d+e[-+]?\d+)(?![\w.])")


def reformat_numbers(text: str, sig: int = SIG) -> str:
    """Sentences written elsewhere (the verdict in summary.json) in this module's format: every
    decimal or exponent number goes through ``fmt`` (counts and percentages stay as they are)."""
    def sub(m: re.Match) -> str:
        sign, body = m.group(1), m.group(2)
        v = float(body) * (-1 if sign in ("-", "−") else 1)
        return fmt(v, sig, signed=sign == "+")
    return typeset(_DECIMAL.sub(sub, text))


_TIGHT_PERCENT = re.compile(r"(\d)%")
_HYPHEN_MINUS = re.compile(r"(?<![\w./-])-(?=\d)")


def typeset(text: str) -> str:
    """The page's one style for text written anywhere (labels from the results, the config):
    '8%' -> '8 %', a hyphen used as a minus sign ('(-0.30, ...') -> '−'. Every text the HTML
    builder writes goes through here; file names and preformatted text do not."""
    return _HYPHEN_MINUS.sub(MINUS, _TIGHT_PERCENT.sub(r"\1 %", text))

"""One number format for every report table, caption, sentence and the compare page.

``fmt`` gives ``sig`` significant digits and keeps trailing zeros so a column reads ``1.00`` next
to ``0.886`` (not ``1`` next to ``0.8856``). Plain decimals from 1e-4 up to 1e5 (``-0.000793``
next to ``-0.00657``, not ``-7.93e-04``); a short exponent outside (``9.50e-6``, ``3.30e5``); below
1e-6 in size a value is shown as ``< 1e-6`` (``> −1e-6`` when negative): such digits are
bootstrap noise around 0, not information. MGR values reach the reports as log10 already.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Mapping

SIG = 3
TINY = 1e-6        # below this in size: "< 1e-6"
HUGE = 1e5         # from this up: exponent notation
SMALL = 1e-4       # below this (down to TINY): a short exponent, 9.50e-6, not 0.00000950
MINUS = "−"        # typographic minus, as everywhere on the pages


def fmt(value: Any, sig: int = SIG, *, signed: bool = False) -> str:
    """A float with ``sig`` significant digits; None/NaN as 'n/a', infinities as ∞."""
    if value is None:
        return "n/a"
    try:
        v = float(value)
    except (TypeError, ValueError):
        return str(value)
    if math.isnan(v):
        return "n/a"
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

    def text(self, sig: int = SIG, signed: bool | None = None) -> str:
        signed = self.signed if signed is None else signed
        v = fmt(self.value, sig, signed=signed)
        if _missing(self.low) and _missing(self.high):  # no interval (e.g. one track): the value alone
            return v
        return f"{v} [{fmt(self.low, sig, signed=signed)}, {fmt(self.high, sig, signed=signed)}]"

    def excludes_zero(self) -> bool:
        return (self.low is not None and self.high is not None
                and (float(self.low) > 0 or float(self.high) < 0))


def _missing(x: Any) -> bool:
    try:
        return x is None or math.isnan(float(x))
    except (TypeError, ValueError):
        return True


_DECIMAL = re.compile(r"(?<![\w.])([-+−]?)(\d+\.\d+(?:e[-+]?\d+)?|\d+e[-+]?\d+)(?![\w.])")


def reformat_numbers(text: str, sig: int = SIG) -> str:
    """Sentences written elsewhere (the verdict in summary.json) in this module's format: every
    decimal or exponent number goes through ``fmt`` (counts and percentages stay as they are)."""
    def sub(m: re.Match) -> str:
        sign, body = m.group(1), m.group(2)
        v = float(body) * (-1 if sign in ("-", "−") else 1)
        return fmt(v, sig, signed=sign == "+")
    return _DECIMAL.sub(sub, text)

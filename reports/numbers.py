"""One number format for every report table, caption and sentence: significant digits.

``fmt`` keeps trailing zeros so a column reads ``1.00`` next to ``0.886`` (not ``1`` next to
``0.8856``), switches to scientific notation only outside [1e-3, 1e5), and never shows a raw MGR:
MGR values reach the reports as log10 already.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

SIG = 3


def fmt(value: Any, sig: int = SIG, *, signed: bool = False) -> str:
    """A float with ``sig`` significant digits; None/NaN as 'n/a', infinities as ∞."""
    if value is None:
        return "n/a"
    v = float(value)
    if math.isnan(v):
        return "n/a"
    if math.isinf(v):
        return ("∞" if v > 0 else "−∞")
    sign = "+" if signed and v > 0 else ""
    if v == 0:
        return f"{0:.{sig - 1}f}"
    if abs(v) >= 1e5 or abs(v) < 1e-3:
        return sign + f"{v:.{sig - 1}e}"
    return sign + f"{v:#.{sig}g}".rstrip(".")


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
        if self.low is None and self.high is None:
            return v
        return f"{v} [{fmt(self.low, sig, signed=signed)}, {fmt(self.high, sig, signed=signed)}]"

    def excludes_zero(self) -> bool:
        return (self.low is not None and self.high is not None
                and (float(self.low) > 0 or float(self.high) < 0))

"""The one error at the boundary between viewfuse and outside code (a fusion method, classifier,
planner, metric, dataset source or model provider, registered from a script or an entry point):
``ExtensionError`` names the kind, the key, the hook and the cause, whether the breach is found at
registration (a missing attribute, a wrong signature, a bad key or colour), while loading an entry
point, or when the hook runs (an exception, a wrong output, a call that does not return).

It is a ``TypeError`` and a ``ValueError`` at once, so code written against the errors each kind
raised before (a wrong type, a wrong value) still catches it. ``plain_name`` is the one check of a
name that becomes a folder or a file name (every kind's key, a dataset source's object names).
"""
from __future__ import annotations

import re

# '#rgb', '#rgba', '#rrggbb', '#rrggbbaa': forms matplotlib draws, told apart without loading it
HEX_COLOR = re.compile(r"#(?:[0-9a-fA-F]{3,4}|[0-9a-fA-F]{6}|[0-9a-fA-F]{8})")

KINDS = ("fusion method", "classifier", "planner", "metric", "dataset source", "model provider")


class ExtensionError(TypeError, ValueError):
    """An outside extension broke the contract. ``kind``, ``key``, ``hook`` and ``cause`` are its
    parts; the message reads "<kind> '<key>' (<hook>): <cause>" unless given whole."""

    def __init__(self, message: str, *, kind: str = "", key: str = "", hook: str = "", cause: str = ""):
        super().__init__(message)
        self.kind, self.key, self.hook, self.cause = kind, key, hook, cause

    @classmethod
    def of(cls, kind: str, key, hook: str, cause: str) -> "ExtensionError":
        return cls(f"{kind} {key!r} ({hook}): {cause}", kind=kind, key=str(key), hook=hook, cause=cause)


# A plain name: letters, digits, '_', '.', '+', '-', starting with a letter, digit or '_' (so never
# '.', '..' or a hidden file), no path separator, no whitespace, at most 128 characters.
PLAIN = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+\-]{0,127}")


def plain_name_problem(name) -> str | None:
    """Why ``name`` cannot be a folder or file name of its own (None: it can)."""
    if not isinstance(name, str):
        return f"must be a string, got {type(name).__name__}"
    if not PLAIN.fullmatch(name):
        return (f"{name!r:.80} is not a plain name (letters, digits and '_.+-', starting with a letter, "
                "digit or '_', at most 128 characters: it becomes a folder or file name, so no '/', '..' "
                "or spaces)")
    return None


def plain_name(kind: str, key, hook: str, name) -> str:
    """``name`` when it is plain; else ``ExtensionError`` naming kind, key and hook."""
    bad = plain_name_problem(name)
    if bad is not None:
        raise ExtensionError.of(kind, key, hook, bad)
    return name


def color_problem(color) -> str | None:
    """Why ``color`` is not a colour the report's figures can draw (None: it is)."""
    if not isinstance(color, str) or not color:
        return f"color must be a colour string (a name such as 'tab:blue', or '#rrggbb'), got {color!r:.60}"
    if HEX_COLOR.fullmatch(color):   # what the built-ins use: no need to load matplotlib at import
        return None
    from matplotlib.colors import is_color_like   # here: matplotlib is heavy, and only registration asks

    if not is_color_like(color):
        return f"color {color!r:.60} is not a colour matplotlib can draw (a name such as 'tab:blue', or '#rrggbb')"
    return None


def text_problem(attr: str, value, *, empty: bool = True) -> str | None:
    """Why ``value`` is not text for ``attr`` (a label, a note): a string, one line."""
    if not isinstance(value, str) or (not empty and not value.strip()) or "\n" in value:
        return f"{attr} must be {'a' if empty else 'a non-empty'} one-line string, got {value!r:.60}"
    return None


def signature_problem(fn, hook: str, call: str, *args, **kwargs) -> str | None:
    """Why ``fn`` cannot be called as ``call`` (with ``args``/``kwargs`` standing in), or None."""
    import inspect

    if not callable(fn):
        return f"{hook} is not callable ({type(fn).__name__})"
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):   # a builtin without a signature: its call will tell
        return None
    try:
        sig.bind(*args, **kwargs)
    except TypeError as e:
        return f"{hook}{sig} cannot be called as {call}: {e}"
    return None


def raise_problems(kind: str, key, hook: str, problems) -> None:
    """One ``ExtensionError`` for every breach found at once (nothing when ``problems`` is empty)."""
    problems = [p for p in problems if p]
    if problems:
        raise ExtensionError.of(kind, key, hook, "; ".join(problems))


def declared_key(cls) -> str:
    """The most derived class's ``key`` (or its older spelling ``name``): a subclass of a built-in
    that sets only ``name`` does not take the built-in's key."""
    for c in (cls if isinstance(cls, type) else type(cls)).__mro__:
        for attr in ("key", "name"):
            if isinstance(vars(c).get(attr), str) and vars(c)[attr]:
                return vars(c)[attr]
    if not isinstance(cls, type):   # an instance's own attribute
        return getattr(cls, "key", "") or getattr(cls, "name", "") or ""
    return ""

"""Names of category classes fitted per instance fold: '<category>__f<k>' is the class of
``category`` fitted without instance ``k``. The data stage writes these names and the protocol
reads them back, so both take them from here (below both floors)."""
from __future__ import annotations

FOLD_SEP = "__f"


def fold_class(category: str, fold: int) -> str:
    """The class of ``category`` in fold ``fold`` (fitted without instance ``fold``)."""
    return f"{category}{FOLD_SEP}{int(fold)}"


def fold_of(name: str) -> str:
    """The fold of a category class ``<category>__f<k>`` (``k``); ValueError for another name."""
    head, sep, k = str(name).rpartition(FOLD_SEP)
    if not sep or not head or not k.isdigit():
        raise ValueError(f"class {name!r} has no fold suffix '{FOLD_SEP}<k>' (evaluate.candidate_folds = true)")
    return k


def category_of(name: str) -> str:
    """The category of a category class or target ``<category>__f<k>`` (``category``); ValueError
    for another name (a target that belongs to no category)."""
    fold_of(name)
    return str(name).rpartition(FOLD_SEP)[0]

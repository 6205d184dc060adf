"""Every named random stream: ``stream(seed, *names)``.

A stream is keyed by a seed and a path of names (a scan, a target, a method key, a track number),
never by the order of draws, so a Ray worker, a local run and a rerun draw the same numbers. A
text name enters as the CRC-32 of its UTF-8 bytes, a non-negative integer as itself, and numpy's
``SeedSequence`` mixes the list: the convention the evaluation grid, planning and the real-imagery
writers have used since their first runs, kept so their numbers stay the same. Floats are
refused (format them first, e.g. ``f"{angle:g}"``): their text is the caller's choice. numpy pads
the list with zeros, so a trailing name 0 adds nothing: streams of one family take the same
number of names.

One older derivation stays beside it, ``crop_seed`` (64 bits of blake2b): every features table's
MC-dropout masks, real-data ones included, are drawn from it, so moving it to ``stream`` would
change every feature. Nothing outside this module turns a name into a seed or derives a stream
of its own from a seed (``[seed, 7]``, ``seed + 1``): it names it, ``stream(seed, 7)``
(tests/pipeline/infra/test_seeds.py walks the code).
"""
from __future__ import annotations

import hashlib
import zlib

import numpy as np


def key(seed: int, *names: str | int) -> list[int]:
    """The seed material of ``stream(seed, *names)``: [seed, one integer per name]; for code that
    hands a seed on (``default_rng(key)`` is the same stream)."""
    out = [_integer(seed, "seed")]
    for n in names:
        out.append(zlib.crc32(n.encode()) if isinstance(n, str) else _integer(n, f"name {n!r}"))
    return out


def stream(seed: int, *names: str | int) -> np.random.Generator:
    """The generator named by (seed, names...): equal in every process for equal arguments."""
    return np.random.default_rng(key(seed, *names))


def integer(seed: int, *names: str | int) -> int:
    """One 32-bit integer of the stream named by (seed, names...), for code that takes an integer
    seed (an optimiser's ``random_state``): the first word ``SeedSequence`` generates from ``key``."""
    return int(np.random.SeedSequence(key(seed, *names)).generate_state(1)[0])


def crop_seed(seed: int, key: str) -> int:
    """The 64-bit seed of one crop's dropout masks, from (seed, crop key) only."""
    h = hashlib.blake2b(f"{int(seed)}|{key}".encode(), digest_size=8).digest()
    return int.from_bytes(h, "little")


def _integer(v, what: str) -> int:
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or v < 0:
        raise TypeError(f"seeds: the {what} must be a text or a non-negative integer, got {type(v).__name__} {v!r}")
    return int(v)

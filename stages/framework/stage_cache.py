"""The stage cache shared across run names: a stage whose key matches a stage some run finished
reuses its outputs instead of computing them again (DVC's run-cache).

Where: ``<artifacts>/.stage-cache/`` — the one place a run writes outside ``<artifacts>/<run>/``
(documented in docs/design.md, "Caching"). Why a store and not a lookup over the other runs'
folders: ``make clean`` removes the runs and keeps the cache, and a run folder can be rerun,
changed or removed at any time. Each entry ``<stage>-<key>/`` holds the outputs of one finished
stage as hard links (a copy where the file system cannot link; never a symlink, which a later
write could redirect) and ``entry.json``: the source run, its manifest, the outputs' sha256.

Reuse: the entry's files are linked into the stage's temporary folder, every file is hashed and
compared with the entry's record (a cached file edited in place, through a link, is caught and
the entry dropped), the dataset files the stage read are checked as an up-to-date check checks
them, and the manifest is written with ``reused`` naming the run. Bounded: ``run.stage_cache_gb``
(0 = off), the least recently used entries (``entry.json``'s mtime, touched on each reuse) removed
first. Stages that write the run's name into their outputs (report, simulate) are never shared.
"""
from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import time
from pathlib import Path

from pipeline.infra.cache import folder_records, record_changed, write_json
from pipeline.infra.outputs import MANIFEST, read_json
from pipeline.infra.progress import echo
from stages.framework.run_folder import OWNER, mark_owned, remove_leftover, stage_paths, swap_in

log = logging.getLogger("viewfuse")

FOLDER = ".stage-cache"
ENTRY = "entry.json"
NOT_SHARED = frozenset({"report", "simulate"})   # their pages name the run (run_name=cfg.run.name)
GIB = 1 << 30


def root(cfg) -> Path:
    """``run.stage_cache`` where set (the seed study sets it to its run's), else <artifacts>/.stage-cache."""
    if cfg.run.stage_cache:
        return Path(os.path.abspath(cfg.path("run.stage_cache")))
    return cfg.artifacts_dir / FOLDER


def bound(cfg) -> int:
    return int(float(cfg.run.stage_cache_gb) * GIB)


def _entry_dir(cfg, stage: str, key: str) -> Path:
    return root(cfg) / f"{stage}-{key}"


def _link_or_copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst, follow_symlinks=False)
    except OSError:   # another file system, or one without hard links
        shutil.copy2(src, dst, follow_symlinks=False)


def _files(manifest: dict) -> dict[str, dict]:
    return {rel: rec for rel, rec in (manifest.get("outputs") or {}).items()}


def publish(cfg, stage: str, manifest: dict, final: Path) -> Path | None:
    """Put a finished stage's outputs in the cache (links), then trim it to ``run.stage_cache_gb``.
    Returns the entry, or None (cache off, a stage not shared, larger than the bound, a failure:
    logged; the run itself never fails for its cache)."""
    limit = bound(cfg)
    if limit <= 0 or stage in NOT_SHARED or manifest.get("reused"):
        return None
    files = _files(manifest)
    size = sum(int(r.get("size", 0)) for r in files.values())
    if size > limit:
        log.info("stage cache: %s not kept (%.2f GiB, over run.stage_cache_gb = %g)", stage, size / GIB,
                 cfg.run.stage_cache_gb)
        return None
    dest = _entry_dir(cfg, stage, manifest["key"])
    if (dest / ENTRY).is_file():
        return dest
    tmp = root(cfg) / f".tmp-{os.getpid()}-{stage}"
    try:
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        for rel in files:
            _link_or_copy(final / rel, tmp / rel)
        entry = {"stage": stage, "key": manifest["key"], "run": cfg.run.name, "size": size,
                 "published": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "manifest": manifest}
        (tmp / ENTRY).write_text(json.dumps(entry, sort_keys=True))
        try:
            os.rename(tmp, dest)
        except OSError:   # another run published the same key first: theirs is as good
            shutil.rmtree(tmp, ignore_errors=True)
    except OSError as e:
        shutil.rmtree(tmp, ignore_errors=True)
        log.warning("stage cache: could not keep %s (%s); the run is not affected", stage, e)
        return None
    evict(cfg, keep=dest)
    return dest


def entries(cfg) -> list[tuple[float, int, Path]]:
    """(last used, bytes, folder) of every entry, least recently used first."""
    out = []
    with contextlib.suppress(OSError):
        for d in root(cfg).iterdir():
            e = d / ENTRY
            with contextlib.suppress(OSError, ValueError, AttributeError):
                out.append((e.stat().st_mtime, int(read_json(e, missing=None, invalid=None).get("size", 0)), d))
    return sorted(out)


def evict(cfg, keep: Path | None = None) -> list[Path]:
    """Remove the least recently used entries until the cache holds at most ``run.stage_cache_gb``."""
    es = entries(cfg)
    total, limit, gone = sum(s for _, s, _ in es), bound(cfg), []
    for _, size, d in es:
        if total <= limit:
            break
        if d == keep:
            continue
        shutil.rmtree(d, ignore_errors=True)
        total -= size
        gone.append(d)
    if gone:
        log.info("stage cache: removed %d least recently used entr%s to stay within run.stage_cache_gb = %g",
                 len(gone), "y" if len(gone) == 1 else "ies", cfg.run.stage_cache_gb)
    return gone


def find(cfg, stage: str, key: str) -> dict | None:
    """The entry for (stage, key), or None."""
    if bound(cfg) <= 0 or stage in NOT_SHARED:
        return None
    d = _entry_dir(cfg, stage, key)
    try:
        entry = read_json(d / ENTRY, missing=None, invalid=None)
    except OSError:
        return None
    if not isinstance(entry, dict):
        return None
    return {**entry, "dir": d} if entry.get("key") == key and entry.get("stage") == stage else None


def reuse(cfg, stage: str, key: str, tmp: Path, inputs_changed) -> dict | None:
    """Fill ``tmp`` from the cache entry for (stage, key) and return the manifest for it, or None
    when there is none or it no longer holds (a file changed: the entry is dropped; a dataset file
    the stage read changed: ``inputs_changed(records)`` says why, the entry is kept)."""
    entry = find(cfg, stage, key)
    if entry is None:
        return None
    src, old = entry["dir"], entry["manifest"]
    why = inputs_changed(old.get("inputs") or {})
    if why:
        log.info("stage cache: %s of run %r not reused: %s", stage, entry["run"], why)
        return None
    t0 = time.perf_counter()
    try:
        for rel in _files(old):
            _link_or_copy(src / rel, tmp / rel)
    except OSError as e:
        log.warning("stage cache: %s of run %r not reused: %s", stage, entry["run"], e)
        return None
    got = folder_records(tmp, skip=(MANIFEST, OWNER))
    bad = sorted(rel for rel, rec in _files(old).items() if (got.get(rel) or {}).get("sha256") != rec.get("sha256"))
    if bad or set(got) != set(_files(old)):
        log.warning("stage cache: %s of run %r changed since it was kept (%s); dropped, the stage runs",
                    stage, entry["run"], ", ".join(bad[:3]) or "files differ")
        shutil.rmtree(src, ignore_errors=True)
        return None
    with contextlib.suppress(OSError):
        os.utime(src / ENTRY)   # most recently used
    reused = {"run": entry["run"], "finished": old.get("finished"), "seconds": old.get("seconds"),
              "cpu_seconds": old.get("cpu_seconds"), "entry": str(src)}
    return {**old, "outputs": got, "seconds": round(time.perf_counter() - t0, 3), "cpu_seconds": 0.0,
            "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "reused": reused}


def changed_inputs(cfg, input_path) -> callable:
    """``reuse``'s check of the dataset files an entry's stage read, against the current config."""
    def check(records: dict) -> str | None:
        memo: dict = {}   # every file hashed (once): the same check an up-to-date stage gets
        for name, rec in records.items():
            path = input_path(cfg, name)
            why = record_changed(path, rec, memo=memo)
            if why:
                return f"input {path} {why}"
        return None
    return check


def adopt(cfg, stage: str, key: str, input_path) -> dict | None:
    """Bring ``stage`` up to date from the cache when an entry matches ``key``: the outputs linked
    into its temporary folder, verified, swapped in with a manifest naming the run they came from.
    Returns that manifest, or None (the stage runs). The caller holds the stage's lock."""
    if find(cfg, stage, key) is None:
        return None
    paths = stage_paths(cfg, stage)
    paths.run_dir.mkdir(parents=True, exist_ok=True)
    if paths.tmp.exists() or paths.tmp.is_symlink():
        remove_leftover(paths.tmp, required=True)
    paths.tmp.mkdir()
    try:
        mark_owned(paths.tmp)
        manifest = reuse(cfg, stage, key, paths.tmp, changed_inputs(cfg, input_path))
        if manifest is None:
            shutil.rmtree(paths.tmp, ignore_errors=True)
            return None
        write_json(paths.tmp / MANIFEST, manifest)
        swap_in(paths)
    except BaseException:
        shutil.rmtree(paths.tmp, ignore_errors=True)
        raise
    r = manifest["reused"]
    echo(f"[{stage}] reused from run {r['run']!r} (stage cache {r['entry']}; it took {r['seconds']} s there): "
         f"{manifest.get('summary')} -> {paths.final}")
    return manifest

"""Run stages with manifests: skip what is up to date, rerun what is stale, write atomically.

Each stage writes into a temporary sibling folder ``.<stage>.tmp``; only when it finishes is that
folder swapped in and the manifest written, so an interrupted run never leaves output that looks
complete (and the next run of any stage removes what a killed run left). Where the runner may
write, the per-stage lock and the swap are ``stages.framework.run_folder``.

A manifest records the stage's key (config sections, code version, upstream digests, the stage's
``extra_key``), the sha256 of every output file and of every dataset file the stage read. A stage
is up to date when its key matches and none of those files changed; otherwise it reruns and says
why. A stage's *digest* (key + its outputs' hashes) is what downstream keys are built from, so
rewriting an upstream output (a model file, results) makes everything below it stale.
"""
from __future__ import annotations

import importlib
import logging
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from loaders.errors import SkipPolicy
from loaders.files import set_max_megapixels
from pipeline.infra.cache import (confined_writes, folder_records, hash_json, load_memo, naming,
                                   record_changed, recording_inputs, remember, save_memo, write_json)
from pipeline.infra.config import Config, to_dict
from pipeline.infra.outputs import MANIFEST, undeclared
from pipeline.infra.outputs import read_manifest as outputs_manifest
from pipeline.infra.progress import duration, echo
from pipeline.infra.workers import pid_file, stop_leftovers
from stages.framework import stage_cache
from stages.framework.outside import banner, check_loaded, outside_parts
from stages.framework.registry import STAGES, StageSpec, code_version, defines
from stages.framework.run_folder import (OWNER, mark_owned, recover_swap, remove_leftover, remove_orphans,  # noqa: F401
                               stage_lock, stage_paths, swap_in)
from pipeline.method.registry import outside_fingerprint
from pipeline.infra.cost import check
from pipeline.infra.cost import describe
from pipeline.infra.device import configure_threads, resolve_device

log = logging.getLogger("viewfuse")

HASHES = "\0hashes"  # ensure()'s per-run memo of file hashes, kept in its digest dict
COSTS = "\0costs"   # ensure()'s set of stages whose cost estimate was checked, kept in its digest dict
INPUT_MEMO = ".inputs.digests.json"  # in <run>/: sha256 of dataset files read, by size, mtime, ctime, inode



@dataclass
class StageContext:
    """What a stage's ``run`` gets: the config, its temporary output folder, upstream folders."""
    cfg: Config
    stage: str
    out: Path
    device_request: str = "auto"
    threads: int = 0
    extra: dict[str, Any] = field(default_factory=dict)  # the stage may record facts for its manifest
    skips: SkipPolicy = field(default_factory=lambda: SkipPolicy(True))  # data.skip_bad_views
    _device: str | None = None

    def input(self, stage: str) -> Path:
        """Final folder of an upstream stage."""
        return self.cfg.stage_dir(stage)

    @property
    def device(self) -> str:
        if self._device is None:
            self._device = resolve_device(self.device_request)
            configure_threads(self.threads)
        return self._device


def read_manifest(cfg: Config, stage: str) -> dict | None:
    # an unreadable manifest counts as none: the stage is stale and reruns
    m = outputs_manifest(cfg.stage_dir(stage), missing=None, invalid=None)
    return m if isinstance(m, dict) else None


def digest(manifest: dict) -> str:
    """What downstream stages key on: the stage's key and the content of its outputs."""
    outs = {k: v.get("sha256") for k, v in (manifest.get("outputs") or {}).items()}
    return hash_json({"key": manifest.get("key"), "outputs": outs})


def stage_key(cfg: Config, spec: StageSpec, upstream: dict[str, str]) -> tuple[str, dict]:
    check_loaded(cfg, spec.name, spec.methods)   # an outside entry it uses that does not load: refused, named
    code, per_module = code_version(spec)
    parts = {
        "stage": spec.name,
        "sections": {s: to_dict(cfg.section(s)) for s in spec.sections},
        "code": code,
        "upstream": upstream,
    }
    # Import the stage module only when it has an extra_key: importing one that does not (evaluate,
    # report) would pull in pandas and matplotlib just to compute a status.
    extra_key = None if defines(spec.module, "extra_key") is False else getattr(_load(spec), "extra_key", None)
    if extra_key is not None:
        parts["inputs"] = extra_key(cfg)
    if spec.methods:  # a fusion method registered from outside (entry point, test): new or edited reruns the stage

        parts["methods"] = outside_fingerprint()
    if spec.defaults:  # the report lists the keys a run sets apart from the defaults (declarations.py)
        parts["defaults"] = hash_json(to_dict(Config()))
    parts.update(outside_parts(cfg, spec.name))   # classifiers, planners, metrics from outside
    return hash_json(parts), {**parts, "code_modules": per_module}


def _load(spec: StageSpec):
    return importlib.import_module(spec.module)


# ------------------------------------------------------------------------------------------------
# Why is a stage stale?

def _key_reason(old: dict, new: dict) -> str:
    """Which part of the key moved, in words."""
    oldp, newp = old.get("parts") or {}, new
    for s, v in newp.get("sections", {}).items():
        if (oldp.get("sections") or {}).get(s) != v:
            return f"config [{s}] changed"
    for u, v in newp.get("upstream", {}).items():
        if (oldp.get("upstream") or {}).get(u) != v:
            return f"upstream stage '{u}' changed"
    if oldp.get("code") != newp.get("code"):
        om, nm = oldp.get("code_modules") or {}, newp.get("code_modules") or {}
        changed = sorted(m for m in set(om) | set(nm) if om.get(m) != nm.get(m))
        return "code changed" + (f" ({', '.join(changed[:4])}{', ...' if len(changed) > 4 else ''})" if changed else "")
    if oldp.get("inputs") != newp.get("inputs"):
        return "its dataset or weights inputs changed"
    if oldp.get("defaults") != newp.get("defaults"):
        return "a setting's default changed"
    return "cache key changed"


def stale_reason(cfg: Config, name: str, key: str, parts: dict, verify: dict | None = None) -> str | None:
    """None when stage ``name`` is up to date for ``key``; otherwise why not. ``verify``: hash the
    stage's outputs against their recorded sha256 (memo for one run; see ``record_changed``)."""
    m = read_manifest(cfg, name)
    if m is None:
        return "missing (never run here)"
    if m.get("key") != key:
        return _key_reason(m, parts)
    final = cfg.stage_dir(name)
    if "outputs" not in m:
        return "manifest predates content hashes"
    for rel, rec in m["outputs"].items():
        why = record_changed(final / rel, rec, verify)
        if why:
            return f"output {final / rel} {why}"
    memo_path = cfg.run_dir / INPUT_MEMO
    memo = load_memo(memo_path)
    before = dict(memo)
    try:
        for entry, rec in (m.get("inputs") or {}).items():
            path = input_path(cfg, entry)
            why = record_changed(path, rec, memo=memo)
            if why:
                return f"input {path} {why}"
    finally:
        if memo != before:
            save_memo(memo_path, memo)
    return None


# Dataset roots an input record is kept relative to: a moved project (relative roots) or a dataset
# copied elsewhere (its root setting changed) finds its inputs again by content.
INPUT_ROOTS = ("data.bigbird_root", "data.avd_root", "data.coil_root", "data.eth80_root", "data.avd_frames_root")


def portable_inputs(cfg: Config, records: dict[str, dict]) -> dict[str, dict]:
    """``records`` with each path under a configured dataset root written ``<root key>:<relative
    name>`` (e.g. ``data.coil_root:obj1__0.png``); other paths stay absolute."""
    roots = [(k, os.path.abspath(cfg.path(k))) for k in INPUT_ROOTS if cfg.section(k)]
    roots.sort(key=lambda kr: -len(kr[1]))  # the innermost root wins
    out = {}
    for path, rec in records.items():
        for key, root in roots:
            if path.startswith(root + os.sep):
                out[f"{key}:{Path(os.path.relpath(path, root)).as_posix()}"] = rec
                break
        else:
            out[path] = rec
    return out


def input_path(cfg: Config, name: str) -> str:
    """The file an input record names (``portable_inputs``) under the current config."""
    key, sep, rel = name.partition(":")
    if sep and key in INPUT_ROOTS and not os.path.isabs(name):
        return str(cfg.path(key) / rel)
    return name


def plan(cfg: Config, name: str, _memo: dict | None = None) -> dict:
    """Status of a stage without running anything: {state: up to date|stale|missing, why, digest}.
    Outputs are checked as ``ensure`` checks them (every one hashed against its manifest, once per
    call through the shared ``_memo``), so ``viewfuse status`` says stale exactly where the next run
    would rerun: a byte edited with its size and mtime restored included."""
    memo = {} if _memo is None else _memo
    if name in memo:
        return memo[name]
    spec = STAGES[name]
    ups = {u: plan(cfg, u, memo) for u in spec.upstream}
    key, parts = stage_key(cfg, spec, {u: p["digest"] for u, p in ups.items()})
    why = stale_reason(cfg, name, key, parts, verify=memo.setdefault(HASHES, {}))
    bad_up = [u for u, p in ups.items() if p["state"] != "up to date"]
    m = read_manifest(cfg, name)
    if m is None:
        res = {"state": "missing", "why": why}
    elif bad_up:
        res = {"state": "stale", "why": f"upstream stage '{bad_up[0]}' is {ups[bad_up[0]]['state']}"}
    elif why is not None:
        res = {"state": "stale", "why": why}
    else:
        res = {"state": "up to date", "why": None}
    res["key"] = key
    res["digest"] = digest(m) if res["state"] == "up to date" else hash_json({"planned": key})
    memo[name] = res
    return res


# ------------------------------------------------------------------------------------------------
# Running

def ensure(cfg: Config, name: str, *, force: bool = False, device: str = "auto", threads: int = 0,
           _keys: dict[str, str] | None = None, _hashes: dict | None = None) -> str:
    """Bring stage ``name`` up to date (upstream first); return its digest. A stage found up to
    date has had its outputs' sha256 checked against its manifest (each file hashed once per run,
    ``_hashes``), so an output edited with its size and mtime restored is caught before a
    downstream stage uses it: the stage reruns."""
    keys = {} if _keys is None else _keys
    hashes = keys.setdefault(HASHES, {}) if _hashes is None else _hashes
    if name in keys:
        return keys[name]
    check_costs(cfg, name, force=force, checked=keys.setdefault(COSTS, set()))
    spec = STAGES[name]
    up = {u: ensure(cfg, u, device=device, threads=threads, _keys=keys, _hashes=hashes) for u in spec.upstream}
    key, parts = stage_key(cfg, spec, up)
    final = stage_paths(cfg, name).final
    # One run of a stage at a time: a second one waits here, then finds the first one's output.
    with stage_lock(cfg, name):
        recover_swap(cfg, name)
        if not force:
            why = stale_reason(cfg, name, key, parts, verify=hashes)
            if why is None:
                echo(f"[{name}] up to date ({final}); skipped (use --force to rerun)")
                m = read_manifest(cfg, name) or {}
                stage_cache.publish(cfg, name, m, final)   # a run finished before the cache existed
                keys[name] = digest(m)
                return keys[name]
            if not why.startswith("missing"):
                echo(f"[{name}] stale: {why}")
            manifest = stage_cache.adopt(cfg, name, key, input_path)
            if manifest is not None:
                keys[name] = digest(manifest)
                return keys[name]
        manifest = run_stage(cfg, spec, key, parts, device=device, threads=threads)
        stage_cache.publish(cfg, name, manifest, final)
    keys[name] = digest(manifest)
    return keys[name]


def closure(name: str) -> list[str]:
    """``name`` and every stage upstream of it, upstream first."""
    out: list[str] = []

    def walk(n: str) -> None:
        for u in STAGES[n].upstream:
            walk(u)
        if n not in out:
            out.append(n)
    walk(name)
    return out


def check_costs(cfg: Config, name: str, *, force: bool = False, checked: set | None = None) -> None:
    """Before any stage of a command runs: every stage it may run (``name`` and its upstream) is
    estimated (``pipeline.infra.cost``: seconds and bytes from every setting that multiplies its
    work) and one over ``run.max_minutes`` or the memory budget is refused, a config error naming
    the keys, unless it is up to date (then it will not run). Pure formulas: this takes
    milliseconds, so a refusal comes before minutes of upstream work, not after."""

    checked = set() if checked is None else checked
    memo: dict = {}
    for stage in closure(name):
        if stage in checked:
            continue
        checked.add(stage)
        try:
            check(cfg, stage)
        except ValueError:
            if (force and stage == name) or plan(cfg, stage, memo)["state"] != "up to date":
                raise


def run_stage(cfg: Config, spec: StageSpec, key: str, parts: dict, *, device: str, threads: int) -> dict:
    """Run one stage into its temporary folder and swap it in; the caller holds the stage's lock."""

    est = check(cfg, spec.name)  # again, with this process as it is now (an address-space limit)
    if est.seconds > 60:
        echo(f"[{spec.name}] estimate: {describe(est)}")
    mod = _load(spec)
    paths = stage_paths(cfg, spec.name)
    final, tmp = paths.final, paths.tmp
    paths.run_dir.mkdir(parents=True, exist_ok=True)
    stop_leftovers(paths.workers)  # a killed run's workers would still write into its .tmp
    if tmp.exists() or tmp.is_symlink():
        remove_leftover(tmp, required=True)  # left by an interrupted run (we hold the lock)
    tmp.mkdir()
    set_max_megapixels(cfg.data.max_image_megapixels)  # the dataset readers' image size limit
    ctx = StageContext(cfg=cfg, stage=spec.name, out=tmp, device_request=device, threads=threads,
                       skips=SkipPolicy.from_config(cfg))
    echo(f"[{spec.name}] running: {banner(cfg, spec.name, spec.help)}")
    t0, c0 = time.perf_counter(), cpu_seconds()
    try:
        mark_owned(tmp)  # inside: a full disk here too names the folder and removes it
        with recording_inputs() as rec, pid_file(paths.workers), confined_writes(tmp):
            summary = mod.run(ctx)
        # Files in the run folder are upstream outputs, already covered by the upstream digests;
        # leaving them out also keeps a moved artifacts folder valid.
        read = rec.records(exclude=cfg.run_dir)
        inputs = portable_inputs(cfg, read)
        if read:  # their digests, so the next check reads none of them
            memo = load_memo(cfg.run_dir / INPUT_MEMO)
            remember(read, memo)
            save_memo(cfg.run_dir / INPUT_MEMO, memo)
        outputs = folder_records(tmp, skip=(MANIFEST, OWNER))
        stray = undeclared(spec.name, outputs)
        if stray:  # the catalog is the one list of what a stage writes
            raise RuntimeError(f"stage {spec.name!r} wrote output(s) that pipeline/infra/outputs.py does not "
                               f"declare: {', '.join(stray[:5])}")
    except BaseException as e:
        shutil.rmtree(tmp, ignore_errors=True)
        named = naming(e, tmp) if isinstance(e, OSError) else e  # a write outside atomic_path: the folder
        if named is not e:
            raise named from e
        raise
    elapsed = time.perf_counter() - t0
    if ctx.skips.enabled:
        ctx.extra.setdefault("skipped", {}).update(ctx.skips.summary())
    manifest = {
        "stage": spec.name,
        "key": key,
        "parts": parts,
        "seconds": round(elapsed, 3),
        "cpu_seconds": round(cpu_seconds() - c0, 3),
        "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "summary": summary,
        "device": ctx._device,
        "extra": ctx.extra,
        "outputs": outputs,
        "inputs": inputs,
    }
    write_json(tmp / MANIFEST, manifest)
    swap_in(paths)
    echo(f"[{spec.name}] done in {duration(elapsed, 1)}: {summary} -> {final}")
    if ctx.skips.count:
        echo(f"[{spec.name}] {ctx.skips.count} bad entr{'y' if ctx.skips.count == 1 else 'ies'} skipped "
             f"(data.skip_bad_views); see {final / MANIFEST} 'extra.skipped'")
    return manifest


def cpu_seconds() -> float:
    """User + system CPU seconds of this process and its reaped children (worker processes)."""
    import resource

    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def stage_timings(cfg: Config) -> dict[str, float]:
    """Seconds each finished stage took (for the report)."""
    out = {}
    for name in STAGES:
        m = read_manifest(cfg, name)
        if m:
            out[name] = m.get("seconds", float("nan"))
    return out

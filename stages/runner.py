"""Run stages with manifests: skip what is up to date, rerun what is stale, write atomically.

Each stage writes into a temporary sibling folder; only when it finishes is that folder swapped in
and the manifest written, so an interrupted run never leaves output that looks complete.
"""
from __future__ import annotations

import importlib
import json
import logging
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.cache import code_hash, hash_json, replace_dir, write_json
from pipeline.config import Config, to_dict
from stages.registry import STAGES, StageSpec

log = logging.getLogger("viewfuse")

MANIFEST = "manifest.json"


class StageNotImplemented(RuntimeError):
    pass


@dataclass
class StageContext:
    """What a stage's ``run`` gets: the config, its temporary output folder, upstream folders."""
    cfg: Config
    stage: str
    out: Path
    device_request: str = "auto"
    threads: int = 0
    extra: dict[str, Any] = field(default_factory=dict)  # the stage may record facts for its manifest
    _device: str | None = None

    def input(self, stage: str) -> Path:
        """Final folder of an upstream stage."""
        return self.cfg.stage_dir(stage)

    @property
    def device(self) -> str:
        if self._device is None:
            from pipeline.device import configure_threads, resolve_device
            self._device = resolve_device(self.device_request)
            configure_threads(self.threads)
        return self._device


def read_manifest(cfg: Config, stage: str) -> dict | None:
    p = cfg.stage_dir(stage) / MANIFEST
    if not p.is_file():
        return None
    try:
        return json.loads(p.read_text())
    except json.JSONDecodeError:
        return None


def stage_key(cfg: Config, spec: StageSpec, upstream_keys: dict[str, str]) -> tuple[str, dict]:
    parts = {
        "stage": spec.name,
        "sections": {s: to_dict(cfg.section(s)) for s in spec.sections},
        "code": code_hash(spec.code),
        "upstream": upstream_keys,
    }
    mod = importlib.import_module(spec.module) if _module_exists(spec.module) else None
    extra_key = getattr(mod, "extra_key", None)
    if extra_key is not None:
        parts["inputs"] = extra_key(cfg)
    return hash_json(parts), parts


def _module_exists(name: str) -> bool:
    import importlib.util
    return importlib.util.find_spec(name) is not None


def ensure(cfg: Config, name: str, *, force: bool = False, device: str = "auto", threads: int = 0,
           _keys: dict[str, str] | None = None) -> str:
    """Bring stage ``name`` up to date (upstream first); return its key."""
    keys = {} if _keys is None else _keys
    if name in keys:
        return keys[name]
    spec = STAGES[name]
    if not _module_exists(spec.module) or not hasattr(importlib.import_module(spec.module), "run"):
        raise StageNotImplemented(f"stage '{name}' is not implemented yet")
    up = {u: ensure(cfg, u, device=device, threads=threads, _keys=keys) for u in spec.upstream}
    key, parts = stage_key(cfg, spec, up)
    manifest = read_manifest(cfg, name)
    final = cfg.stage_dir(name)
    if not force and manifest is not None and manifest.get("key") == key:
        print(f"[{name}] up to date ({final}); skipped (use --force to rerun)", flush=True)
        keys[name] = key
        return key
    run_stage(cfg, spec, key, parts, device=device, threads=threads)
    keys[name] = key
    return key


def run_stage(cfg: Config, spec: StageSpec, key: str, parts: dict, *, device: str, threads: int) -> dict:
    if not _module_exists(spec.module):
        raise StageNotImplemented(f"stage '{spec.name}' is not implemented yet")
    mod = importlib.import_module(spec.module)
    if not hasattr(mod, "run"):
        raise StageNotImplemented(f"stage '{spec.name}' is not implemented yet")
    final = cfg.stage_dir(spec.name)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = final.with_name(f".{spec.name}.tmp")
    if tmp.exists():
        shutil.rmtree(tmp)  # left by an interrupted run
    tmp.mkdir(parents=True)
    ctx = StageContext(cfg=cfg, stage=spec.name, out=tmp, device_request=device, threads=threads)
    print(f"[{spec.name}] running: {spec.help}", flush=True)
    t0 = time.perf_counter()
    try:
        summary = mod.run(ctx)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    elapsed = time.perf_counter() - t0
    manifest = {
        "stage": spec.name,
        "key": key,
        "parts": parts,
        "seconds": round(elapsed, 3),
        "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "summary": summary,
        "device": ctx._device,
        "extra": ctx.extra,
    }
    write_json(tmp / MANIFEST, manifest)
    replace_dir(tmp, final)
    print(f"[{spec.name}] done in {_fmt(elapsed)}: {summary} -> {final}", flush=True)
    return manifest


def _fmt(s: float) -> str:
    return f"{s:.1f} s" if s < 120 else f"{s / 60:.1f} min"


def stage_timings(cfg: Config) -> dict[str, float]:
    """Seconds each finished stage took (for the report)."""
    out = {}
    for name in STAGES:
        m = read_manifest(cfg, name)
        if m:
            out[name] = m.get("seconds", float("nan"))
    return out

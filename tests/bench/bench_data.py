"""Speed goal of the data stage: the default stand-ins (12 objects x 120 views, two AVD scans) in
under 60 s and 400 MB on this machine.

Prints measured seconds and megabytes and their ratios to the goals (ratio < 1 = goal met), plus
the per-view rendering costs behind them.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

GOAL_S, GOAL_MB = 60.0, 400.0


def _cpu_s() -> float:
    import resource
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def _per_view_ms(fn, items) -> float:
    fn(items[0])  # warm caches (textures, meshes)
    t = time.perf_counter()
    for it in items:
        fn(it)
    return 1000 * (time.perf_counter() - t) / len(items)


def main() -> None:
    import numpy as np

    from loaders.synthetic.avd_writer import plan_scan, render_shot
    from loaders.synthetic.bigbird_writer import encode_jpeg, make_rig, render_view
    from loaders.synthetic.nuisance import RigNuisance, sensor
    from loaders.synthetic.objects import make_instance
    from loaders.synthetic.scene import scan_instances
    from pipeline.infra.config import load_config
    from stages.framework.runner import ensure

    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(ROOT / "configs" / "synthetic.toml", {"run": {"artifacts": tmp}})
        t0, c0 = time.perf_counter(), _cpu_s()
        ensure(cfg, "data", force=True)
        secs, cpu = time.perf_counter() - t0, _cpu_s() - c0
        mb = sum(p.stat().st_size for p in cfg.stage_dir("data").rglob("*") if p.is_file()) / 1e6
    syn = cfg.data.synthetic
    print(f"bench_data: default `viewfuse data` {secs:.1f} s (goal {GOAL_S:.0f} s, ratio {secs / GOAL_S:.2f}); "
          f"{mb:.0f} MB (goal {GOAL_MB:.0f} MB, ratio {mb / GOAL_MB:.2f}); workers={syn.workers}; "
          f"{cpu:.0f} CPU s (load-independent; wall on an idle machine is about CPU s / workers)")

    rig, inst = make_rig(syn.bigbird_width, syn.bigbird_height), make_instance(syn.instances[0], 0)
    bb = _per_view_ms(lambda a: render_view(inst, rig, 1, a), list(range(0, 360, 30)))
    rgb, _ = render_view(inst, rig, 1, 0)
    nz = RigNuisance.from_config(syn)
    sen = _per_view_ms(lambda i: sensor(rgb, nz, 0, np.random.default_rng(i)), list(range(12)))
    jpg = _per_view_ms(lambda _: encode_jpeg(rgb, nz.quality), list(range(12)))
    first = cfg.data.scans[0]
    plan = plan_scan(syn, first, 0, scan_instances(syn.instances, cfg.data.scans, first, syn.instances_per_scan))
    avd = _per_view_ms(lambda s: render_shot(plan, s), list(plan.shots[::37]))
    print(f"bench_data: per view, BigBIRD {syn.bigbird_width}x{syn.bigbird_height} render {bb:.1f} ms + sensor "
          f"{sen:.1f} ms + JPEG {jpg:.1f} ms; AVD {syn.avd_width}x{syn.avd_height} render+noise {avd:.1f} ms")


if __name__ == "__main__":
    main()

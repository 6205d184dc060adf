"""Stage ``data``: render the synthetic stand-ins, or check the real dataset paths.

Synthetic (``data.source = "synthetic"``) writes, under the stage folder,
``bigbird/<object>/...`` (BigBIRD object folders), ``avd/instance_id_map.txt`` and
``avd/<scan>/...`` for every scan of ``data.scans`` (an AVD root), and ``truth.json`` (per scan:
object poses, grid, camera; no reader needs it). Views are rendered by ``data.synthetic.workers`` processes; every view draws its randomness
from (seed, its own name), so the files do not depend on the worker count or order.

Real imagery (``data.source = "real_imagery"``) writes the same folders and ``truth.json`` from
COIL-100 photographs and real AVD scan metadata (``loaders.real_imagery``, docs/real_data.md), or,
with ``data.real_imagery.dataset = "eth80"``, from ETH-80 category folds (``loaders.real_imagery.category``).

Real (``data.source = "real"``) only checks that the configured roots hold what the readers need
and writes ``roots.json``; nothing is copied. ``data_roots(cfg)`` tells later stages where the
BigBIRD and AVD roots are in either case.
"""
from __future__ import annotations

import hashlib
import time
from pathlib import Path

from loaders.errors import BadInputError
from pipeline.infra import footprints
from pipeline.infra.budget import budget, cap_workers
from pipeline.infra.cache import load_memo, memo_record, save_memo, tree_digest, write_json
from pipeline.infra.workers import worker_pool
from pipeline.infra.outputs import name as out_name
from stages.framework.roots import data_roots
from pipeline.infra.progress import bar as progress_bar

CHUNK = 12  # views per worker task: one AVD cluster, a few BigBIRD angles


DIGEST_MEMO = ".data.digests.json"  # in <artifacts>/<run>/: per-file sha256 by size, mtime, ctime, inode


def extra_key(cfg) -> str:
    """Real data: a content fingerprint of the inputs, so edits to them rerun the pipeline and a
    moved or copied dataset (new paths, new mtimes, same bytes) does not. Each scan folder and the
    instance map enter by name and sha256; each BigBIRD object folder by its calibration file's
    sha256 and the names and sizes of its other files (the views, which the features stage reads
    and records by sha256). Only names relative to the roots enter the key; the per-file digests
    are memoised in the run folder (``DIGEST_MEMO``), so a rerun reads only what changed."""
    if cfg.data.source != "real":
        return ""
    bb, avd = data_roots(cfg)
    memo_path = cfg.run_dir / DIGEST_MEMO
    memo, used = load_memo(memo_path), {}
    h = hashlib.sha256()
    for name in cfg.data.scans:
        scan = avd / name
        h.update(f"scan {name}:{tree_digest(scan, memo, into=used) if scan.is_dir() else 'missing'}\n".encode())
    idmap = avd / "instance_id_map.txt"
    h.update(f"map:{memo_record(idmap, memo, used)['sha256'] if idmap.is_file() else 'missing'}\n".encode())
    if bb.is_dir():
        for obj in sorted(bb.iterdir()):
            if (obj / "calibration.h5").is_file():
                views = tree_digest(obj, memo, by_name=lambda rel: rel != "calibration.h5", into=used)
                h.update(f"object {obj.name}:{views}\n".encode())
    else:
        h.update(b"bigbird missing\n")
    if used != memo:
        save_memo(memo_path, used)
    return h.hexdigest()


def run(ctx) -> str:
    cfg = ctx.cfg
    if cfg.data.source == "real":
        return _check_real(ctx)
    if cfg.data.source == "real_imagery":
        return _write_real_imagery(ctx)
    return _write_synthetic(ctx)


def _write_real_imagery(ctx) -> str:
    """COIL-100 photographs on real AVD geometry (loaders/real_imagery/, docs/real_data.md)."""
    from loaders.real_imagery.category import write_real_category
    from loaders.real_imagery.write import write_real_imagery

    cfg = ctx.cfg
    t0 = time.perf_counter()
    writer = write_real_category if cfg.data.real_imagery.dataset == "eth80" else write_real_imagery
    extra, summary = writer(cfg, ctx.out / out_name("data", "bigbird"), ctx.out / out_name("data", "avd"),
                                        ctx.out / out_name("data", "truth"), ctx.skips)
    write_json(ctx.out / out_name("data", "roots"), {"source": "real_imagery", "bigbird_root": "bigbird",
                                                     "avd_root": "avd", "scans": list(cfg.data.scans)})
    ctx.extra.update({**extra, "seconds": round(time.perf_counter() - t0, 2)})
    return f"{summary} in {time.perf_counter() - t0:.0f} s"


# ----------------------------------------------------------------------------------------------
# Real data

def _check_real(ctx) -> str:
    from loaders.bigbird import list_objects

    cfg = ctx.cfg
    bb, avd = data_roots(cfg)
    where = f" (set it in {cfg.source_path}; see README, Real photographs)" if cfg.source_path else ""
    if not bb.is_dir():
        raise BadInputError(bb, f"'data.bigbird_root' is not an existing folder{where}")
    objects = list_objects(bb)
    if not objects:
        raise BadInputError(bb, "'data.bigbird_root' holds no BigBIRD object folder "
                                "(a folder with calibration.h5, e.g. aunt_jemima_original_syrup/)")
    if not avd.is_dir():
        raise BadInputError(avd, f"'data.avd_root' is not an existing folder{where}")
    if not (avd / "instance_id_map.txt").is_file():
        raise BadInputError(avd / "instance_id_map.txt",
                            "missing: the AVD root must hold instance_id_map.txt (downloaded separately)")
    counts = {}
    for name in cfg.data.scans:
        scan = avd / name
        if not scan.is_dir():
            raise BadInputError(scan, f"scan folder {name!r} of 'data.scans' is missing from 'data.avd_root'")
        for part in ("jpg_rgb", "annotations.json", "image_structs.mat"):
            if not (scan / part).exists():
                raise BadInputError(scan / part, f"missing from the scan folder {scan}")
        counts[name] = sum(1 for p in (scan / "jpg_rgb").iterdir() if p.suffix.lower() == ".jpg")
        if counts[name] == 0:
            raise BadInputError(scan / "jpg_rgb", "holds no .jpg image")
    _validate_real(ctx, bb, avd, objects)
    write_json(ctx.out / out_name("data", "roots"), {"source": "real", "bigbird_root": str(bb), "avd_root": str(avd),
                                        "scans": list(cfg.data.scans), "bigbird_objects": objects,
                                        "avd_images": counts})
    ctx.extra.update({"bigbird_objects": len(objects), "avd_images": counts})
    scans = ", ".join(f"{k}: {v} images" for k, v in counts.items())
    return f"real data: {len(objects)} BigBIRD objects in {bb}; {scans} in {avd}"


def _validate_real(ctx, bb: Path, avd: Path, objects: list[str]) -> None:
    """Read what is cheap to read up front, so a malformed file stops the run here and not after
    minutes of scoring: the instance map, annotations.json, image_structs.mat and every box
    (malformed files always raise; bad single entries follow data.skip_bad_views), and each
    object's calibration (folders with views but no calibration.h5 follow the skip policy)."""
    from loaders.avd import AVDScan
    from loaders.bigbird import BigBirdObject, uncalibrated_objects

    cfg = ctx.cfg
    for calib in uncalibrated_objects(bb):
        ctx.skips.handle(BadInputError(calib, "object folder has views but no calibration file; object skipped"),
                         "bigbird", "BigBIRD view")
    for name in objects:
        BigBirdObject(bb / name).check_calibration(cfg.features.bigbird_cameras)
    for name in cfg.data.scans:
        AVDScan(avd, name, skip=ctx.skips.log("avd", "AVD entry"))


# ----------------------------------------------------------------------------------------------
# Synthetic stand-ins

def _work(task: tuple):
    """One worker task (module-level so processes can import it)."""
    kind = task[0]
    if kind == "bigbird-meta":
        from loaders.synthetic.bigbird_writer import make_rig, write_object_metadata
        _, folder, syn, _seed = task
        write_object_metadata(Path(folder), make_rig(syn.bigbird_width, syn.bigbird_height), syn.angle_step_deg)
        return kind, 0, None
    if kind == "bigbird-views":
        from loaders.synthetic.bigbird_writer import make_rig, write_view
        from loaders.synthetic.nuisance import RigNuisance
        from loaders.synthetic.objects import make_instance
        _, folder, syn, seed, name, views = task
        rig = make_rig(syn.bigbird_width, syn.bigbird_height)
        inst = make_instance(name, seed)
        nz = RigNuisance.from_config(syn)
        for c, a in views:
            write_view(Path(folder), inst, rig, c, a, seed=seed, nuisance=nz, write_depth=syn.write_depth)
        return kind, len(views), None
    if kind == "avd-shots":
        from loaders.synthetic.avd_writer import plan_scan, write_shot
        _, folder, syn, scan, seed, instances, indices = task
        plan = plan_scan(syn, scan, seed, instances)
        boxes = {}
        for i in indices:
            shot = plan.shots[i]
            boxes[shot.name], _ = write_shot(Path(folder), plan, shot)
        return kind, len(indices), boxes
    raise ValueError(f"unknown task {kind!r}")  # pragma: no cover


def _init_worker() -> None:
    import cv2
    cv2.setNumThreads(1)  # one process per core already


def _write_synthetic(ctx) -> str:
    from loaders.synthetic.avd_writer import plan_scan, truth, write_scan_metadata
    from loaders.synthetic.bigbird_writer import angles
    from loaders.synthetic.objects import CATEGORY_NAMES, make_instance
    from loaders.synthetic.scene import scan_instances

    cfg = ctx.cfg
    syn, seed = cfg.data.synthetic, cfg.data.seed
    bb_root, avd_root = ctx.out / out_name("data", "bigbird"), ctx.out / out_name("data", "avd")
    t0 = time.perf_counter()
    # Plans validate names, rooms and grids before any work starts.
    placed = {s: scan_instances(syn.instances, cfg.data.scans, s, syn.instances_per_scan) for s in cfg.data.scans}
    plans = {s: plan_scan(syn, s, seed, placed[s]) for s in cfg.data.scans}

    tasks: list[tuple] = []
    views = [(c, a) for c in syn.bigbird_cameras for a in angles(syn.angle_step_deg)]
    # AVD clusters first: a scan's rendering warms its room meshes once per worker.
    for scan, plan in plans.items():
        n_shots = len(plan.shots)
        for k in range(0, n_shots, CHUNK):
            tasks.append(("avd-shots", str(avd_root / scan), syn, scan, seed, placed[scan],
                          list(range(k, min(k + CHUNK, n_shots)))))
    for name in syn.instances:
        folder = str(bb_root / name)
        tasks.append(("bigbird-meta", folder, syn, seed))
        for k in range(0, len(views), CHUNK):
            tasks.append(("bigbird-views", folder, syn, seed, name, views[k:k + CHUNK]))
    n_images = sum(len(p.shots) for p in plans.values())
    total = len(views) * len(syn.instances) + n_images

    boxes: dict[str, list] = {}  # image names carry the scan's prefix: unique across scans
    bar = progress_bar(total=total, desc="data: render views", unit="view")
    workers = cap_workers("data.synthetic.workers", syn.workers, footprints.data_worker(syn), budget(cfg),
                          parent=footprints.data_worker(syn))
    if workers > 1:
        with worker_pool(workers, initializer=_init_worker) as pool:
            for kind, n, res in pool.map(_work, tasks):
                if kind == "avd-shots":
                    boxes.update(res)
                bar.update(n)
    else:
        for task in tasks:
            kind, n, res = _work(task)
            if kind == "avd-shots":
                boxes.update(res)
            bar.update(n)
    bar.close()
    faces = {}
    for name in syn.instances:
        inst = make_instance(name, seed)
        faces[name] = {"height_m": inst.height,
                       "faces": {r: {"texture": key, "family": CATEGORY_NAMES[fam]}
                                 for r, (key, fam) in inst.spec.paint.items()}}
    scans = {}
    for scan, plan in plans.items():
        write_scan_metadata(avd_root, plan, {s.name: boxes[s.name] for s in plan.shots})
        scans[scan] = truth(plan)
        for name in scans[scan]["instances"]:
            scans[scan]["instances"][name].update(faces[name])
    # Top level: the first scan's truth (the single-scan layout readers of older runs know), then
    # every scan under "scans" and every object's paint under "objects".
    sidecar = {**scans[cfg.data.scans[0]], "seed": seed, "scans": scans, "objects": faces,
               "bigbird": {"cameras": list(syn.bigbird_cameras), "angles": angles(syn.angle_step_deg),
                           "image_size": [syn.bigbird_width, syn.bigbird_height]}}
    write_json(ctx.out / out_name("data", "truth"), sidecar)
    write_json(ctx.out / out_name("data", "roots"), {"source": "synthetic", "bigbird_root": "bigbird", "avd_root": "avd",
                                        "scans": list(cfg.data.scans), "bigbird_objects": sorted(syn.instances)})
    mb = _folder_bytes(ctx.out) / 1e6
    n_boxes = sum(len(b) for b in boxes.values())
    interp = sum(t["interpolated"] for t in scans.values())
    ctx.extra.update({"bigbird_views": len(views) * len(syn.instances), "avd_images": n_images,
                      "avd_interpolated": interp, "avd_boxes": n_boxes, "megabytes": round(mb, 1),
                      "scans": {s: sorted(placed[s]) for s in plans},
                      "workers": workers, "seconds": round(time.perf_counter() - t0, 2)})
    per_scan = ", ".join(f"{s}: {len(p.shots)} images, {len(placed[s])} instances" for s, p in plans.items())
    return (f"synthetic: {len(syn.instances)} BigBIRD objects x {len(views)} views; {per_scan} "
            f"({interp} interpolated, {n_boxes} boxes); {mb:.0f} MB in {time.perf_counter() - t0:.0f} s")


def _folder_bytes(root: Path) -> int:
    return sum(p.stat().st_size for p in root.rglob("*") if p.is_file())

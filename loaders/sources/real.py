"""Built-in source ``real``: the real BigBIRD and AVD roots, read in place by the later stages. The
data stage only checks that the configured roots hold what the readers need (reading what is cheap
to read, so a malformed file stops the run here) and writes ``roots.json``; nothing is copied."""
from __future__ import annotations

from pathlib import Path

from loaders.errors import BadInputError
from pipeline.infra.cache import load_memo, memo_record, save_memo, sha256_stream, tree_digest, write_json
from pipeline.infra.datasets import AVD_BOXES_PER_SCAN, DatasetSource, Work, register_dataset
from pipeline.infra.outputs import name as out_name

DIGEST_MEMO = ".data.digests.json"  # in <artifacts>/<run>/: per-file sha256 by size, mtime, ctime, inode


@register_dataset
class Real(DatasetSource):
    key = "real"
    doc = "real BigBIRD + AVD roots, read in place (data.bigbird_root, data.avd_root)"
    writes = False
    label = "real data (BigBIRD + AVD)"

    def check(self, cfg, need) -> None:
        need(bool(cfg.data.bigbird_root), "'data.bigbird_root' must be set when data.source = 'real'")
        need(bool(cfg.data.avd_root), "'data.avd_root' must be set when data.source = 'real'")

    def input_key(self, cfg) -> str:
        return input_key(cfg)

    def work(self, cfg) -> Work:
        # BigBIRD: 120 turntable angles a camera; the objects are the root's unless features names them
        objects = cfg.features.bigbird_objects
        views = len(objects) * len(cfg.features.bigbird_cameras) * 120 if objects else None
        # every box of a modelled instance up to features.max_difficulty: at most all of a typical scan's
        crops = len(cfg.data.scans) * AVD_BOXES_PER_SCAN[cfg.features.max_difficulty]
        return Work(views, crops, ("features.bigbird_objects", "features.bigbird_cameras"),
                    ("data.scans", "features.max_difficulty"), views_per_class=120)

    def write(self, ctx) -> str:
        return check_roots(ctx)


def roots(cfg) -> tuple[Path, Path]:
    return cfg.path("data.bigbird_root"), cfg.path("data.avd_root")


def input_key(cfg) -> str:
    """Real data: a content fingerprint of the inputs, so edits to them rerun the pipeline and a
    moved or copied dataset (new paths, new mtimes, same bytes) does not. Each scan folder and the
    instance map enter by name and sha256; each BigBIRD object folder by its calibration file's
    sha256 and the names and sizes of its other files (the views, which the features stage reads
    and records by sha256). Only names relative to the roots enter the key; the per-file digests
    are memoised in the run folder (``DIGEST_MEMO``), so a rerun reads only what changed."""
    bb, avd = roots(cfg)
    memo_path = cfg.run_dir / DIGEST_MEMO
    memo, used = load_memo(memo_path), {}
    h = sha256_stream()
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



def check_roots(ctx) -> str:
    from loaders.bigbird import list_objects  # heavy: cv2

    cfg = ctx.cfg
    bb, avd = roots(cfg)
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
    from loaders.avd import AVDScan  # heavy: scipy
    from loaders.bigbird import BigBirdObject, uncalibrated_objects  # heavy: cv2

    cfg = ctx.cfg
    for calib in uncalibrated_objects(bb):
        ctx.skips.handle(BadInputError(calib, "object folder has views but no calibration file; object skipped"),
                         "bigbird", "BigBIRD view")
    for name in objects:
        BigBirdObject(bb / name).check_calibration(cfg.features.bigbird_cameras)
    for name in cfg.data.scans:
        AVDScan(avd, name, skip=ctx.skips.log("avd", "AVD entry"))



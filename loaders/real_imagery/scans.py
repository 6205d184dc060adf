"""The one scan writer of every turntable source (COIL-100, ETH-80, a source of your own): real AVD
scans' geometry with turntable photographs placed at their located instances, written in the AVD
format the other stages read (docs/real_data.md).

A source gives, per scan, where its targets stand (``Placed``: the located real instance, the
seeded yaw, the target's photographs by turntable angle and its own truth fields) and how a frame
is drawn (``Frames``); ``write_scans`` writes, per scan, a frame per view that gets one
(``frame_views``: per grid point the view facing the instance best, or every box) showing the
photograph at the angle nearest the real bearing (refused beyond ``max_view_error_deg``,
counted), the object scaled uniformly into the real box (``frame_fit``, which records the angle
shown as ``view``) and pasted by its mask, the farthest object of a frame first (its distance from
the real camera), so that only a nearer object covers it, the real move graph with
those boxes as the only ones, the real ``image_structs.mat``, a shared black placeholder for every
other image (``write_scan_files``), and returns the truth record of every scan; ``summaries``
gives the view-error and box-fit distributions over all scans.
"""
from __future__ import annotations

import json
import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from loaders.avd import AVDScan
from loaders.errors import BadInputError
from loaders.files import plain_name
from loaders.real_imagery.frames import fit_in_box, object_bearing_deg, view_error_deg
from loaders.real_imagery.pairing import box_rows, located_xy
from loaders.synthetic.bigbird_writer import encode_jpeg
from pipeline.infra.cache import confined_dir, copy_file, link_file, write_bytes, write_json
from pipeline.infra.workers import can_fork, forked_pool, inherited
from pipeline.scene.rays import facing_error
from pipeline.infra.budget import budget, cap_workers
from pipeline.infra.footprints import PROCESS

log = logging.getLogger("viewfuse.loaders")


@dataclass
class Placed:
    """One target placed at a located real instance of a scan."""
    instance: str            # the real AVD instance
    xy: np.ndarray           # its located position, metres
    yaw_deg: float           # the target's seeded yaw
    label: int               # the target's id in the written instance map
    photos: dict             # turntable angle -> photograph tuple (rgb, mask, ...)
    record: dict             # the truth record's fields of the source (position, residual, what it is)


@dataclass(frozen=True)
class Frames:
    """How a source draws its frames: ``nearest(bearing, photos)`` the angle shown; ``item(scan,
    image, placed, photo, box)`` what one framed box contributes; ``render(scan, image, items,
    (width, height))`` the frame; the truth record's names of the angles used and of the largest view error."""
    nearest: Callable[[float, dict], Any]
    item: Callable[[str, str, Placed, tuple, tuple], Any]
    render: Callable[[str, str, list, tuple[int, int]], np.ndarray]
    jpeg_quality: int
    used_key: str = "heldout_views_used"
    max_key: str = "view_error_deg_max"


@dataclass
class Located:
    """A scan read and its instances located from their real rays (``pairing.located_xy``)."""
    scan: AVDScan
    rows: Any
    loc: dict
    refused: list


def locate(avd_root: Path, scan: str, max_difficulty: int, max_ray_residual_m: float, skips) -> Located:
    """The real metadata copy (no ``jpg_rgb/``) reads as 1920x1080 images; a scan with its frames
    (e.g. the synthetic source's) at their own size."""
    frames = (Path(avd_root) / scan / "jpg_rgb").is_dir()
    s = AVDScan(avd_root, scan, skip=skips.log("avd", "AVD entry"), frames=frames)
    K = s.intrinsics()
    rows = box_rows(s, max_difficulty)
    loc, refused = located_xy(rows, float(K[0, 0]), float(K[0, 2]), max_ray_residual_m, scan)
    return Located(s, rows, loc, refused)


def write_scans(avd_root: Path, avd_out: Path, scans: dict[str, tuple[Located, list[Placed]]], frames: Frames,
                mode: str, max_view_error_deg: float, workers: int = 1) -> tuple[dict, dict]:
    """Every scan of ``scans`` = {scan: (located, its placements in instance order)}: (truth per
    scan, counts per scan). ``workers`` > 1: the scans are written by that many forked processes, a
    scan each (every frame draws its noise from its own stream, so the files do not depend on it)."""
    placeholders: dict[tuple[int, int], Path] = {}   # one black frame per image size, linked for every unframed image
    for located, _ in scans.values():
        size = located.scan.image_size
        if size not in placeholders:
            placeholders[size] = avd_out / f".placeholder-{size[0]}x{size[1]}.jpg"
            write_bytes(placeholders[size], encode_jpeg(np.zeros((size[1], size[0], 3), np.uint8), 50))
    args = (avd_root, avd_out, frames, mode, max_view_error_deg, placeholders)
    if workers > 1 and len(scans) > 1 and can_fork():
        done = _write_parallel(scans, args, workers)
    else:
        done = {scan: _write_scan(scans[scan], *args) for scan in scans}
    for p in placeholders.values():
        p.unlink()
    return {s: done[s][0] for s in scans}, {s: done[s][1] for s in scans}


def _write_named(scan: str):
    # No cv2.setNumThreads here: in a forked child it tears down the pool inherited without its
    # threads and waits on them for ever. The parent set one thread before forking.
    return _write_scan(inherited("scan_rows")[scan], *inherited("scan_args"))


def _write_parallel(scans: dict, args: tuple, workers: int) -> dict:
    import cv2

    # One OpenCV thread while the writers run (one process per core already): set here, where the
    # pool's threads exist, so the forked children run OpenCV serially and never touch its pool.
    cv_threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        # each writer inherits the scans (photographs, located rows) and the frame drawer (closures)
        # instead of receiving them pickled
        with forked_pool(min(workers, len(scans)), {"scan_rows": scans, "scan_args": args}) as pool:
            # the scans with the most boxes first: the last ones to finish are short
            order = sorted(scans, key=lambda s: -len(scans[s][0].rows))
            futures = {s: pool.submit(_write_named, s) for s in order}
            return {s: futures[s].result() for s in order}
    finally:
        cv2.setNumThreads(cv_threads)


def writer_count(cfg, key: str, requested: int) -> int:
    """``requested`` scan writers (the config's ``key``), capped by the cores and the memory budget:
    each a forked process that draws one full frame at a time (~10 frame-sized buffers)."""
    import psutil

    rss = float(psutil.Process().memory_info().rss)
    return cap_workers(key, requested, PROCESS + 10 * 3 * 1920 * 1080, budget(cfg), parent=rss)


def _write_scan(job: tuple[Located, list[Placed]], avd_root, avd_out, frames: Frames, mode: str,
                max_view_error_deg: float, placeholders: dict):
    located, placed = job
    s, rows = located.scan, located.rows
    placeholder = placeholders[s.image_size]
    scan = s.scan
    grid = s.grid_points()
    items: dict[str, list] = {}
    boxes: dict[str, list] = {}
    record = {}
    for p in placed:
        d = frame_views(rows[rows["instance"] == p.instance], p.xy, grid, mode)
        bear = object_bearing_deg(d[["cam_x", "cam_y"]].to_numpy(float), p.xy, p.yaw_deg)
        used, errs, fits = [], [], []
        for r, b in zip(d.itertuples(index=False), bear):
            a = frames.nearest(float(b), p.photos)
            err = float(view_error_deg(b, a))
            errs.append(err)
            if err > max_view_error_deg:  # no frame: the photograph would not show this viewpoint
                continue
            photo = p.photos[a]
            box, fit = frame_fit(r.image, (int(r.box_x0), int(r.box_y0), int(r.box_x1), int(r.box_y1)), photo[1])
            fit["view"] = a
            depth = float(np.hypot(float(r.cam_x) - p.xy[0], float(r.cam_y) - p.xy[1]))
            items.setdefault(r.image, []).append((depth, frames.item(scan, r.image, p, photo, box)))
            boxes.setdefault(r.image, []).append([*box, p.label, int(r.difficulty)])
            used.append(a)
            fits.append(fit)
        name = p.record["name"]
        record[name] = {**{k: v for k, v in p.record.items() if k != "name"}, "frames": len(used), frames.used_key: sorted(set(used)),
                        "frames_refused_view_error": len(errs) - len(used),
                        frames.max_key: round(max(errs), 3) if errs else None, "frame_fit": fits, "_errors": errs}
    folder = avd_out / scan
    jpg = confined_dir(folder / "jpg_rgb")
    for name in sorted(items):
        # the farthest object first: a nearer one covers it (with its own silhouette) where the real boxes overlap
        drawn = [it for _, it in sorted(items[name], key=lambda di: -di[0])]
        write_bytes(jpg / name, encode_jpeg(frames.render(scan, name, drawn, s.image_size), frames.jpeg_quality))
    write_scan_files(avd_root, folder, scan, boxes, placeholder, sorted(record))
    unpaired = sorted(set(located.loc) - {p.instance for p in placed})
    info = {"instances": record, "refused": located.refused, "unpaired": unpaired}
    return info, {"paired": len(placed), "refused": len(located.refused), "unpaired": len(unpaired),
                  "frames": len(items)}


def summaries(truth: dict, max_view_error_deg: float, source: str, shown: str,
              bound_key: str = "data.real_imagery.max_view_error_deg") -> tuple[dict, dict]:
    """(view error, box fit) over every scan's frames (the per-frame errors popped off the
    records); a warning naming ``source`` and what a frame shows when the bound refused frames."""
    errors = [e for sc in truth.values() for r in sc["instances"].values() for e in r.pop("_errors")]
    view_error = view_error_summary(errors, max_view_error_deg)
    if view_error["refused"]:
        log.warning("%s: %d of %d frames refused: the nearest %s is more than %s = %g degrees from the "
                    "bearing", source, view_error["refused"], view_error["frames"], shown, bound_key,
                    max_view_error_deg)
    box_fit = fit_summary([f for sc in truth.values() for r in sc["instances"].values() for f in r["frame_fit"]])
    return view_error, box_fit


def frame_views(rows, xy, grid: dict[str, int], mode: str):
    """The rows (one instance) that get a frame: per grid point the view facing it best (the only
    views ``select_tracks`` can pick), or every row for ``mode = 'all'``."""
    d = rows.drop_duplicates("image").reset_index(drop=True)
    if mode == "all" or d.empty:
        return d
    err = facing_error(d[["cam_x", "cam_y"]].to_numpy(float), d["heading"].to_numpy(float), xy)
    gid = np.array([grid.get(n, -1 - i) for i, n in enumerate(d["image"])])
    best: dict[int, int] = {}
    for i, g in enumerate(gid):
        if g not in best or err[i] < err[best[g]]:
            best[int(g)] = i
    return d.iloc[sorted(best.values())].reset_index(drop=True)


def view_error_summary(errors, bound: float) -> dict:
    """The viewpoint error of every candidate frame (degrees between its bearing and the held-out view
    nearest it): quantiles, the share beyond 2.5 and 5 degrees, and how many the bound refused."""
    e = np.asarray(errors, float)
    if e.size == 0:
        return {"frames": 0, "refused": 0, "bound": bound}
    q = np.percentile(e, [50, 90, 99])
    return {"frames": int(e.size), "refused": int((e > bound).sum()), "bound": float(bound),
            "median": round(float(q[0]), 3), "p90": round(float(q[1]), 3), "p99": round(float(q[2]), 3),
            "max": round(float(e.max()), 3), "share_over_2_5": round(float((e > 2.5).mean()), 4),
            "share_over_5": round(float((e > 5.0).mean()), 4)}


def fit_summary(fits) -> dict:
    """The distribution over written frames of the uniform scale (frame pixels per photograph pixel)
    and of the box's fill (the object box's share of the real box's area: 1 where the object's
    aspect ratio is the box's, lower the more they differ)."""
    if not fits:
        return {"frames": 0}
    scale = np.array([f["scale"] for f in fits], float)
    fill = np.array([f["fill"] for f in fits], float)

    def q(v):
        p = np.percentile(v, [5, 50, 95])
        return {"min": round(float(v.min()), 4), "p5": round(float(p[0]), 4), "median": round(float(p[1]), 4),
                "p95": round(float(p[2]), 4), "max": round(float(v.max()), 4)}
    return {"frames": int(len(fits)), "scale": q(scale), "fill": q(fill),
            "share_fill_below_0_5": round(float((fill < 0.5).mean()), 4)}


def frame_fit(image: str, box, mask) -> tuple[tuple[int, int, int, int], dict]:
    """The object box written for a real ``box`` (``fit_in_box``) and the frame's record."""
    obj_box, scale, fill = fit_in_box(mask, box)
    return obj_box, {"image": image, "real_box": [int(v) for v in box], "scale": round(scale, 4),
                     "fill": round(fill, 4)}


def write_scan_files(avd_root: Path, folder: Path, scan: str, boxes: dict, placeholder: Path, present) -> None:
    """The scan folder beside its frames (``jpg_rgb/`` already holds one per key of ``boxes``): the
    real move graph with ``boxes`` as the only boxes, the placeholder linked for every other
    image, the real ``image_structs.mat`` and ``present_instance_names.txt`` (``present``)."""
    jpg = folder / "jpg_rgb"
    ann_path = avd_root / scan / "annotations.json"
    real = json.loads(ann_path.read_text())
    ann = {}
    for name, entry in real.items():
        try:  # the reader has counted (or refused) a key that is not a plain file name
            plain_name(name, ann_path, "image key")
        except BadInputError:
            continue
        ann[name] = {**{k: v for k, v in entry.items() if k != "bounding_boxes"},
                     "bounding_boxes": boxes.get(name, [])}
        if not (jpg / name).exists():
            link_file(placeholder, jpg / name)
    write_json(folder / "annotations.json", ann)
    copy_file(avd_root / scan / "image_structs.mat", folder / "image_structs.mat")
    if (avd_root / scan / "cameras.txt").is_file():   # a scan with its own intrinsics (the real copy has none)
        copy_file(avd_root / scan / "cameras.txt", folder / "cameras.txt")
    write_bytes(folder / "present_instance_names.txt", "".join(f"{n}\n" for n in present).encode())

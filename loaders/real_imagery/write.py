"""The data stage's writer for ``data.source = "real_imagery"`` (docs/real_data.md).

Writes, under the stage folder, in the formats the other stages already read:

- ``bigbird/coil_obj<k>/``: the COIL training views of every object of ``data.real_imagery.objects``
  (``loaders.real_imagery.training``);
- ``avd/instance_id_map.txt`` (``coil_obj<k> k``) and ``avd/<scan>/`` per scan: the real
  ``image_structs.mat`` (copied: real camera poses), an ``annotations.json`` with the real move graph
  of every image and, as boxes, the real boxes of the paired instances in the views that get a frame
  (relabelled with the COIL object's id), ``present_instance_names.txt`` (the paired objects) and
  ``jpg_rgb/``: a frame per such view (``loaders.real_imagery.frames``); every other image of the
  scan is one shared black placeholder frame of the real size (hard links: the reader needs a file
  per image, nothing reads its pixels);
- ``truth.json``: per scan, each paired object's located position, its seeded yaw, the real
  instance it stands for and the ray residual, and per frame its real box, scale and fill
  (``frame_fit``: the object is scaled uniformly into the real box and the written box is the
  object's own, ``frames.fit_in_box``); the refused and unpaired instances; the distributions of
  the viewpoint error (``view_error_deg``) and of the fit (``box_fit``).

An object with fewer readable training views than ``models.min_views`` is left out here
(``training.modellable``, the check every writer of this source calls).
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from loaders.avd import KINECT_SIZE, AVDScan
from loaders.coil import CoilFolder, object_name
from loaders.errors import BadInputError
from loaders.files import plain_name
from loaders.real_imagery.frames import (
    fit_in_box,
    heldout_angles,
    nearest_view,
    object_bearing_deg,
    render_frame,
    view_error_deg,
)
from loaders.real_imagery.pairing import box_rows, located_xy, pair_scan
from loaders.real_imagery.training import modellable, write_training_object
from loaders.synthetic.bigbird_writer import encode_jpeg
from pipeline.scene.rays import facing_error
from pipeline.infra.cache import confined_dir, copy_file, link_file, write_bytes, write_json
from pipeline.infra import seeds

log = logging.getLogger("viewfuse.loaders")


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


def _heldout(coil: CoilFolder, k: int, step: int, skips) -> dict[int, tuple]:
    out = {}
    for a in heldout_angles([v.angle for v in coil.views(k)], step):
        try:
            out[a] = coil.read(coil.view(k, a))
        except BadInputError as err:
            skips.handle(err, "coil", "COIL view")
    return out


def write_real_imagery(cfg, bb_out: Path, avd_out: Path, truth_path: Path, skips) -> tuple[dict, str]:
    """Write both sides (BigBIRD root ``bb_out``, AVD root ``avd_out``, the sidecar ``truth_path``);
    returns (manifest extras, summary)."""
    ri = cfg.data.real_imagery
    coil_root, avd_root = cfg.path("data.coil_root"), cfg.path("data.avd_root")
    coil = CoilFolder(coil_root, skip=skips.log("coil", "COIL view"))
    trained, missing = {}, {}
    for k in ri.objects:
        if k not in coil.objects:
            raise BadInputError(coil_root / f"obj{k}__0.png",
                                f"COIL object {k} of 'data.real_imagery.objects' has no view in the folder")
        info = write_training_object(bb_out, coil, k, ri.train_step_deg, ri.train_jpeg_quality)
        if not modellable(len(info["angles"]), cfg.models.min_views, object_name(k), coil_root / f"obj{k}__0.png",
                          f"data.real_imagery.train_step_deg = {ri.train_step_deg}", skips, "coil", "COIL view"):
            continue
        trained[k] = info["angles"]
        if info["missing"]:
            missing[object_name(k)] = info["missing"]
    heldout = {k: _heldout(coil, k, ri.train_step_deg, skips) for k in trained}
    heldout = {k: v for k, v in heldout.items() if v}
    if len(heldout) < 2:
        raise BadInputError(coil_root, "fewer than two COIL objects with readable training and held-out views")
    avd_out.mkdir(parents=True, exist_ok=True)
    write_bytes(avd_out / "instance_id_map.txt",
                "".join(f"{object_name(k)} {k}\n" for k in sorted(heldout)).encode())
    placeholder = avd_out / ".placeholder.jpg"
    write_bytes(placeholder, encode_jpeg(np.zeros((KINECT_SIZE[1], KINECT_SIZE[0], 3), np.uint8), 50))
    truth, counts = {}, {}
    for scan in cfg.data.scans:
        truth[scan], counts[scan] = _write_scan(cfg, avd_root, avd_out, scan, heldout, placeholder, skips)
    placeholder.unlink()
    errors = [e for s in truth.values() for r in s["instances"].values() for e in r.pop("_errors")]
    view_error = view_error_summary(errors, ri.max_view_error_deg)
    box_fit = fit_summary([f for s in truth.values() for r in s["instances"].values() for f in r["frame_fit"]])
    if view_error["refused"]:
        log.warning("real imagery: %d of %d frames refused: the nearest held-out view is more than "
                    "data.real_imagery.max_view_error_deg = %g degrees from the bearing", view_error["refused"],
                    view_error["frames"], ri.max_view_error_deg)
    write_json(truth_path, {"source": "real_imagery", "pairing": "synthetic: seeded "
                                    "(data.real_imagery.pairing_seed, yaws_seed)", "scans": truth,
                                    "view_error_deg": view_error, "box_fit": box_fit,
                                    "train_step_deg": ri.train_step_deg,
                                    "objects": {object_name(k): {"training_angles": trained[k],
                                                                 "heldout_angles": sorted(heldout[k])}
                                                for k in sorted(heldout)}})
    extra = {"coil_objects": len(heldout), "training_views": sum(len(trained[k]) for k in heldout),
             "missing_training_views": missing, "scans": counts, "view_error_deg": view_error,
             "box_fit": box_fit}
    per_scan = "; ".join(f"{s}: {c['paired']} paired instances, {c['frames']} frames" for s, c in counts.items())
    return extra, (f"real imagery: {len(heldout)} COIL objects x {ri.train_step_deg}-degree training views "
                   f"({extra['training_views']} views); {per_scan} (pairing synthetic, seeded)")


def _write_scan(cfg, avd_root: Path, avd_out: Path, scan: str, heldout: dict, placeholder: Path, skips):
    ri = cfg.data.real_imagery
    s = AVDScan(avd_root, scan, skip=skips.log("avd", "AVD entry"), frames=False)
    K = s.intrinsics()
    rows = box_rows(s, ri.max_difficulty)
    loc, refused = located_xy(rows, float(K[0, 0]), float(K[0, 2]), ri.max_ray_residual_m, scan)
    pairs, left = pair_scan(scan, loc, sorted(heldout), ri.pairing_seed, ri.yaws_seed)
    grid = s.grid_points()
    items: dict[str, list] = {}
    boxes: dict[str, list] = {}
    record = {}
    for p in pairs:
        d = frame_views(rows[rows["instance"] == p.instance], np.asarray(p.xy), grid, ri.frames)
        bear = object_bearing_deg(d[["cam_x", "cam_y"]].to_numpy(float), np.asarray(p.xy), p.yaw_deg)
        views = heldout[p.object_id]
        used, errs, fits = [], [], []
        for r, b in zip(d.itertuples(index=False), bear):
            a = nearest_view(float(b), views)
            err = float(view_error_deg(b, a))
            errs.append(err)
            if err > ri.max_view_error_deg:  # no frame: the view shown would not be this viewpoint's
                continue
            rgb, mask = views[a]
            box, fit = frame_fit(r.image, (int(r.box_x0), int(r.box_y0), int(r.box_x1), int(r.box_y1)), mask)
            items.setdefault(r.image, []).append((rgb, mask, box))
            boxes.setdefault(r.image, []).append([*box, p.object_id, int(r.difficulty)])
            used.append(a)
            fits.append(fit)
        record[object_name(p.object_id)] = {"position": list(p.xy), "yaw_deg": p.yaw_deg, "avd_instance": p.instance,
                                            "coil_object": p.object_id, "residual_m": round(p.residual_m, 4),
                                            "frames": len(used), "heldout_views_used": sorted(set(used)),
                                            "frames_refused_view_error": len(errs) - len(used),
                                            "view_error_deg_max": round(max(errs), 3) if errs else None,
                                            "frame_fit": fits, "_errors": errs}
    folder = avd_out / scan
    jpg = confined_dir(folder / "jpg_rgb")
    for name in sorted(items):
        rng = seeds.stream(cfg.data.seed, f"{scan}/{name}")
        frame = render_frame(KINECT_SIZE, items[name], ri.noise_std, ri.blur_sigma_px, rng)
        write_bytes(jpg / name, encode_jpeg(frame, ri.jpeg_quality))
    write_scan_files(avd_root, folder, scan, boxes, placeholder,
                     [object_name(p.object_id) for p in sorted(pairs, key=lambda p: p.object_id)])
    info = {"instances": record, "refused": refused, "unpaired": left}
    return info, {"paired": len(pairs), "refused": len(refused), "unpaired": len(left), "frames": len(items)}


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
    write_bytes(folder / "present_instance_names.txt", "".join(f"{n}\n" for n in present).encode())

"""The data stage's writer for ``data.real_imagery.dataset = "eth80"``: category-level classes with
every test object unseen (docs/real_data.md, "Category-level classes").

Folds by instance: fold ``f`` holds out instance ``f`` of every category. Its classes are
``<category>__f<f>`` (``fold_class``), each fitted on the views of the category's OTHER instances
(several photographs per azimuth: the intra-class variation enters the fit; ``class_members``
tells the models stage which object folders make each class). The held-out instance ``f`` of
category ``c`` is the scene object of class ``c__f<f>``: its photographs appear only in AVD frames,
and the evaluate stage, with ``evaluate.candidate_folds``, draws its candidates (and so its
component choice) from fold ``f``'s classes only.

Training folders (BigBIRD format, camera NP1), one per instance, ``eth80_<category><n>`` (each
photograph is scored once however many folds use it): the view at azimuth ``a`` is
``NP1_<360 n + round(a)>.jpg`` (the "angle" is a view code, unique within any class: its remainder
mod 360 is the name's azimuth, its quotient the instance) with a pose file of that code that puts
NP1 at exactly ``a`` (22.5-degree multiples, not the rounded name), its mask (map >= 128) and the
photograph as it is, on the dataset's blue cloth.

Scenes, as for COIL (``write``): the real AVD boxes, instances located from their real rays, then
a seeded pairing (``pairing_seed``) that spreads the held-out instances over the located instances
of all scans so that each is placed before any is placed twice (distinct within a scan), a seeded
yaw per placement, and per frame the held-out instance's photograph whose azimuth is nearest the
real bearing: up to 11.25 degrees away with 16 azimuths. ``background``: the object, cut out by
its map, over black or over real clutter (``clutter``).
"""
from __future__ import annotations

import zlib
from pathlib import Path

import cv2
import numpy as np

from loaders.avd import KINECT_SIZE, AVDScan
from loaders.errors import BadInputError
from loaders.eth80 import Eth80Folder, class_object
from loaders.pbm import encode_pbm
from loaders.real_imagery.clutter import read_backgrounds, render_category_frame
from loaders.real_imagery.frames import object_bearing_deg
from loaders.real_imagery.pairing import box_rows, located_xy
from loaders.real_imagery.write import frame_views, write_scan_files
from loaders.synthetic.bigbird_writer import calibration_datasets, encode_jpeg, make_rig, write_h5
from pipeline.scene.folds import fold_class
from pipeline.infra.cache import write_bytes, write_json


def view_code(instance: int, azimuth: float) -> int:
    """The BigBIRD angle field of one training view: 360 x instance + the name's azimuth."""
    return 360 * int(instance) + int(round(azimuth)) % 360


def rng_for(seed: int, *parts: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), *(zlib.crc32(p.encode()) for p in parts)])


def class_members(cfg) -> dict[str, list[str]] | None:
    """{class: its training object folders} of an ETH-80 category run (None otherwise): class
    ``c__f<f>`` is every configured instance of ``c`` but ``f``."""
    ri = cfg.data.real_imagery
    if cfg.data.source != "real_imagery" or ri.dataset != "eth80":
        return None
    return {fold_class(c, f): [class_object(c, i) for i in ri.instances if i != f]
            for c in ri.categories for f in ri.instances}


def write_training_class(root: Path, cls: str, members: dict[int, dict], quality: int) -> int:
    """One object folder from ``members`` = {instance: {azimuth: (rgb, mask, map)}}; views of
    another size than the first are resized to it. Returns the number of views written."""
    folder = Path(root) / cls
    first = next(iter(next(iter(members.values())).values()))[0]
    H, W = first.shape[:2]
    rig = make_rig(W, H)
    write_h5(folder / "calibration.h5", calibration_datasets(rig))
    write_h5(folder / "poses" / "turntable.h5", {"center": np.zeros(3), "normal": np.array([0.0, 0.0, 1.0])})
    n = 0
    for inst in sorted(members):
        for az, (rgb, mask, _) in sorted(members[inst].items()):
            if rgb.shape[:2] != (H, W):
                rgb = cv2.resize(rgb, (W, H), interpolation=cv2.INTER_AREA)
                mask = cv2.resize(mask.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST).astype(bool)
            code = view_code(inst, az)
            write_h5(folder / "poses" / f"NP5_{code}_pose.h5",
                     {"H_table_from_reference_camera": rig.reference_pose(az), "board_frame_offset": np.zeros(3)})
            write_bytes(folder / f"NP1_{code}.jpg", encode_jpeg(rgb, quality))
            write_bytes(folder / "masks" / f"NP1_{code}_mask.pbm", encode_pbm(mask))
            n += 1
    return n


def fold_members(views: dict[tuple[str, int], dict], category: str, fold: int) -> dict[int, dict]:
    """The training instances of ``category`` in fold ``fold``: every other instance with views."""
    return {i: v for (c, i), v in views.items() if c == category and i != fold and v}


def assign_targets(located: dict[str, list[str]], targets: list[str], seed: int) -> dict[str, dict[str, str]]:
    """{scan: {AVD instance: target}}: scans in the given order; each takes the targets placed
    least often so far (ties by a seeded draw), distinct within the scan, matched to its located
    instances by a seeded permutation; a scan with more located instances than targets leaves
    the extra ones (drawn) unpaired."""
    tie = rng_for(seed, "eth80-ties").permutation(len(targets))
    order = {t: int(tie[k]) for k, t in enumerate(sorted(targets))}
    used = {t: 0 for t in targets}
    out: dict[str, dict[str, str]] = {}
    for scan, names in located.items():
        names = sorted(names)
        k = min(len(names), len(targets))
        rng = rng_for(seed, "eth80-pairing", scan)
        if len(names) > k:
            names = sorted(rng.choice(names, size=k, replace=False).tolist())
        chosen = sorted(targets, key=lambda t: (used[t], order[t]))[:k]
        perm = rng.permutation(k)
        out[scan] = {names[j]: chosen[int(perm[j])] for j in range(k)}
        for t in chosen:
            used[t] += 1
    return out


def nearest_azimuth(bearing_deg: float, azimuths) -> float:
    """The azimuth of ``azimuths`` circularly nearest ``bearing_deg`` (ties: the smaller)."""
    a = np.asarray(sorted(azimuths), float)
    d = np.abs((a - float(bearing_deg) + 180.0) % 360.0 - 180.0)
    return float(a[int(np.argmin(d))])


def write_real_category(cfg, bb_out: Path, avd_out: Path, truth_path: Path, skips) -> tuple[dict, str]:
    """Write both sides (BigBIRD root ``bb_out``, AVD root ``avd_out``, the sidecar ``truth_path``);
    returns (manifest extras, summary)."""
    ri = cfg.data.real_imagery
    root, avd_root = cfg.path("data.eth80_root"), cfg.path("data.avd_root")
    eth = Eth80Folder(root, skip=skips.log("eth80", "ETH-80 view"))
    views: dict[tuple[str, int], dict] = {}
    for c in ri.categories:
        for i in ri.instances:
            if (c, i) not in eth.objects:
                raise BadInputError(root / f"{c}{i}", f"ETH-80 {c}{i} (data.real_imagery.categories x instances) "
                                                      f"has no view in the folder")
            views[(c, i)] = eth.read_instance(c, i, set(ri.elevations))
            if not views[(c, i)]:
                skips.handle(BadInputError(root / f"{c}{i}", "no readable view on data.real_imagery.elevations; "
                                                             "instance left out"), "eth80", "ETH-80 view")
    n_views = 0
    for (c, i), v in sorted(views.items()):
        if v:
            n_views += write_training_class(bb_out, class_object(c, i), {i: v}, ri.train_jpeg_quality)
    trained = {}
    for f in ri.instances:
        for c in ri.categories:
            members = fold_members(views, c, f)
            if not members:
                raise BadInputError(root / f"{c}{f}", f"fold {f}: category {c!r} has no training instance with views")
            trained[fold_class(c, f)] = sorted(members)
    targets = {fold_class(c, i): (c, i) for (c, i), v in views.items() if v}
    ids = {t: k + 1 for k, t in enumerate(sorted(targets))}
    avd_out.mkdir(parents=True, exist_ok=True)
    write_bytes(avd_out / "instance_id_map.txt", "".join(f"{t} {ids[t]}\n" for t in sorted(ids)).encode())
    backgrounds = read_backgrounds(cfg.path("data.avd_frames_root"), skips) if ri.background == "avd_frames" else None
    scans, located = {}, {}
    for scan in cfg.data.scans:
        s = AVDScan(avd_root, scan, skip=skips.log("avd", "AVD entry"), frames=False)
        K = s.intrinsics()
        rows = box_rows(s, ri.max_difficulty)
        loc, refused = located_xy(rows, float(K[0, 0]), float(K[0, 2]), ri.max_ray_residual_m, scan)
        scans[scan] = (s, rows, loc, refused)
        located[scan] = sorted(loc)
    placed = assign_targets(located, sorted(targets), ri.pairing_seed)
    placeholder = avd_out / ".placeholder.jpg"
    write_bytes(placeholder, encode_jpeg(np.zeros((KINECT_SIZE[1], KINECT_SIZE[0], 3), np.uint8), 50))
    truth, counts = {}, {}
    for scan, (s, rows, loc, refused) in scans.items():
        truth[scan], counts[scan] = _write_scan(cfg, avd_root, avd_out, s, rows, loc, refused, placed[scan],
                                                targets, views, ids, backgrounds, placeholder)
    placeholder.unlink()
    times = {t: sum(1 for p in placed.values() if t in p.values()) for t in targets}
    write_json(truth_path, {
        "source": "real_imagery", "dataset": "eth80",
        "pairing": "synthetic: seeded (data.real_imagery.pairing_seed, yaws_seed)",
        "folds": {str(f): {"held_out_instance": f, "classes": {fold_class(c, f): trained[fold_class(c, f)]
                                                              for c in ri.categories}} for f in ri.instances},
        "targets": {t: {"category": c, "instance": i, "placements": times[t]} for t, (c, i) in sorted(targets.items())},
        "scans": truth, "background": ri.background})
    unplaced = sorted(t for t, n in times.items() if n == 0)
    extra = {"classes": len(trained), "targets": len(targets), "training_views": n_views,
             "unplaced_targets": unplaced, "scans": counts}
    per_scan = "; ".join(f"{k}: {c['paired']} placed, {c['frames']} frames" for k, c in counts.items())
    return extra, (f"real imagery (ETH-80 categories): {len(ri.categories)} categories x {len(ri.instances)} folds "
                   f"= {len(trained)} classes ({n_views} training views); {len(targets) - len(unplaced)} of "
                   f"{len(targets)} held-out instances placed; {per_scan} (pairing synthetic, seeded)")


def _write_scan(cfg, avd_root, avd_out, s, rows, loc, refused, placed, targets, views, ids, backgrounds, placeholder):
    ri = cfg.data.real_imagery
    scan = s.scan
    grid = s.grid_points()
    items: dict[str, list] = {}
    boxes: dict[str, list] = {}
    record = {}
    for inst in sorted(placed):
        t = placed[inst]
        xy = loc[inst][0]
        yaw = round(float(rng_for(ri.yaws_seed, "yaw", scan, inst).uniform(0.0, 360.0)), 6)
        d = frame_views(rows[rows["instance"] == inst], xy, grid, ri.frames)
        bear = object_bearing_deg(d[["cam_x", "cam_y"]].to_numpy(float), xy, yaw)
        photos = views[targets[t]]
        used, gaps = [], []
        for r, b in zip(d.itertuples(index=False), bear):
            a = nearest_azimuth(float(b), photos)
            rgb, mask, alpha = photos[a]
            box = (int(r.box_x0), int(r.box_y0), int(r.box_x1), int(r.box_y1))
            bg_rng = rng_for(ri.background_seed, "background", scan, r.image, inst)
            items.setdefault(r.image, []).append(((rgb, mask, alpha, box), bg_rng))
            boxes.setdefault(r.image, []).append([*box, ids[t], int(r.difficulty)])
            used.append(a)
            gaps.append(abs((a - float(b) + 180.0) % 360.0 - 180.0))
        c, i = targets[t]
        record[t] = {"position": [float(xy[0]), float(xy[1])], "yaw_deg": yaw, "avd_instance": inst,
                     "category": c, "eth80_instance": i, "residual_m": round(float(loc[inst][1]), 4),
                     "frames": len(d), "azimuths_used": sorted(set(used)),
                     "max_view_offset_deg": round(max(gaps), 3) if gaps else None}
    folder = avd_out / scan
    jpg = folder / "jpg_rgb"
    jpg.mkdir(parents=True, exist_ok=True)
    for name in sorted(items):
        rng = np.random.default_rng([cfg.data.seed, zlib.crc32(f"{scan}/{name}".encode())])
        its = [it for it, _ in items[name]]
        frame = render_category_frame(KINECT_SIZE, its, backgrounds, ri.noise_std, ri.blur_sigma_px, rng,
                                      [g for _, g in items[name]])
        write_bytes(jpg / name, encode_jpeg(frame, ri.jpeg_quality))
    write_scan_files(avd_root, folder, scan, boxes, placeholder, sorted(record))
    unpaired = sorted(set(loc) - set(placed))
    info = {"instances": record, "refused": refused, "unpaired": unpaired}
    return info, {"paired": len(placed), "refused": len(refused), "unpaired": len(unpaired), "frames": len(items)}

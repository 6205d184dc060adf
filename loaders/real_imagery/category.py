"""The data stage's writer for ``data.real_imagery.dataset = "eth80"``: ETH-80 classes by folds of
instances, at category or instance level (docs/real_data.md, "Category-level classes" and "The
instance-category contrast").

Folds by instance: fold ``f`` holds out instance ``f`` of every category; the scene object of
class ``<category>__f<f>`` (``fold_class``) is instance ``f``, and the evaluate stage, with
``evaluate.candidate_folds``, draws its candidates (and so its component choice) from fold ``f``'s
classes only. What a class is fitted on is ``class_level``: 'category' = the category's OTHER
instances (several photographs per azimuth: the intra-class variation enters the fit, every
scored photograph is of an unseen object); 'instance' = instance ``f`` itself, as COIL's classes.
``view_split`` decides which azimuths train and which the frames show ('alternate': even and odd
multiples of 22.5 degrees), the same for both levels: the frames, pairing, yaws and backgrounds
do not depend on ``class_level``, so two runs differing only in it are the controlled contrast.
``fold_classes`` records the classes (``truth.json`` ``classes``; the models stage reads it).

An instance with fewer training views than ``models.min_views`` (``training.modellable``, the
check the COIL writer calls too) or no frame azimuth is left out here, named under the skip
policy; a fold's class of a left-out instance's category is then left out at both levels.

Training folders (BigBIRD format, camera NP1), one per usable instance, ``eth80_<category><n>``
(each photograph is scored once however many folds use it): the view at azimuth ``a`` is
``NP1_<360 n + round(a)>.jpg`` (the "angle" is a view code, unique within any class: its remainder
mod 360 is the name's azimuth, its quotient the instance) with a pose file of that code that puts
NP1 at exactly ``a`` (22.5-degree multiples, not the rounded name), its mask (map >= 128) and the
photograph on the training background (``clutter.on_surround``: by default the frames' kind, the
photograph extended so that no training crop runs off it, ``data.real_imagery.train_pad``).

Scenes, as for COIL (``write``): the real AVD boxes, instances located from their real rays, then
a seeded pairing (``pairing_seed``) that spreads the held-out instances over the located instances
of all scans so that each is placed before any is placed twice (distinct within a scan), a seeded
yaw per placement, and per frame the held-out instance's photograph at the frame azimuth nearest
the real bearing; a frame whose nearest azimuth is more than ``max_view_error_deg`` away is not
written and is counted (``truth.json`` ``view_error_deg``). The object is scaled uniformly into
its box (``frames.fit_in_box``), cut out by its map over black or real clutter (``clutter``).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from loaders.errors import BadInputError
from loaders.eth80 import STEP_DEG, Eth80Folder, class_object
from loaders.pbm import encode_pbm
from loaders.real_imagery.clutter import on_surround, read_backgrounds
from loaders.real_imagery.scans import Placed, locate, summaries, write_scans, writer_count
from loaders.real_imagery.training import modellable
from loaders.real_imagery.write import plain_frames, training_crop
from loaders.synthetic.bigbird_writer import calibration_datasets, encode_jpeg, make_rig, write_h5
from pipeline.scene.folds import category_of, fold_class, fold_of
from pipeline.infra.cache import write_bytes, write_json
from pipeline.infra import seeds




def view_code(instance: int, azimuth: float) -> int:
    """The BigBIRD angle field of one training view: 360 x instance + the name's azimuth."""
    return 360 * int(instance) + int(round(azimuth)) % 360


def split_azimuths(azimuths, view_split: str) -> tuple[list[float], list[float]]:
    """(training azimuths, frame azimuths) of one instance: every azimuth both ('none'), or the
    even multiples of 22.5 degrees for training and the odd ones for the frames ('alternate')."""
    az = sorted(float(a) for a in azimuths)
    if view_split == "none":
        return az, az
    even = [a for a in az if round(a / STEP_DEG) % 2 == 0]
    return even, [a for a in az if round(a / STEP_DEG) % 2 == 1]


def fold_classes(kept, categories, instances, class_level: str) -> dict[str, list[str]]:
    """{class ``c__f<f>``: its training object folders} over the usable instances ``kept`` (a set
    of (category, instance)): a fold's class of category c exists only where instance f of c is
    usable (so both levels have the same classes and candidates); 'category' = the other usable
    instances of c, 'instance' = instance f itself."""
    out = {}
    for f in instances:
        for c in categories:
            if (c, f) not in kept:
                continue
            members = [f] if class_level == "instance" else [i for i in instances if i != f and (c, i) in kept]
            out[fold_class(c, f)] = [class_object(c, i) for i in members]
    return out


def class_members(cfg, truth: dict | None = None) -> dict[str, list[str]] | None:
    """{class: its training object folders} of an ETH-80 category run (None otherwise): the data
    stage's record (``truth["classes"]``: instances it left out are in no class), or, without
    one, what the config gives when every instance is usable (``fold_classes``)."""
    ri = cfg.data.real_imagery
    if cfg.data.source != "real_imagery" or ri.dataset != "eth80":
        return None
    if truth and isinstance(truth.get("classes"), dict):
        return {str(k): [str(o) for o in v] for k, v in truth["classes"].items()}
    kept = {(c, i) for c in ri.categories for i in ri.instances}
    return fold_classes(kept, ri.categories, ri.instances, ri.class_level)


def contrast_members(cfg, truth: dict | None = None) -> dict[str, list[str]] | None:
    """{class: [its instance's folder]} of the contrast's instance arm (``data.real_imagery.contrast``;
    None otherwise): the same classes as the run's category arm (``class_members``), each fitted on
    instance f of its category alone. Every usable instance has its own training folder (written
    once, whatever the level), so the features are shared and only the class models' training set
    differs between the arms."""
    if not getattr(cfg.data.real_imagery, "contrast", False):
        return None
    members = class_members(cfg, truth)
    if members is None:
        return None
    return {cls: [class_object(category_of(cls), int(fold_of(cls)))] for cls in members}


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


def assign_targets(located: dict[str, list[str]], targets: list[str], seed: int) -> dict[str, dict[str, str]]:
    """{scan: {AVD instance: target}}: scans in the given order; each takes the targets placed
    least often so far (ties by a seeded draw), distinct within the scan, matched to its located
    instances by a seeded permutation; a scan with more located instances than targets leaves
    the extra ones (drawn) unpaired."""
    tie = seeds.stream(seed, "eth80-ties").permutation(len(targets))
    order = {t: int(tie[k]) for k, t in enumerate(sorted(targets))}
    used = {t: 0 for t in targets}
    out: dict[str, dict[str, str]] = {}
    for scan, names in located.items():
        names = sorted(names)
        k = min(len(names), len(targets))
        rng = seeds.stream(seed, "eth80-pairing", scan)
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


def read_views(cfg, skips) -> tuple[dict, dict]:
    """The usable instances' photographs, split: ({(c, i): {azimuth: (rgb, mask, map)}} of the
    training azimuths, the same of the frame azimuths). An instance with fewer training views than
    models.min_views (``training.modellable``) or no frame azimuth is left out, named under the
    skip policy; none usable is an error naming the folder."""
    ri = cfg.data.real_imagery
    root = cfg.path("data.eth80_root")
    eth = Eth80Folder(root, skip=skips.log("eth80", "ETH-80 view"))
    train, test = {}, {}
    setting = f"data.real_imagery.view_split = {ri.view_split!r}, elevations = {list(ri.elevations)}"
    for c in ri.categories:
        for i in ri.instances:
            if (c, i) not in eth.objects:
                raise BadInputError(root / f"{c}{i}", f"ETH-80 {c}{i} (data.real_imagery.categories x instances) "
                                                      f"has no view in the folder")
            views = eth.read_instance(c, i, set(ri.elevations))
            tr, te = split_azimuths(views, ri.view_split)
            if not modellable(len(tr), cfg.models.min_views, class_object(c, i), root / f"{c}{i}", setting, skips,
                              "eth80", "ETH-80 view", unit="instance"):
                continue
            if not te:
                skips.handle(BadInputError(root / f"{c}{i}", f"{class_object(c, i)}: no readable view at a frame "
                                                             f"azimuth ({setting}); instance left out"),
                             "eth80", "ETH-80 view")
                continue
            train[(c, i)] = {a: views[a] for a in tr}
            test[(c, i)] = {a: views[a] for a in te}
    if not train:
        raise BadInputError(root, "no ETH-80 instance of data.real_imagery.categories x instances can be modelled "
                                  "(the skips above say why)")
    return train, test


def write_real_category(cfg, bb_out: Path, avd_out: Path, truth_path: Path, skips) -> tuple[dict, str]:
    """Write both sides (BigBIRD root ``bb_out``, AVD root ``avd_out``, the sidecar ``truth_path``);
    returns (manifest extras, summary)."""
    ri = cfg.data.real_imagery
    root, avd_root = cfg.path("data.eth80_root"), cfg.path("data.avd_root")
    train, test = read_views(cfg, skips)
    train_bg = ri.background if ri.train_background == "same" else ri.train_background
    need_bg = "avd_frames" in (ri.background, train_bg)
    backgrounds = read_backgrounds(cfg.path("data.avd_frames_root"), skips) if need_bg else None
    n_views, borders, crop = 0, {}, training_crop(cfg)
    for (c, i), v in sorted(train.items()):
        on_bg, borders[class_object(c, i)] = on_surround(v, train_bg, backgrounds, lambda a: seeds.stream(
            ri.background_seed, "train-background", c, str(i), f"{a:g}"), crop)
        n_views += write_training_class(bb_out, class_object(c, i), {i: on_bg}, ri.train_jpeg_quality)
    classes = fold_classes(set(train), ri.categories, ri.instances, ri.class_level)
    for cls, members in classes.items():
        if not members:
            raise BadInputError(root / cls.split("__")[0], f"class {cls}: category has no other usable instance "
                                                            f"(data.real_imagery.instances)")
    targets = {fold_class(c, i): (c, i) for (c, i) in test}
    ids = {t: k + 1 for k, t in enumerate(sorted(targets))}
    avd_out.mkdir(parents=True, exist_ok=True)
    write_bytes(avd_out / "instance_id_map.txt", "".join(f"{t} {ids[t]}\n" for t in sorted(ids)).encode())
    backgrounds = backgrounds if ri.background == "avd_frames" else None
    scans = {scan: locate(avd_root, scan, ri.max_difficulty, ri.max_ray_residual_m, skips) for scan in cfg.data.scans}
    placed = assign_targets({scan: sorted(loc.loc) for scan, loc in scans.items()}, sorted(targets), ri.pairing_seed)
    frames = plain_frames(cfg.data.seed, ri, backgrounds, nearest=nearest_azimuth, used_key="azimuths_used",
                          max_key="max_view_offset_deg")
    truth, counts = write_scans(avd_root, avd_out, {scan: (loc, _place(ri, loc, placed[scan], targets, test, ids))
                                                    for scan, loc in scans.items()}, frames, ri.frames,
                                ri.max_view_error_deg, writer_count(cfg, "data.real_imagery.workers", ri.workers))
    view_error, box_fit = summaries(truth, ri.max_view_error_deg, "real imagery (ETH-80)", "frame azimuth")
    times = {t: sum(1 for p in placed.values() if t in p.values()) for t in targets}
    left_out = sorted(class_object(c, i) for c in ri.categories for i in ri.instances if (c, i) not in train)
    background = {"frames": ri.background, "training": train_bg, "train_pad": ri.train_pad}
    write_json(truth_path, {
        "source": "real_imagery", "dataset": "eth80",
        "pairing": "synthetic: seeded (data.real_imagery.pairing_seed, yaws_seed)",
        "class_level": ri.class_level, "view_split": ri.view_split, "classes": classes,
        "folds": {str(f): {"held_out_instance": f,
                           "classes": {k: v for k, v in classes.items() if fold_of(k) == str(f)}}
                  for f in ri.instances},
        "targets": {t: {"category": c, "instance": i, "placements": times[t],
                        "training_azimuths": sorted(train[(c, i)]), "frame_azimuths": sorted(test[(c, i)])}
                    for t, (c, i) in sorted(targets.items())},
        "left_out_instances": left_out, "scans": truth, "background": background, "training_border_px": borders,
        "view_error_deg": view_error, "box_fit": box_fit})
    unplaced = sorted(t for t, n in times.items() if n == 0)
    extra = {"classes": len(classes), "targets": len(targets), "training_views": n_views,
             "unplaced_targets": unplaced, "left_out_instances": left_out, "scans": counts,
             "view_error_deg": view_error, "box_fit": box_fit, "background": background,
             "class_level": ri.class_level, "view_split": ri.view_split}
    per_scan = "; ".join(f"{k}: {c['paired']} placed, {c['frames']} frames" for k, c in counts.items())
    return extra, (f"real imagery (ETH-80, {ri.class_level} level): {len(classes)} classes over "
                   f"{len(ri.instances)} folds ({n_views} training views, background {train_bg}; frames on "
                   f"{ri.background}); {len(targets) - len(unplaced)} of {len(targets)} held-out instances placed"
                   f"{f', {len(left_out)} left out' if left_out else ''}; {per_scan}; "
                   f"{view_error['refused']} frames beyond the view-error bound (pairing synthetic, seeded)")


def _place(ri, located, placed: dict[str, str], targets: dict, photos: dict, ids: dict) -> list[Placed]:
    """The scan's placements (``assign_targets``'s {AVD instance: target}) in instance order, each
    with its seeded yaw."""
    out = []
    for inst in sorted(placed):
        t = placed[inst]
        xy = located.loc[inst][0]
        yaw = round(float(seeds.stream(ri.yaws_seed, "yaw", located.scan.scan, inst).uniform(0.0, 360.0)), 6)
        c, i = targets[t]
        out.append(Placed(inst, xy, yaw, ids[t], photos[targets[t]],
                          {"name": t, "position": [float(xy[0]), float(xy[1])], "yaw_deg": yaw, "avd_instance": inst,
                           "category": c, "eth80_instance": i, "residual_m": round(float(located.loc[inst][1]), 4)}))
    return out

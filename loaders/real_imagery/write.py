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

from pathlib import Path

import numpy as np

from loaders.coil import CoilFolder, object_name
from loaders.errors import BadInputError
from loaders.real_imagery.clutter import on_surround, read_backgrounds, render_category_frame
from loaders.real_imagery.frames import heldout_angles, nearest_view
from loaders.real_imagery.pairing import pair_scan
from loaders.real_imagery.scans import Frames, Located, Placed, locate, summaries, write_scans, writer_count
from loaders.real_imagery.training import modellable, write_training_object
from pipeline.infra.cache import write_bytes, write_json
from pipeline.infra import seeds



def _heldout(coil: CoilFolder, k: int, step: int, skips) -> dict[int, tuple]:
    out = {}
    for a in heldout_angles([v.angle for v in coil.views(k)], step):
        try:
            rgb, mask = coil.read(coil.view(k, a))
            out[a] = (rgb, mask, mask.astype(np.float32))   # the mask is the alpha it is cut out by
        except BadInputError as err:
            skips.handle(err, "coil", "COIL view")
    return out


def write_real_imagery(cfg, bb_out: Path, avd_out: Path, truth_path: Path, skips) -> tuple[dict, str]:
    """Write both sides (BigBIRD root ``bb_out``, AVD root ``avd_out``, the sidecar ``truth_path``);
    returns (manifest extras, summary)."""
    ri = cfg.data.real_imagery
    coil_root, avd_root = cfg.path("data.coil_root"), cfg.path("data.avd_root")
    coil = CoilFolder(coil_root, skip=skips.log("coil", "COIL view"))
    train_bg = ri.background if ri.train_background == "same" else ri.train_background
    need_bg = "avd_frames" in (ri.background, train_bg)
    backgrounds = read_backgrounds(cfg.path("data.avd_frames_root"), skips) if need_bg else None
    crop = training_crop(cfg)

    def prepare(k: int, photos: dict):
        return on_surround(photos, train_bg, backgrounds, lambda a: seeds.stream(
            ri.background_seed, "train-background", object_name(k), str(a)), crop)

    trained, missing, borders = {}, {}, {}
    for k in ri.objects:
        if k not in coil.objects:
            raise BadInputError(coil_root / f"obj{k}__0.png",
                                f"COIL object {k} of 'data.real_imagery.objects' has no view in the folder")
        info = write_training_object(bb_out, coil, k, ri.train_step_deg, ri.train_jpeg_quality, prepare)
        borders[object_name(k)] = info["border_px"]
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
    located = {scan: locate(avd_root, scan, ri.max_difficulty, ri.max_ray_residual_m, skips) for scan in cfg.data.scans}
    placed = {scan: (loc, place_pairs(scan, loc, heldout, ri, lambda k: {"name": object_name(k), "coil_object": k}))
              for scan, loc in located.items()}
    frames = plain_frames(cfg.data.seed, ri, backgrounds if ri.background == "avd_frames" else None)
    truth, counts = write_scans(avd_root, avd_out, placed, frames, ri.frames, ri.max_view_error_deg,
                                writer_count(cfg, "data.real_imagery.workers", ri.workers))
    view_error, box_fit = summaries(truth, ri.max_view_error_deg, "real imagery", "held-out view")
    background = {"frames": ri.background, "training": train_bg, "train_pad": ri.train_pad}
    write_json(truth_path, {"source": "real_imagery", "pairing": "synthetic: seeded "
                                    "(data.real_imagery.pairing_seed, yaws_seed)", "scans": truth,
                                    "view_error_deg": view_error, "box_fit": box_fit,
                                    "train_step_deg": ri.train_step_deg, "background": background,
                                    "training_border_px": borders,
                                    "objects": {object_name(k): {"training_angles": trained[k],
                                                                 "heldout_angles": sorted(heldout[k])}
                                                for k in sorted(heldout)}})
    extra = {"coil_objects": len(heldout), "training_views": sum(len(trained[k]) for k in heldout),
             "missing_training_views": missing, "scans": counts, "view_error_deg": view_error,
             "box_fit": box_fit, "background": background}
    per_scan = "; ".join(f"{s}: {c['paired']} paired instances, {c['frames']} frames" for s, c in counts.items())
    return extra, (f"real imagery: {len(heldout)} COIL objects x {ri.train_step_deg}-degree training views "
                   f"({extra['training_views']} views, on {train_bg}; frames on {ri.background}); {per_scan} "
                   "(pairing synthetic, seeded)")


def place_pairs(scan: str, located: Located, heldout: dict[int, dict], s, own) -> list[Placed]:
    """The seeded pairing of the scan's located instances with the objects (ids) of ``heldout``
    (``pairing.pair_scan``, ``s``: the section with ``pairing_seed`` and ``yaws_seed``); ``own(id)``:
    the object's truth fields (its ``name`` in the instance map among them)."""
    pairs, _ = pair_scan(scan, located.loc, sorted(heldout), s.pairing_seed, s.yaws_seed)
    return [Placed(p.instance, np.asarray(p.xy), p.yaw_deg, p.object_id, heldout[p.object_id],
                   {**own(p.object_id), "position": list(p.xy), "yaw_deg": p.yaw_deg, "avd_instance": p.instance,
                    "residual_m": round(p.residual_m, 4)})
            for p in pairs]


def training_crop(cfg) -> tuple[float, bool] | None:
    """(margin, square) of the features stage's crops, which the training photographs are
    extended to hold (``data.real_imagery.train_pad = 'surround'``), or None ('none')."""
    return (cfg.features.margin, cfg.features.square) if cfg.data.real_imagery.train_pad == "surround" else None


def plain_frames(data_seed: int, s, backgrounds=None, **keys) -> Frames:
    """Frames of turntable photographs (COIL-100, ETH-80, a source of your own): the view
    ``keys['nearest']`` picks (default: the held-out view nearest the bearing), each object cut out
    by its alpha (its mask where the photograph has no map) over black, or, with ``backgrounds``
    (real AVD frames), over a clutter region drawn per box from ``s.background_seed`` (0 where the
    section has none); the sensor model of ``s`` (noise, blur, JPEG quality)."""
    bg_seed = int(getattr(s, "background_seed", 0))

    def item(scan: str, image: str, p, photo: tuple, box):
        rgb, mask, alpha = photo if len(photo) > 2 else (*photo, None)
        return (rgb, mask, alpha, box), seeds.stream(bg_seed, "background", scan, image, p.instance)

    def render(scan: str, name: str, items: list, size: tuple[int, int]) -> np.ndarray:
        rng = seeds.stream(data_seed, f"{scan}/{name}")
        return render_category_frame(size, [it for it, _ in items], backgrounds, s.noise_std, s.blur_sigma_px, rng,
                                     [g for _, g in items])
    return Frames(**{"nearest": nearest_view, **keys}, item=item, render=render, jpeg_quality=s.jpeg_quality)

"""Stage ``features``: crop every needed view and score it -> ``bigbird.parquet``, ``avd.parquet``.

BigBIRD (GP training) views get the deterministic pass and ``features.bigbird_samples`` MC-dropout
samples (their mean is the GP training target, ``models.targets``); AVD (test) boxes
up to ``features.max_difficulty`` get the deterministic pass and ``features.n_samples`` MC-dropout
samples. One crop policy for both (``pipeline.scoring.crops``). Bad views follow ``data.skip_bad_views``:
counted, logged and listed in the manifest, or a named error.

Executors (``run.executor``): images are read and cropped here, in batches of
``features.batch_size``; each batch is scored by one task. ``local`` scores them in this process;
``ray`` puts the classifier weights in Ray's object store once and scores the batches on the
workers, one GPU per task where the cluster has GPUs (unless ``run.device = "cpu"``). Dropout
masks depend only on (features.seed, crop key), so both give the same Parquet files on the same
kind of device.

Cache key: [features] + the data and classifier stages' keys (images, dropout p, input size,
normalisation, training) + the classifier card hash (the weights themselves), via ``extra_key``.
"""
from __future__ import annotations

import logging
import time
from contextlib import contextmanager
from typing import Iterator

import numpy as np

from pipeline.infra.progress import bar as progress_bar
from pipeline.infra.outputs import read
from loaders.errors import BadInputError
from pipeline.method.geometry import project_unit_circle
from pipeline.scoring.features import CropJob
from pipeline.scoring.features import forget_scorers
from pipeline.infra.device import available_cores, free_of, runnable_others
from pipeline.scoring.classifiers import card_arch, classifier
from pipeline.scoring.features import ScoringModel, register_scorer
from pipeline.infra.cost import Counts, check
from pipeline.infra.executor import executor_for
from pipeline.scoring.features import build_table, metadata, score_jobs, viewpoint_spread, write_table
from pipeline.infra.outputs import name as out_name
from stages.framework.roots import data_roots
from pipeline.infra.threads import INTERVAL_S, torch_following

log = logging.getLogger("viewfuse.features")


def extra_key(cfg) -> str:
    """The weights' identity: the classifier card hash. The runner brings the classifier stage up
    to date before it computes this stage's key, so the card read here is the one used."""

    card = read(cfg.stage_dir("classifier"), "classifier", "card", missing=None, invalid=None)
    return "classifier=" + str(card.get("hash")) if isinstance(card, dict) else "classifier=missing"


def bigbird_objects(cfg, root, skips) -> list:
    """The object folders to score. A folder with views but no calibration.h5 is one skip naming
    the file (an error with skips off); a calibration that lacks a key the views need is one error
    naming the file and key (every view of the object would fail the same way)."""
    from loaders.bigbird import BigBirdObject, list_objects, uncalibrated_objects  # heavy: cv2

    f = cfg.features
    present = list_objects(root)
    if f.bigbird_objects:
        missing = [o for o in f.bigbird_objects if o not in present]
        if missing:
            raise ValueError(f"'features.bigbird_objects' names {missing[0]!r}, which is not a BigBIRD object "
                             f"folder (with calibration.h5) in {root}")
        names = list(f.bigbird_objects)
    else:
        names = present
        for calib in uncalibrated_objects(root):
            skips.handle(BadInputError(calib, "object folder has views but no calibration file; object skipped"),
                         "bigbird", "BigBIRD view")
    objs = [BigBirdObject(root / n) for n in names]
    for o in objs:
        o.check_calibration(f.bigbird_cameras)  # a bad calibration is one error, before any scoring
    return objs


def bigbird_jobs(cfg, root, skips, bar) -> Iterator:
    f = cfg.features
    skip = skips.log("bigbird", "BigBIRD view")
    objs = bigbird_objects(cfg, root, skips)
    bar.reset(total=sum(len(o.views(f.bigbird_cameras)) for o in objs))
    for o in objs:
        seen = 0
        for rec in o.iter_views(f.bigbird_cameras, skip=skip):
            seen += 1
            bar.update(1)
            x, y, z = (float(v) for v in rec.pose[:3, 3])
            ux, uy = project_unit_circle(np.array([x, y]), what=f"camera of {rec.view.image_path}")
            v = rec.view
            yield CropJob(key=f"bigbird/{v.object}/NP{v.camera}_{v.angle}", image=rec.image, box=rec.box,
                          columns={"object": v.object, "camera": v.camera, "angle_deg": v.angle,
                                   "image": v.image_path.relative_to(root).as_posix(),
                                   "box_x0": rec.box[0], "box_y0": rec.box[1], "box_x1": rec.box[2],
                                   "box_y1": rec.box[3], "cam_x": x, "cam_y": y, "cam_z": z,
                                   "u_x": float(ux), "u_y": float(uy)})
        # Views skipped by the reader still count on the bar.
        bar.update(len(o.views(f.bigbird_cameras)) - seen)


def avd_boxes(cfg, scan) -> list:
    """[(image, its boxes to score)] of one scan: the boxes of the scored instances up to
    ``features.max_difficulty``, images without one left out."""
    f = cfg.features
    if f.avd_instances:
        unknown = [n for n in f.avd_instances if n not in scan.instance_ids]
        if unknown:
            raise ValueError(f"'features.avd_instances' names {unknown[0]!r}, which is not in "
                             f"{scan.root / 'instance_id_map.txt'}")
        names = list(f.avd_instances)
    else:
        names = list(scan.present_instances)
    ids = {scan.instance_ids[n] for n in names}
    todo = [(img, [b for b in img.boxes if b.instance_id in ids and b.difficulty <= f.max_difficulty])
            for img in scan.images.values()]
    return [(img, boxes) for img, boxes in todo if boxes]


def avd_jobs(cfg, scan, skips, bar) -> Iterator:
    todo = avd_boxes(cfg, scan)
    bar.reset(total=len(todo))
    for img, boxes in todo:
        bar.update(1)
        try:
            image = scan.read_image(img.name)
        except BadInputError as err:
            skips.handle(err, "avd", "AVD entry")
            continue
        for b in boxes:
            inst = scan.instance_names[b.instance_id]
            yield CropJob(key=f"avd/{scan.scan}/{img.name}/{inst}/{b.x0},{b.y0},{b.x1},{b.y1}", image=image,
                          box=(b.x0, b.y0, b.x1, b.y1),
                          columns={"scan": scan.scan, "image": img.name, "instance": inst,
                                   "instance_id": b.instance_id, "difficulty": b.difficulty,
                                   "box_x0": b.x0, "box_y0": b.y0, "box_x1": b.x1, "box_y1": b.y1,
                                   "cam_x": float(img.position[0]), "cam_y": float(img.position[1]),
                                   "heading": float(img.heading), "registered": bool(img.registered)})


@contextmanager
def _scorer_released():
    try:
        yield
    finally:
        forget_scorers()


@contextmanager
def _threads_for_scoring(ctx, executor):
    """Local scoring with threads left at 0 ("all cores"): as many torch threads as cores are
    free now (``pipeline.infra.device.free_of``), then re-chosen once a second as the batches are
    scored (``pipeline.infra.threads``), the count restored after. Yields the starting count."""
    import torch


    auto = executor.name == "local" and ctx.device == "cpu" and not (ctx.threads or ctx.cfg.run.threads)
    before = torch.get_num_threads()   # after ctx.device has configured the stage's threads
    if not auto:
        yield before
        return
    cores, others = available_cores(), runnable_others()
    n = free_of(cores, others)
    log.info("scoring with %d torch thread(s) to start: %d core(s), %.0f other runnable thread(s); "
             "re-chosen every %.0f s from the cores free then", n, cores, others, INTERVAL_S)
    torch.set_num_threads(n)
    try:
        with torch_following(cores) as watch:
            watch.n = n
            yield n
    finally:
        torch.set_num_threads(before)


def prepare_scoring(ctx, executor, policy):
    """(ScoringModel for the tasks, card, whether tasks want a GPU, device named in the summary)."""
    from pipeline.scoring.card import load_classifier  # heavy: torch
    from pipeline.scoring.mc_dropout import MCDropoutScorer  # heavy: torch

    if executor.name == "local":
        device = ctx.device
        model, card = load_classifier(ctx.input("classifier"), device)
        sm = ScoringModel.from_model(model, card, policy, device, with_weights=False)
        fast = classifier(card_arch(card)).channels_last_scoring
        register_scorer(sm.key, MCDropoutScorer(model, device, channels_last=fast))
        return sm, card, False, device
    # Ray: the weights go to the object store; tasks score on a GPU where the cluster has one.
    want = ctx.device_request
    if want == "cuda" and not executor.gpus:
        raise RuntimeError("run.device = 'cuda' (or --device cuda) but the Ray cluster has no GPU")
    device = "cuda" if executor.gpus and want != "cpu" else "cpu"
    model, card = load_classifier(ctx.input("classifier"), "cpu")
    return ScoringModel.from_model(model, card, policy, device, with_weights=True), card, device == "cuda", f"Ray ({device})"


def run(ctx) -> str:
    from loaders.avd import AVDScan  # heavy: scipy
    from pipeline.scoring.crops import CropPolicy  # heavy: cv2

    cfg = ctx.cfg
    f = cfg.features
    t0 = time.perf_counter()
    bb_root, avd_root = data_roots(cfg)
    policy = CropPolicy.from_config(cfg)
    skips = ctx.skips  # data.skip_bad_views; the runner writes the counts into the manifest
    # The scans first: their files (JSON, .mat, instance map) fail fast, before minutes of scoring.
    scans = [AVDScan(avd_root, name, skip=skips.log("avd", "AVD entry")) for name in cfg.data.scans]
    # The cost model again, with the AVD boxes the scans hold (unknown before the data existed).
    check(cfg, "features", Counts(avd_crops=sum(len(b) for s in scans for _, b in avd_boxes(cfg, s))), base=False)
    with executor_for(cfg) as ex, _scorer_released(), _threads_for_scoring(ctx, ex) as threads:
        sm, card, gpu, device = prepare_scoring(ctx, ex, policy)
        for key, mine in (("input_size", policy.size), ("mean", list(policy.mean)), ("std", list(policy.std))):
            if card.get(key) is not None and card[key] != mine:
                raise ValueError(f"{ctx.input('classifier') / out_name('classifier', 'card')}: classifier {key} {card[key]} differs "
                                 f"from 'classifier.{key}' = {mine} (rerun the classifier stage)")
        names = list(card["output_names"])
        dim = len(names)
        md = metadata(config_hash=cfg.section_hash("features"), classifier_hash=card["hash"], seed=f.seed,
                      output_names=names, n_samples=f.n_samples, crop_policy=policy.as_dict())
        timings = {}
        common = dict(seed=f.seed, batch_size=f.batch_size, dim=dim, gpu=gpu)

        # BigBIRD: the deterministic pass plus the dropout samples whose mean the GPs are trained on.
        t1 = time.perf_counter()
        with progress_bar(desc="features: BigBIRD views", unit="view") as bar:
            bb = score_jobs(bigbird_jobs(cfg, bb_root, skips, bar), sm, policy, ex, what="BigBIRD",
                            n_samples=f.bigbird_samples, **common)
        det_bb, mc_bb = bb.arrays(dim, f.bigbird_samples, release=True)
        write_table(build_table("bigbird", bb.columns, det_bb, mc_bb, md), ctx.out / out_name("features", "bigbird"))
        del mc_bb
        timings["bigbird_s"] = round(time.perf_counter() - t1, 2)

        # AVD: deterministic pass + N_s dropout samples per box, every scan of data.scans in turn.
        t2 = time.perf_counter()
        with progress_bar(desc="features: AVD images", unit="image") as bar:
            def jobs():  # rows carry their scan
                for scan in scans:
                    bar.set_description(f"features: AVD {scan.scan}")
                    yield from avd_jobs(cfg, scan, skips, bar)
            av = score_jobs(jobs(), sm, policy, ex, what="AVD", n_samples=f.n_samples, **common)
        # the arrays only as arguments: the table is their one other copy while it is written
        write_table(build_table("avd", av.columns, *av.arrays(dim, f.n_samples, release=True), md),
                    ctx.out / out_name("features", "avd"))
        timings["avd_s"] = round(time.perf_counter() - t2, 2)
    if av.n == 0:
        log.warning("no AVD box up to difficulty %d in scans %s: avd.parquet is empty", f.max_difficulty,
                    ", ".join(cfg.data.scans))

    spread = viewpoint_spread(np.asarray(bb.columns.get("object", []), dtype=object), det_bb, names)
    for obj, s in spread.items():
        log.info("viewpoint spread %s: top components %s, std over views %s (max %.3f, %d argmax classes)",
                 obj, s["top_components"], s["top_std"], s["max_std"], s["argmax_classes_seen"])
    timings["total_s"] = round(time.perf_counter() - t0, 2)
    ctx.extra.update({
        "bigbird_crops": bb.n, "avd_crops": av.n, "n_samples": f.n_samples,
        # crops that ran off their photograph or frame, padded with features.pad (the data page shows them)
        "crops_off_image": {"bigbird": bb.off_image, "avd": av.off_image, "pad": f.pad},
        "bigbird_samples": f.bigbird_samples, "score_dim": dim,
        "classifier_hash": card["hash"], "crop_policy": policy.as_dict(),
        "bigbird_viewpoint_spread": spread, "timings": timings, "torch_threads": threads,
        "executor": cfg.run.executor,
    })
    n_skip = skips.count
    return (f"{bb.n} BigBIRD crops (1 + {f.bigbird_samples} passes) + {av.n} AVD crops (1 + {f.n_samples} passes), D = {dim}, "
            f"{n_skip} skipped; off their image (padded '{f.pad}'): {bb.off_image} BigBIRD, {av.off_image} AVD; BigBIRD {timings['bigbird_s']:.0f} s, AVD {timings['avd_s']:.0f} s on {device}")

"""Built-in source ``synthetic``: the stand-ins rendered by ``loaders.synthetic`` (BigBIRD object
folders, AVD scans, ``truth.json``). Views are rendered by ``data.synthetic.workers`` processes;
every view draws its randomness from (seed, its own name), so the files do not depend on the
worker count or order."""
from __future__ import annotations

import time
from pathlib import Path

from pipeline.infra import footprints
from pipeline.infra.budget import budget, cap_workers, cores
from pipeline.infra.cache import write_json
from pipeline.infra.config.inputs import AVD_INSTANCES
from pipeline.infra.datasets import DatasetSource, Work, register_dataset
from pipeline.infra.outputs import name as out_name
from pipeline.infra.progress import bar as progress_bar
from pipeline.infra.workers import worker_pool
from loaders.synthetic.objects import make_instance
from loaders.synthetic.objects import CATEGORY_NAMES

CHUNK = 12  # views per worker task: one AVD cluster, a few BigBIRD angles


@register_dataset
class Synthetic(DatasetSource):
    key = "synthetic"
    doc = "synthetic stand-ins of BigBIRD objects and AVD scans ([data.synthetic])"
    label = "synthetic data (stand-ins rendered in the BigBIRD and AVD formats, not real images)"
    badge = "synthetic data"
    rendered = True

    def check(self, cfg, need) -> None:
        s = cfg.data.synthetic
        # the stand-ins are drawn and labelled by their AVD names
        unknown = [n for n in s.instances if n not in AVD_INSTANCES or n == "background"]
        need(not unknown, f"'data.synthetic.instances' names {(unknown or [''])[0]!r}, which is not an instance of "
                          "the AVD instance map (docs/formats/avd_instance_id_map.txt; e.g. "
                          f"{AVD_INSTANCES[2]!r})")
        scans = cfg.data.scans
        if 0 < s.instances_per_scan < len(s.instances):
            need(s.instances_per_scan * len(scans) >= len(s.instances),
                 f"'data.synthetic.instances_per_scan' = {s.instances_per_scan} x {len(scans)} scan(s) leaves some "
                 f"of the {len(s.instances)} 'data.synthetic.instances' in no scan")
        if not isinstance(cfg.models.classes, str):
            for c in cfg.models.classes:
                need(c in s.instances, f"'models.classes' names {c!r}, which is not in 'data.synthetic.instances'")
            need(cfg.models.camera in s.bigbird_cameras,
                 f"'models.camera' = {cfg.models.camera} is not among 'data.synthetic.bigbird_cameras'")

    def classes(self, cfg):
        return tuple(cfg.features.bigbird_objects or cfg.data.synthetic.instances)

    def work(self, cfg) -> Work:
        s = cfg.data.synthetic
        rendered = len(s.instances) * len(s.bigbird_cameras) * (360 // s.angle_step_deg)
        objects = len(cfg.features.bigbird_objects or s.instances)
        scored = objects * len(set(cfg.features.bigbird_cameras) & set(s.bigbird_cameras)) * (360 // s.angle_step_deg)
        # the AVD boxes depend on the rendered scans' plans: not known before the data stage
        return Work(scored, None, ("data.synthetic.instances", "data.synthetic.angle_step_deg",
                                   "features.bigbird_cameras", "data.synthetic.bigbird_cameras"),
                    ("data.scans", "features.max_difficulty"),
                    data_keys=("data.synthetic.instances", "data.synthetic.bigbird_cameras",
                               "data.synthetic.angle_step_deg", "data.synthetic.bigbird_width",
                               "data.synthetic.bigbird_height"),
                    rendered_megapixels=rendered * s.bigbird_width * s.bigbird_height / 1e6,
                    render_workers=max(1, min(s.workers, cores())),
                    views_per_class=scored / max(objects, 1) / max(len(cfg.features.bigbird_cameras), 1))

    def write(self, ctx) -> str:
        return write_synthetic(ctx)



def _work(task: tuple):
    """One worker task (module-level so processes can import it)."""
    kind = task[0]
    if kind == "bigbird-meta":
        from loaders.synthetic.bigbird_writer import make_rig, write_object_metadata  # heavy: cv2
        _, folder, syn, _seed = task
        write_object_metadata(Path(folder), make_rig(syn.bigbird_width, syn.bigbird_height), syn.angle_step_deg)
        return kind, 0, None
    if kind == "bigbird-views":
        from loaders.synthetic.bigbird_writer import make_rig, write_view  # heavy: cv2
        from loaders.synthetic.nuisance import RigNuisance  # heavy: cv2
        _, folder, syn, seed, name, views = task
        rig = make_rig(syn.bigbird_width, syn.bigbird_height)
        inst = make_instance(name, seed)
        nz = RigNuisance.from_config(syn)
        for c, a in views:
            write_view(Path(folder), inst, rig, c, a, seed=seed, nuisance=nz, write_depth=syn.write_depth)
        return kind, len(views), None
    if kind == "avd-shots":
        from loaders.synthetic.avd_writer import plan_scan, write_shot  # heavy: cv2
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


def write_synthetic(ctx) -> str:
    from loaders.synthetic.avd_writer import plan_scan, truth, write_scan_metadata  # heavy: cv2
    from loaders.synthetic.bigbird_writer import angles  # heavy: cv2
    from loaders.synthetic.scene import scan_instances  # heavy: cv2

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

"""Built-in source ``real_imagery``: real photographs on real AVD robot geometry
(``loaders.real_imagery``, docs/real_data.md): COIL-100 objects (``data.real_imagery.dataset =
"coil"``, ``loaders.real_imagery.write``) or ETH-80 category folds (``"eth80"``,
``loaders.real_imagery.category``), written as BigBIRD object folders, AVD scans and ``truth.json``."""
from __future__ import annotations

import time

from pipeline.infra.cache import write_json
from pipeline.infra.datasets import DatasetSource, Work, frames_per_scan, register_dataset
from pipeline.infra.outputs import name as out_name
from pipeline.scene.folds import fold_class


@register_dataset
class RealImagery(DatasetSource):
    key = "real_imagery"
    doc = "COIL-100 or ETH-80 photographs on real AVD scans' geometry ([data.real_imagery])"
    badge = "real images, synthetic pairing"

    def describe(self, data: dict, extra: dict) -> str:
        ri = data.get("real_imagery") or {}
        if ri.get("dataset") != "eth80":
            what = ("real imagery: COIL-100 photographs along real AVD robot paths (real poses, boxes and move graph); "
                    "which COIL object stands at each AVD instance, and its yaw, is a synthetic seeded pairing "
                    "(docs/real_data.md)")
        else:
            alt = ri.get("view_split") == "alternate"
            fit = ("each class is fitted on the target instance's own even azimuths (instance level)"
                   if ri.get("class_level") == "instance" else
                   "each class is a category fitted on the other instances of its fold, so every scored frame shows "
                   "an object no class model has seen")
            what = (f"real imagery, {ri.get('class_level', 'category')}-level classes: ETH-80 photographs along real "
                    f"AVD robot paths; {fit}; a frame shows the held-out photograph whose azimuth is nearest the real "
                    f"bearing, up to {'22.5° away (the 8 odd azimuths)' if alt else '11.25° away (16 azimuths)'}; "
                    "which instance stands at each AVD instance, and its yaw, is a synthetic seeded pairing "
                    "(docs/real_data.md)")
        return f"{what}; {backgrounds(ri, extra)}"

    def category_targets(self, data: dict) -> bool:
        return (data.get("real_imagery") or {}).get("dataset") == "eth80"

    def check(self, cfg, need) -> None:
        ri = cfg.data.real_imagery
        need(bool(cfg.data.avd_root), "'data.avd_root' must be set when data.source = 'real_imagery'")
        for key in ("background", "train_background"):
            need(getattr(ri, key) != "avd_frames" or bool(cfg.data.avd_frames_root),
                 f"'data.real_imagery.{key}' = 'avd_frames' needs 'data.avd_frames_root'")
        if ri.dataset == "eth80":
            check_eth80(cfg, need)
        else:
            need(bool(cfg.data.coil_root), "'data.coil_root' must be set when data.source = 'real_imagery'")
            need(ri.train_background != "original",
                 "'data.real_imagery.train_background' = 'original' is ETH-80's blue cloth (COIL-100's own ground "
                 "is black: 'black')")
            need(ri.class_level == "category" and ri.view_split == "none" and not ri.contrast,
                 "'data.real_imagery.class_level', 'view_split' and 'contrast' are for dataset = 'eth80' (COIL classes are "
                 "instances, split by data.real_imagery.train_step_deg)")
            need(ri.train_step_deg % 5 == 0 and 360 % ri.train_step_deg == 0,
                 f"'data.real_imagery.train_step_deg' = {ri.train_step_deg} must be a multiple of 5 that divides 360")
            need(len(set(ri.objects)) == len(ri.objects) and len(ri.objects) >= 2,
                 "'data.real_imagery.objects' must list at least two distinct COIL object numbers")
            n_views = 360 // ri.train_step_deg if ri.train_step_deg and 360 % ri.train_step_deg == 0 else 0
            need(n_views >= cfg.models.min_views,
                 f"'data.real_imagery.train_step_deg' = {ri.train_step_deg} gives each object {n_views} training "
                 f"views, fewer than 'models.min_views' = {cfg.models.min_views}: no class could be modelled (a "
                 f"step of at most {360 // cfg.models.min_views} degrees reaches it)")

    def classes(self, cfg):
        # at most these (the data stage may leave some out): ETH-80's are a class per (category,
        # fold) at both class levels (loaders/real_imagery/category.py, fold_classes)
        ri = cfg.data.real_imagery
        if ri.dataset == "eth80":
            return tuple(fold_class(c, f) for f in ri.instances for c in ri.categories)
        return tuple(f"coil_obj{int(k):03d}" for k in ri.objects)

    def classes_words(self, cfg):
        if cfg.data.real_imagery.dataset == "eth80":
            return ("'models.classes' = 'all': at most a class per category of 'data.real_imagery.categories' and fold "
                    "of 'data.real_imagery.instances' (<category>__f<fold>)")
        return "'models.classes' = 'all': at most the objects of 'data.real_imagery.objects'"

    def work(self, cfg) -> Work:
        ri = cfg.data.real_imagery
        if ri.dataset == "eth80":   # the ring's 16 azimuths 22.5 degrees apart; 'alternate' trains on every other
            ring = 8 if ri.view_split == "alternate" else 16
            views = len(ri.categories) * len(ri.instances) * len(ri.elevations) * ring
            view_keys = ("data.real_imagery.categories", "data.real_imagery.instances", "data.real_imagery.elevations",
                         "data.real_imagery.view_split")
            # a category class is fitted on its fold's other instances, an instance class on its own
            members = len(ri.instances) - 1 if ri.class_level == "category" else 1
            per_class = max(members, 1) * len(ri.elevations) * ring
        else:
            views = len(ri.objects) * (360 // ri.train_step_deg)
            view_keys = ("data.real_imagery.objects", "data.real_imagery.train_step_deg")
            per_class = 360 // ri.train_step_deg
        crops = len(cfg.data.scans) * frames_per_scan(ri.frames, ri.max_difficulty)
        crop_keys = ("data.scans", "data.real_imagery.frames", "data.real_imagery.max_difficulty")
        return Work(views, crops, view_keys, crop_keys, written=views + crops, views_per_class=per_class)

    def write(self, ctx) -> str:
        """COIL-100 photographs on real AVD geometry (loaders/real_imagery/, docs/real_data.md)."""
        from loaders.real_imagery.category import write_real_category  # heavy: cv2
        from loaders.real_imagery.write import write_real_imagery  # heavy: cv2

        cfg = ctx.cfg
        t0 = time.perf_counter()
        writer = write_real_category if cfg.data.real_imagery.dataset == "eth80" else write_real_imagery
        extra, summary = writer(cfg, ctx.out / out_name("data", "bigbird"), ctx.out / out_name("data", "avd"),
                                ctx.out / out_name("data", "truth"), ctx.skips)
        write_json(ctx.out / out_name("data", "roots"), {"source": "real_imagery", "bigbird_root": "bigbird",
                                                         "avd_root": "avd", "scans": list(cfg.data.scans)})
        ctx.extra.update({**extra, "seconds": round(time.perf_counter() - t0, 2)})
        return f"{summary} in {time.perf_counter() - t0:.0f} s"


BACKGROUNDS = {"black": "cut out onto black", "avd_frames": "cut out onto real AVD clutter",
               "original": "on the photographs' own background (ETH-80's blue cloth)"}
PADS = {"surround": "training photographs extended with that surround, so no training crop is padded",
        "none": "training crops that run off their photograph padded by features.pad"}


def backgrounds(ri: dict, extra: dict) -> str:
    """The background of each side, from the data stage's record (``extra``), else the config's keys."""
    bg = extra.get("background") or {}
    if ri.get("dataset") != "eth80" and not bg and "train_pad" not in ri:
        return "backgrounds: COIL-100's own black on both sides"     # a run from before the key
    frames = bg.get("frames") or ri.get("background", "black")
    train = bg.get("training") or (frames if ri.get("train_background", "same") == "same" else ri["train_background"])
    pad_key = bg.get("train_pad") or ri.get("train_pad")
    pad = f"; {PADS[pad_key]}" if pad_key in PADS else ""    # a record from before the key says nothing
    if frames == train:
        return f"backgrounds: frames and training views alike {BACKGROUNDS.get(frames, frames)}{pad}"
    return (f"backgrounds: frames {BACKGROUNDS.get(frames, frames)}, training views {BACKGROUNDS.get(train, train)} "
            f"(a deliberate mismatch, data.real_imagery.train_background){pad}")


def check_eth80(cfg, need) -> None:
    """data.real_imagery.dataset = 'eth80': category classes, folds by instance."""
    ri = cfg.data.real_imagery
    need(bool(cfg.data.eth80_root), "'data.eth80_root' must be set when data.real_imagery.dataset = 'eth80'")
    need(len(set(ri.categories)) == len(ri.categories) and len(ri.categories) >= 2,
         "'data.real_imagery.categories' must list at least two distinct categories")
    need(len(set(ri.instances)) == len(ri.instances) and len(ri.instances) >= 2,
         "'data.real_imagery.instances' must list at least two distinct instances (one fold each)")
    need(ri.class_level != "instance" or ri.view_split == "alternate",
         "'data.real_imagery.class_level' = 'instance' needs 'data.real_imagery.view_split' = 'alternate' (an "
         "instance's class is fitted on its training azimuths; the frames show the held-out ones)")
    need(not ri.contrast or (ri.class_level == "category" and ri.view_split == "alternate"),
         "'data.real_imagery.contrast' = true needs 'class_level' = 'category' (the first arm; the instance arm is "
         "the second) and 'view_split' = 'alternate' (no frame shows an azimuth an instance class was fitted on)")
    need(not ri.contrast or cfg.evaluate.test_domain_variance == "none",
         "'data.real_imagery.contrast' = true needs 'evaluate.test_domain_variance' = 'none' (the calibrated "
         "likelihood is fitted against the category arm's models only)")
    need(cfg.evaluate.candidate_folds, "data.real_imagery.dataset = 'eth80' needs 'evaluate.candidate_folds' = true "
                                       "(a target's candidates are its own fold's classes)")
    need(cfg.evaluate.candidates not in ("sampled", "hard") or cfg.evaluate.n_candidates <= len(ri.categories),
         f"'evaluate.n_candidates' = {cfg.evaluate.n_candidates} exceeds the {len(ri.categories)} categories of a fold")

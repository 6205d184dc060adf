"""A turntable dataset of your own as a source in one file: subclass ``TurntableSource``, give it a
``name`` and a ``read`` (your photographs: {object: {turntable angle in whole degrees: (rgb, mask)}}),
and register it (``vf.register_dataset`` or a ``viewfuse.datasets`` entry point). Everything else
is COIL-100's path (``write``): the training views (angles that are multiples of
``train_step_deg``), cut out by their masks onto black as the frames show them, become BigBIRD object folders with a reference pose per angle
(``category.write_training_class``), the other angles are held out and shown at the located
instances of the real AVD scans of ``data.avd_root`` by the shared scan writer (``scans``), paired
and turned by the section's seeds, and ``truth.json`` records it as COIL's does.

The section ``[data.<name>]`` is ``TurntableConfig`` (subclass it to add keys of your own; ``root``
names your folder, resolved against the config's project root by ``self.path(cfg, "root")``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from loaders.errors import BadInputError
from loaders.real_imagery.category import write_training_class
from loaders.real_imagery.read_check import check_photos
from loaders.real_imagery.clutter import on_surround
from loaders.real_imagery.scans import locate, summaries, write_scans
from loaders.real_imagery.training import modellable
from loaders.real_imagery.write import place_pairs, plain_frames
from pipeline.infra.cache import write_bytes, write_json
from pipeline.infra.config.fields import SEED_MAX, setting as _f
from pipeline.infra.datasets import DatasetSource, Work, frames_per_scan
from pipeline.infra.outputs import name as out_name


@dataclass(frozen=True)
class TurntableConfig:
    root: str = _f("", doc="the folder of turntable photographs (the source's read)")
    train_step_deg: int = _f(30, lo=1, hi=180, doc="angles that are multiples of this train; the others are held "
                                                   "out and shown in the frames")
    pairing_seed: int = _f(0, lo=0, hi=SEED_MAX, doc="which object each located AVD instance stands for")
    yaws_seed: int = _f(0, lo=0, hi=SEED_MAX, doc="each placed object's yaw, uniform on [0, 360) degrees")
    max_difficulty: int = _f(4, lo=1, hi=5, doc="AVD boxes up to this difficulty locate instances and get frames")
    max_ray_residual_m: float = _f(0.25, lo=0.0, hi=100.0, doc="an instance whose rays miss by more is not paired")
    frames: str = _f("viewpoints", choices=("viewpoints", "all"), doc="as data.real_imagery.frames")
    max_view_error_deg: float = _f(20.0, lo=0.0, hi=180.0,
                                   doc="a frame shows the held-out view nearest its bearing; none beyond this")
    noise_std: float = _f(2.0, lo=0.0, hi=50.0, doc="sensor model: Gaussian read noise std, grey levels")
    blur_sigma_px: float = _f(0.7, lo=0.0, hi=10.0, doc="sensor model: Gaussian blur sigma, pixels")
    jpeg_quality: int = _f(85, lo=30, hi=100, doc="JPEG quality of the written AVD frames")
    train_jpeg_quality: int = _f(95, lo=30, hi=100, doc="JPEG quality of the training views")


class TurntableSource(DatasetSource):
    """A source of turntable photographs on real AVD geometry: implement ``read``."""

    config = TurntableConfig
    required_hooks = (("read", "read(cfg, skips)", 2),)

    def read(self, cfg, skips) -> dict[str, dict[int, tuple[np.ndarray, np.ndarray]]]:
        """{object name (a plain name: it names a folder): {angle in whole degrees, [0, 360): (rgb
        uint8 (H, W, 3), mask bool (H, W))}}, checked by ``read_check.check_photos``; a bad
        file is ``skips.handle(BadInputError(path, why), self.name, "photograph")`` (counted, or raised)."""
        raise NotImplementedError(f"dataset source {self.name!r} has no read")

    def check(self, cfg, need) -> None:
        need(bool(cfg.data.avd_root), f"'data.avd_root' must be set when data.source = {self.name!r} (the real "
                                      "AVD scans whose geometry the photographs are placed in)")
        o = self.options(cfg)
        need(bool(o.root), f"'data.{self.name}.root' must be set (the folder of photographs)")
        need(360 % o.train_step_deg == 0, f"'data.{self.name}.train_step_deg' = {o.train_step_deg} must divide 360")

    def work(self, cfg) -> Work:
        """The frames follow the scans as COIL's do; how many photographs train is the reader's (not
        estimated unless a subclass says, e.g. from its folder); a class is fitted on at most one
        photograph per multiple of ``train_step_deg``."""
        o = self.options(cfg)
        crops = len(cfg.data.scans) * frames_per_scan(o.frames, o.max_difficulty)
        return Work(None, crops, (), ("data.scans", f"data.{self.name}.frames", f"data.{self.name}.max_difficulty"),
                    written=crops, views_per_class=360 // o.train_step_deg)

    def write(self, ctx) -> str:
        t0 = time.perf_counter()
        cfg, o, skips = ctx.cfg, self.options(ctx.cfg), ctx.skips
        root, avd_root = self.path(cfg, "root"), cfg.path("data.avd_root")
        train, held = self._split(cfg, o, root, check_photos(self.name, self.read(cfg, skips)), skips)
        bb_out, avd_out = ctx.out / out_name("data", "bigbird"), ctx.out / out_name("data", "avd")
        # cut out onto black and extended as the frames show them (clutter.on_surround)
        crop = (cfg.features.margin, cfg.features.square)
        n_views = sum(write_training_class(bb_out, n, {0: on_surround(
            {a: (rgb, mask, mask.astype(np.float32)) for a, (rgb, mask) in v.items()}, "black", None,
            lambda a: None, crop)[0]}, o.train_jpeg_quality) for n, v in sorted(train.items()))
        names = sorted(held)
        ids = {n: k + 1 for k, n in enumerate(names)}
        avd_out.mkdir(parents=True, exist_ok=True)
        write_bytes(avd_out / "instance_id_map.txt", "".join(f"{n} {ids[n]}\n" for n in names).encode())
        by_id = {ids[n]: held[n] for n in names}
        placed = {}
        for scan in cfg.data.scans:
            loc = locate(avd_root, scan, o.max_difficulty, o.max_ray_residual_m, skips)
            placed[scan] = (loc, place_pairs(scan, loc, by_id, o, lambda k: {"name": names[k - 1]}))
        truth, counts = write_scans(avd_root, avd_out, placed, plain_frames(cfg.data.seed, o), o.frames,
                                    o.max_view_error_deg)
        view_error, box_fit = summaries(truth, o.max_view_error_deg, self.name, "held-out view",
                                        f"data.{self.name}.max_view_error_deg")
        write_json(ctx.out / out_name("data", "truth"), {
            "source": self.name, "pairing": f"synthetic: seeded (data.{self.name}.pairing_seed, yaws_seed)",
            "scans": truth, "view_error_deg": view_error, "box_fit": box_fit, "train_step_deg": o.train_step_deg,
            "objects": {n: {"training_angles": sorted(train[n]), "heldout_angles": sorted(held[n])} for n in names}})
        write_json(ctx.out / out_name("data", "roots"), {"source": self.name, "bigbird_root": "bigbird",
                                                         "avd_root": "avd", "scans": list(cfg.data.scans)})
        ctx.extra.update({"objects": len(names), "training_views": n_views, "scans": counts,
                          "view_error_deg": view_error, "box_fit": box_fit,
                          "seconds": round(time.perf_counter() - t0, 2)})
        per_scan = "; ".join(f"{s}: {c['paired']} paired instances, {c['frames']} frames" for s, c in counts.items())
        return (f"{self.name}: {len(names)} objects, {n_views} training views every {o.train_step_deg} degrees; "
                f"{per_scan} (pairing synthetic, seeded) in {time.perf_counter() - t0:.0f} s")

    def _split(self, cfg, o, root: Path, photos: dict, skips) -> tuple[dict, dict]:
        """(training, held-out) views of each object that can be modelled and has a held-out view."""
        train, held = {}, {}
        for n in sorted(photos):
            tr = {a: v for a, v in photos[n].items() if a % o.train_step_deg == 0}
            he = {a: v for a, v in photos[n].items() if a % o.train_step_deg != 0}
            if not modellable(len(tr), cfg.models.min_views, n, root, f"data.{self.name}.train_step_deg = "
                              f"{o.train_step_deg}", skips, self.name, "photograph"):
                continue
            if not he:
                skips.handle(BadInputError(root, f"{n}: no held-out view (every angle is a multiple of "
                                                 f"data.{self.name}.train_step_deg); object left out"),
                             self.name, "photograph")
                continue
            train[n], held[n] = tr, he
        if len(held) < 2:
            raise BadInputError(root, "fewer than two objects with training and held-out views (the skips above "
                                      "say why)")
        return train, held

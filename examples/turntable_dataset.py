"""A dataset of your own in one file: a folder of turntable photographs with the angle in each file
name (``mug_090.png``) becomes ``data.source = "photo_folder"`` by its reader alone
(``vf.TurntableSource``: training views every ``train_step_deg``, the other angles shown at the
located instances of real-format AVD scans). The script makes its small folder, renders tiny
synthetic AVD scans for the geometry, runs the data stage on the new source, then scores the
written frames of one object with a colour classifier and fuses them.
Run: python examples/turntable_dataset.py"""
import json
import re
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

import viewfuse as vf

ROOT = Path(__file__).resolve().parents[1]
NAME = re.compile(r"([a-z]+)_(\d{3})\.png")
COLOURS = {"mug": (200, 60, 40), "bowl": (40, 160, 200), "can": (90, 200, 70)}


@vf.register_dataset
class PhotoFolder(vf.TurntableSource):
    name = "photo_folder"
    doc = "a folder of <object>_<angle>.png turntable photographs on black"

    def read(self, cfg, skips):
        photos = {}
        for path in sorted(self.path(cfg, "root").glob("*.png")):
            m = NAME.fullmatch(path.name)
            if m is None:
                raise ValueError(f"{path}: not an <object>_<angle>.png photograph")
            rgb = vf.read_image(path)          # checked before decoding; a bad file names itself
            photos.setdefault(m[1], {})[int(m[2])] = (rgb, rgb.max(axis=2) > 16)   # the object: not black
        return photos


def make_photos(folder: Path) -> None:
    """Each object a coloured body with a white mark that turns with the table."""
    folder.mkdir(parents=True)
    for name, colour in COLOURS.items():
        for a in range(0, 360, 15):
            img = np.zeros((96, 96, 3), np.uint8)
            cv2.rectangle(img, (24, 16), (72, 84), colour, -1)
            if np.cos(np.radians(a)) > -0.2:   # the mark is on the side facing the camera
                cv2.circle(img, (int(48 + 20 * np.sin(np.radians(a))), 50), 8, (255, 255, 255), -1)
            cv2.imwrite(str(folder / f"{name}_{a:03d}.png"), img[:, :, ::-1])


def stage(config: str, *sets: str) -> None:
    from stages.commands.cli import main   # the launcher route (docs/api.md): the stages see this registration

    args = ["data", "--config", str(ROOT / "configs" / config)] + [x for s in sets for x in ("--set", s)]
    if main(args) != 0:
        sys.exit("the data stage failed")


def colour_scores(rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    mean = rgb[mask].mean(axis=0) if mask.any() else np.zeros(3)
    return mean / max(mean.sum(), 1.0)


if __name__ == "__main__":
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        make_photos(tmp / "photos")
        # Real-format AVD scans for the geometry: the synthetic stand-ins, small.
        stage("synthetic.toml", f"run.artifacts={tmp / 'art'}", "run.name=geometry", "data.scans=['Home_001_1']",
              "data.synthetic.instances=['red_bull', 'pringles_bbq', 'pepto_bismol']", "data.synthetic.workers=1",
              "data.synthetic.angle_step_deg=120", "data.synthetic.room_size_m=[2.4, 2.4]",
              "data.synthetic.grid_step_m=0.5", "data.synthetic.bigbird_width=64", "data.synthetic.bigbird_height=64",
              "evaluate.n_candidates=3")
        avd = tmp / "art" / "geometry" / "data" / "avd"
        print("dataset sources:", ", ".join(vf.datasets()))
        stage("synthetic.toml", f"run.artifacts={tmp / 'art'}", "run.name=photos", "data.source='photo_folder'",
              f"data.photo_folder.root='{tmp / 'photos'}'", f"data.avd_root='{avd}'", "data.scans=['Home_001_1']",
              "evaluate.n_candidates=3")
        data = tmp / "art" / "photos" / "data"
        truth = json.loads((data / "truth.json").read_text())
        print("training folders:", ", ".join(sorted(p.name for p in (data / "bigbird").iterdir())))

        # A colour classifier: each class's mean training score; a frame's own class probabilities.
        classes = sorted(COLOURS)
        centre = {}
        for c in classes:
            views = sorted((data / "bigbird" / c).glob("NP1_*.jpg"))
            centre[c] = np.mean([colour_scores(im := vf.read_image(v), im.max(axis=2) > 16)
                                 for v in views], axis=0)
        scan = data / "avd" / "Home_001_1"
        ann = json.loads((scan / "annotations.json").read_text())
        ids = dict(line.split() for line in (data / "avd" / "instance_id_map.txt").read_text().splitlines())
        target = sorted(truth["scans"]["Home_001_1"]["instances"])[0]
        own = []
        for image, entry in sorted(ann.items()):
            for x0, y0, x1, y1, label, _ in entry["bounding_boxes"]:
                if str(label) == ids[target]:
                    crop = vf.read_image(scan / "jpg_rgb" / image)[y0:y1, x0:x1]
                    s = colour_scores(crop, crop.max(axis=2) > 16)
                    d = np.array([np.sum((s - centre[c]) ** 2) for c in classes])
                    own.append(np.exp(-d / 0.002) / np.exp(-d / 0.002).sum())
        own = np.asarray(own)[:8, None, :]                        # (views, 1 sample, classes)
        log_post = vf.fuse("simple_bayes", cameras=np.zeros((len(own), 2)), own=own,
                           dropout=np.zeros((len(own), 1, 1)))
        p = np.exp(log_post[-1])
        print(f"{target}: {len(own)} frames fused, P(final) = " + ", ".join(f"{c} {v:.3f}" for c, v in zip(classes, p)))

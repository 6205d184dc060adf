"""A tiny turntable world for the outside-dataset tests (docs/extending.md, "A dataset"): the source
module an outside package ships (``SOURCE_MODULE``: a ``vf.TurntableSource`` reading
``<object>_<angle>.png``), a folder of such photographs drawn here (``write_photos``), and
real-format AVD scans for their geometry (``render_geometry``: the synthetic stand-ins, small).
Importable in the subprocesses that get the outside package on their PYTHONPATH."""
from __future__ import annotations

from pathlib import Path

SOURCE_NAME = "outside_turntable"
PACKAGE = "vf_outside_data"
ENTRY_POINTS = {"viewfuse.datasets": {SOURCE_NAME: f"{PACKAGE}:Folder"}}
SCAN = "Home_001_1"

SOURCE_MODULE = '''
import re
import cv2
import numpy as np
import viewfuse as vf

NAME = re.compile(r"([a-z]+)_(\\d{3})\\.png")


class Folder(vf.TurntableSource):       # no decorator: the entry point names the class
    name = "outside_turntable"

    def read(self, cfg, skips):
        out = {}
        for p in sorted(self.path(cfg, "root").glob("*.png")):
            m = NAME.fullmatch(p.name)
            rgb = np.ascontiguousarray(cv2.imread(str(p))[:, :, ::-1])
            out.setdefault(m[1], {})[int(m[2])] = (rgb, rgb.max(axis=2) > 16)
        return out
'''

# each object a coloured body on black with a white mark that turns with the table
COLOURS = {"mug": (200, 60, 40), "bowl": (40, 160, 200), "can": (90, 200, 70)}

# the synthetic stand-ins at their smallest that still place three instances in one scan
GEOMETRY = {"run": {"name": "geometry"}, "evaluate": {"n_candidates": 3},
            "data": {"scans": [SCAN], "synthetic": {
                "instances": ["red_bull", "pringles_bbq", "pepto_bismol"], "angle_step_deg": 120,
                "bigbird_width": 64, "bigbird_height": 64, "room_size_m": [2.4, 2.4], "grid_step_m": 0.5,
                "distractors": 1, "occluders": 1, "workers": 1}}}


def write_photos(folder: Path, step_deg: int = 15, size: int = 64) -> Path:
    """``<object>_<angle>.png`` for every object of ``COLOURS`` every ``step_deg`` degrees."""
    import cv2
    import numpy as np

    folder.mkdir(parents=True)
    s = size / 64
    for name, colour in COLOURS.items():
        for a in range(0, 360, step_deg):
            img = np.zeros((size, size, 3), np.uint8)
            cv2.rectangle(img, (int(16 * s), int(10 * s)), (int(48 * s), int(56 * s)), colour, -1)
            cv2.circle(img, (int(s * (32 + 12 * np.sin(np.radians(a)))), int(30 * s)), int(5 * s), (255, 255, 255), -1)
            cv2.imwrite(str(folder / f"{name}_{a:03d}.png"), img)
    return folder


def render_geometry(repo: Path, artifacts: Path):
    """The synthetic run ``geometry`` (data stage only) under ``artifacts``; returns its config
    (its AVD scans: ``cfg.stage_dir('data') / 'avd'``)."""
    from pipeline.infra.config import load_config, merge
    from stages.framework.runner import ensure

    cfg = load_config(repo / "configs" / "synthetic.toml", merge(GEOMETRY, {"run": {"artifacts": str(artifacts)}}))
    ensure(cfg, "data", device="cpu")
    return cfg


def source_overrides(artifacts: Path, photos: Path, avd: Path, name: str = "photos", **section) -> dict:
    """The config overrides that make ``data.source`` the outside source on ``photos`` and ``avd``."""
    return {"run": {"artifacts": str(artifacts), "name": name}, "evaluate": {"n_candidates": 3},
            "data": {"source": SOURCE_NAME, "scans": [SCAN], "avd_root": str(avd),
                     SOURCE_NAME: {"root": str(photos), **section}}}

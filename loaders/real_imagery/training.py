"""The COIL training views as BigBIRD object folders (docs/formats/bigbird.md).

Object ``k`` becomes ``coil_obj<k:03d>/``: its views at multiples of ``train_step_deg`` as
``NP1_<a>.jpg`` (the PNG re-encoded as JPEG: BigBIRD stores JPEG), its mask from the black
background (``loaders.coil.object_mask``) as ``masks/NP1_<a>_mask.pbm``, and a 128x128 rig
calibration with reference poses that put camera NP1 at bearing ``a`` around the table axis
(``loaders.synthetic.bigbird_writer``'s rig: the features stage reads the view's GP input from
that pose, so training view ``a`` sits at angle ``a`` on the unit circle, where the frames'
held-out views are placed too). Missing and bad views are left out (counted by the caller).
"""
from __future__ import annotations

from pathlib import Path

from loaders.coil import SIZE, CoilFolder, object_name
from loaders.pbm import encode_pbm
from loaders.synthetic.bigbird_writer import (
    encode_jpeg,
    make_rig,
    write_object_metadata,
)
from pipeline.infra.cache import write_bytes


def training_angles(train_step_deg: int) -> list[int]:
    return list(range(0, 360, int(train_step_deg)))


def write_training_object(root: Path, coil: CoilFolder, k: int, train_step_deg: int, quality: int) -> dict:
    """Write object k's training folder; returns {"angles": written, "missing": lacking ones}.
    Nothing is written for an object with no readable training view."""
    want = training_angles(train_step_deg)
    views = coil.read_object(k, set(want))
    out = {"angles": sorted(views), "missing": [a for a in want if a not in views]}
    if not views:
        return out
    folder = Path(root) / object_name(k)
    write_object_metadata(folder, make_rig(*SIZE), int(train_step_deg))
    for a, (rgb, mask) in sorted(views.items()):
        write_bytes(folder / f"NP1_{a}.jpg", encode_jpeg(rgb, quality))
        write_bytes(folder / "masks" / f"NP1_{a}_mask.pbm", encode_pbm(mask))
    return out

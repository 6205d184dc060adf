"""The COIL training views as BigBIRD object folders (docs/formats/bigbird.md).

Object ``k`` becomes ``coil_obj<k:03d>/``: its views at multiples of ``train_step_deg`` as
``NP1_<a>.jpg`` (the PNG re-encoded as JPEG: BigBIRD stores JPEG; cut out by its mask onto the
frames' surround, black or clutter, and extended so that no training crop runs off it:
``clutter.on_surround``), its mask from the black background (``loaders.coil.object_mask``) as
``masks/NP1_<a>_mask.pbm``, and a rig calibration of the written size with reference poses that put camera NP1 at bearing ``a`` around the table axis
(``loaders.synthetic.bigbird_writer``'s rig: the features stage reads the view's GP input from
that pose, so training view ``a`` sits at angle ``a`` on the unit circle, where the frames'
held-out views are placed too). Missing and bad views are left out (counted by the caller).

``modellable`` is the one check, for every dataset side of this source (COIL objects, ETH-80
instances, any later one), that a side has enough training views for the models stage: a side
with fewer than ``models.min_views`` is skipped in the data stage (counted, logged and named under
``data.skip_bad_views``, or refused with skips off), not two stages later.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from loaders.coil import CoilFolder, object_name
from loaders.errors import BadInputError
from loaders.pbm import encode_pbm
from loaders.synthetic.bigbird_writer import (
    encode_jpeg,
    make_rig,
    write_object_metadata,
)
from pipeline.infra.cache import write_bytes


def modellable(n_views: int, min_views: int, name: str, path: Path, setting: str, skips, part: str,
               what: str, unit: str = "object") -> bool:
    """Whether a side named ``name`` with ``n_views`` readable training views (at ``setting``, the
    keys that chose them) can be modelled; if not, a named skip under ``part`` (``skips.handle``:
    counted and logged, or raised with skips off) and False."""
    if n_views >= min_views:
        return True
    skips.handle(BadInputError(path, f"{name}: {n_views} readable training view{'s' if n_views != 1 else ''} at "
                                     f"{setting}, fewer than models.min_views = {min_views}; {unit} left out"),
                 part, what)
    return False


def training_angles(train_step_deg: int) -> list[int]:
    return list(range(0, 360, int(train_step_deg)))


def write_training_object(root: Path, coil: CoilFolder, k: int, train_step_deg: int, quality: int,
                          prepare=None) -> dict:
    """Write object k's training folder; returns {"angles": written, "missing": lacking ones,
    "border_px": the surround added}. ``prepare(k, {angle: (rgb, mask, alpha)})`` -> (views,
    border px) puts the photographs on the frames' surround (``clutter.on_surround``); the rig is
    the written size's. Nothing is written for an object with no readable training view."""
    want = training_angles(train_step_deg)
    views = coil.read_object(k, set(want))
    out = {"angles": sorted(views), "missing": [a for a in want if a not in views], "border_px": 0}
    if not views:
        return out
    photos = {a: (rgb, mask, mask.astype(np.float32)) for a, (rgb, mask) in views.items()}
    if prepare is not None:
        photos, out["border_px"] = prepare(k, photos)
    H, W = next(iter(photos.values()))[0].shape[:2]
    folder = Path(root) / object_name(k)
    write_object_metadata(folder, make_rig(W, H), int(train_step_deg))
    for a, (rgb, mask, _) in sorted(photos.items()):
        write_bytes(folder / f"NP1_{a}.jpg", encode_jpeg(rgb, quality))
        write_bytes(folder / "masks" / f"NP1_{a}_mask.pbm", encode_pbm(mask))
    return out

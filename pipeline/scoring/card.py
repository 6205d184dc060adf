"""The classifier card: the identity of a scorer (architecture, weights and their digest, training
settings) and loading the classifier it describes, digest checked."""
from __future__ import annotations

from pathlib import Path

from torch import nn

from pipeline.infra.outputs import name as out_name
from pipeline.infra.outputs import read_json
from pipeline.infra.cache import hash_json, sha256_file
from pipeline.scoring.classifiers import UnknownClassifier, card_arch, classifier
from pipeline.scoring.weight_files import WeightsError, WeightsNotFoundError, load_into, load_state_dict_file


CARD = out_name("classifier", "card")
WEIGHTS_NPZ = out_name("classifier", "weights")


def card_hash(card: dict) -> str:
    """Hash of everything that changes a score (not timings or accuracy bookkeeping)."""
    keys = ("architecture", "weights_sha256", "num_classes", "output_names", "dropout", "input_size", "mean", "std")
    # the entry's own keys (EfficientNet-Lite0's drop_connect; none for AlexNet, whose hashes stay as
    # they were); a card of an arch not registered here keeps every key it has of the known ones
    try:
        extra = tuple(classifier(card_arch(card)).card_fields)
    except UnknownClassifier:
        extra = ("drop_connect",)
    return hash_json({k: card.get(k) for k in keys} | {k: card[k] for k in extra if k in card})


def read_card(folder: str | Path) -> dict:
    p = Path(folder) / CARD
    if not p.is_file():
        raise FileNotFoundError(f"{p}: classifier card not found (run `viewfuse classifier` first)")
    card = read_json(p)     # ArtifactError (a ValueError) names the file
    for k in ("weights_file", "weights_sha256", "num_classes", "output_names", "dropout", "hash"):
        if k not in card:
            raise ValueError(f"{p}: classifier card lacks key {k!r}")
    return card


def weights_path(folder: str | Path, card: dict) -> Path:
    p = Path(card["weights_file"])
    return p if p.is_absolute() else Path(folder) / p


def load_classifier(folder: str | Path, device: str = "cpu", verify: bool = True) -> tuple[nn.Module, dict]:
    """Model (eval mode, on ``device``) and card from a classifier artifact folder."""
    card = read_card(folder)
    wp = weights_path(folder, card)
    if not wp.is_file():
        raise WeightsNotFoundError(f"{wp}: weights file named by {Path(folder) / CARD} is missing")
    if verify and sha256_file(wp) != card["weights_sha256"]:
        raise WeightsError(wp, f"sha256 differs from the one recorded in {Path(folder) / CARD}: the file "
                               f"changed since the classifier stage ran (rerun it)")
    entry = classifier(card_arch(card))
    model = entry.build(int(card["num_classes"]), float(card["dropout"]), float(card.get("drop_connect", 0.0)))
    load_into(model, load_state_dict_file(wp), wp, entry.display)
    return model.eval().to(device), card

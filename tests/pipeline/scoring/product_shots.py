"""The real AVD product photographs (``<realdata>/avd_product_shots/<instance>.jpg``, one per
instance) scored by EfficientNet-Lite0, and which ImageNet classes count as a sensible answer for
each: the ImageNet-1k classes of the product's kind of container (ImageNet has no class for the
products themselves). The kinds were assigned from what the products are, not from the network's
answers.

``python -m tests.pipeline.scoring.product_shots`` prints the top-1/top-5 plausibility counts for
the two candidate input normalisations (docs/results.md quotes them).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

BOTTLE = {"beer bottle", "pop bottle", "water bottle", "wine bottle", "whiskey jug", "water jug", "pill bottle",
          "soap dispenser", "lotion", "sunscreen", "hair spray", "perfume", "bottlecap"}
BOX = {"packet", "carton", "crate", "pencil box"}
CAN = {"milk can", "oil filter", "can opener"}
CUP = {"cup", "coffee mug", "beaker", "measuring cup", "goblet", "bucket", "pitcher"}
PLATE = {"plate", "tray", "paper towel", "soup bowl", "mixing bowl"}
PEN = {"fountain pen", "ballpoint", "lipstick", "pencil box"}

KIND = {
    **dict.fromkeys(("aunt_jemima_original_syrup", "cholula_chipotle_hot_sauce", "coca_cola_glass_bottle",
                     "crystal_hot_sauce", "listerine_green", "pepto_bismol", "softsoap_clear", "softsoap_gold",
                     "softsoap_white", "tapatio_hot_sauce",
                     "vo5_tea_therapy_healthful_green_tea_smoothing_shampoo"), BOTTLE),
    **dict.fromkeys(("crest_complete_minty_fresh", "honey_bunches_of_oats_honey_roasted",
                     "honey_bunches_of_oats_with_almonds", "mahatma_rice",
                     "nature_valley_granola_thins_dark_chocolate", "nature_valley_sweet_and_salty_nut_almond",
                     "nature_valley_sweet_and_salty_nut_cashew", "nature_valley_sweet_and_salty_nut_peanut",
                     "nature_valley_sweet_and_salty_nut_roasted_mix_nut", "nutrigrain_harvest_blueberry_bliss",
                     "quaker_chewy_low_fat_chocolate_chunk", "spongebob_squarepants_fruit_snaks"), BOX),
    "advil_liqui_gels": BOX | {"pill bottle"},
    "hersheys_bar": BOX | {"chocolate sauce"},
    **dict.fromkeys(("bumblebee_albacore", "hunts_sauce", "progresso_new_england_clam_chowder", "red_bull",
                     "pringles_bbq"), CAN),
    "red_cup": CUP,
    "paper_plate": PLATE,
    "expo_marker_red": PEN,
}

IMAGENET_NORM = ((0.485, 0.456, 0.406), (0.229, 0.224, 0.225))


def load_shots(folder: Path, size: int = 224) -> tuple[list[str], np.ndarray]:
    """(instance names, uint8 crops (n, size, size, 3)): each whole photograph squared by
    replicating its light border (the project's crop policy, margin 0) and resized."""
    from loaders.jpeg import read_rgb
    from pipeline.scoring.crops import CropPolicy

    policy = CropPolicy(margin=0.0, square=True, size=size, pad="edge")
    names, crops = [], []
    for p in sorted(Path(folder).glob("*.jpg")):
        img = read_rgb(p)  # through the image gate, as the readers decode
        crops.append(policy.crop(img, (0, 0, img.shape[1], img.shape[0]))[0])
        names.append(p.stem)
    return names, np.stack(crops)


def top_k(model, crops: np.ndarray, mean, std, k: int = 5) -> np.ndarray:
    """Indices (n, k) of the k largest deterministic scores."""
    import torch

    from pipeline.scoring.crops import to_tensor

    with torch.no_grad():
        return model.eval()(to_tensor(crops, mean, std)).topk(k, dim=-1).indices.numpy()


def plausibility(names: list[str], top: np.ndarray, classes: list[str]) -> dict:
    """Counts of photographs whose top-1 / any of the top-5 is a sensible class for its kind."""
    top1 = [classes[t[0]] in KIND[n] for n, t in zip(names, top)]
    top5 = [any(classes[j] in KIND[n] for j in t[:5]) for n, t in zip(names, top)]
    return {"photos": len(names), "top1": int(sum(top1)), "top5": int(sum(top5)),
            "top5_missed": [n for n, ok in zip(names, top5) if not ok]}


def main() -> None:
    from pipeline.scoring import efficientnet_lite as E
    from pipeline.scoring.alexnet import imagenet_names
    from tests.loaders.realdata import REALDATA

    names, crops = load_shots(REALDATA / "avd_product_shots")
    model = E.load_wheel_weights()
    classes = imagenet_names(1000)
    for label, (mean, std) in (("(x - 127) / 128", (E.MEAN, E.STD)), ("ImageNet mean/std", IMAGENET_NORM)):
        r = plausibility(names, top_k(model, crops, mean, std), classes)
        print(f"{label:18s}: top-1 sensible {r['top1']}/{r['photos']}, top-5 {r['top5']}/{r['photos']}; "
              f"no sensible class in the top 5: {', '.join(r['top5_missed']) or 'none'}")


if __name__ == "__main__":
    main()

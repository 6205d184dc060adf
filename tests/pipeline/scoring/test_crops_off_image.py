"""The features stage counts the crops whose box ran off their image (filled by features.pad):
the count the data page's claim "no training crop is padded" is checked against."""
from __future__ import annotations

import numpy as np

from pipeline.scoring.crops import CropPolicy
from pipeline.scoring.features import CropJob, Scored, crop_batches


def test_crops_off_their_image_are_counted():
    img = np.zeros((100, 100, 3), np.uint8)
    boxes = [(40, 40, 60, 60),      # inside with its margin
             (0, 40, 20, 60),       # its margin leaves the left edge
             (10, 10, 90, 90),      # 80 px + 10 % a side: 96 px, inside
             (5, 30, 95, 70)]       # 90 px wide: the square of 108 px leaves both sides
    jobs = (CropJob(f"k{i}", img, b) for i, b in enumerate(boxes))
    out = Scored()
    batches = list(crop_batches(jobs, CropPolicy(margin=0.1, size=16), out, what="t", n_samples=0, seed=0,
                                batch_size=3))
    assert sum(len(b.crops) for b in batches) == 4
    assert out.off_image == 2
    inside = [(x0 >= 0 and y0 >= 0 and x1 <= 100 and y1 <= 100) for x0, y0, x1, y1 in
              zip(out.columns["crop_x0"], out.columns["crop_y0"], out.columns["crop_x1"], out.columns["crop_y1"])]
    assert inside == [True, False, True, False]

"""Tiny datasets drawn by hand for the training tests: coloured rectangles on a noisy grey background,
class = colour."""

import numpy as np
from vla_detector_training.dataset import Box, write_data_config, write_sample

NAMES = ["red", "green"]
COLOURS = [(220, 30, 30), (30, 200, 40)]
W, H = 64, 48


def draw_dataset(root, n_train=16, n_val=4, seed=0):
    """Coloured rectangles on a noisy grey background: class = colour."""
    rng = np.random.default_rng(seed)
    for split, n in (("train", n_train), ("val", n_val)):
        for i in range(n):
            img = rng.integers(90, 140, (H, W, 3), dtype=np.uint8)
            boxes = []
            for c in rng.permutation(2)[: rng.integers(1, 3)]:
                bw, bh = rng.integers(8, 20), rng.integers(8, 20)
                x, y = rng.integers(0, W - bw), rng.integers(0, H - bh)
                img[y : y + bh, x : x + bw] = COLOURS[c]
                boxes.append(Box(int(c), x + bw / 2, y + bh / 2, float(bw), float(bh)))
            write_sample(root, split, f"{split}{i}", img, boxes)
    write_data_config(root, NAMES, ["train", "val"])
    return root

"""Synthetic labels match the rendered geometry (checked against an independent segmentation render)."""

from pathlib import Path

import mujoco
import numpy as np
import pytest
from vla_common.catalogue import load_catalogue
from vla_common.objects import OBJECT_CLASSES
from vla_detector_training.dataset import load_data_config, load_split
from vla_detector_training.synth import SceneSampler, synthesize

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def sampler():
    s = SceneSampler(320, 240)
    yield s
    s.close()


def object_masks(sampler):
    """Pixels of each object class from our own segmentation render of the current scene."""
    m = sampler.sim.model
    r = mujoco.Renderer(m, height=sampler.height, width=sampler.width)
    r.enable_segmentation_rendering()
    r.update_scene(sampler.sim.data, camera=sampler.cam)
    seg = r.render()
    r.close()
    geom = np.where(seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM), seg[..., 0], -1)
    body = np.where(geom >= 0, m.geom_bodyid[np.maximum(geom, 0)], -1)
    return {c: body == m.body(f"obj_{c}").id for c in sampler.classes}


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4, 5])
def test_labels_match_rendered_geometry(sampler, seed):
    rgb, labels, info = sampler.sample(np.random.default_rng([42, seed]))
    assert rgb.shape == (240, 320, 3) and rgb.dtype == np.uint8
    assert 1 <= len(labels) <= 4
    assert sorted(lb.class_id for lb in labels) == sorted(p.class_id for p in sampler.sim.object_poses())
    masks = object_masks(sampler)
    for lb in labels:
        mask = masks[lb.class_id]
        ys, xs = np.nonzero(mask)
        assert len(xs) > 20, f"{lb.class_id} barely visible but labelled"
        x1, y1, x2, y2 = lb.box.xyxy()
        inside = (xs + 0.5 >= x1 - 1) & (xs + 0.5 <= x2 + 1) & (ys + 0.5 >= y1 - 1) & (ys + 0.5 <= y2 + 1)
        assert inside.mean() > 0.995, f"{lb.class_id}: object pixels outside its box"
        # Box is tight: where the object is (nearly) unoccluded its pixels span the box.
        if lb.visible > 0.95:
            assert xs.min() + 0.5 - x1 < 2.5 and x2 - xs.max() - 0.5 < 2.5
            assert ys.min() + 0.5 - y1 < 2.5 and y2 - ys.max() - 0.5 < 2.5
        # The box centre is near the object's projected 3-D centre (perspective moves it a little).
        pc = np.array(lb.projected_centre)
        assert np.hypot(*(pc - (lb.box.cx, lb.box.cy))) < 0.2 * max(lb.box.w, lb.box.h) + 1.0


def test_synthesize_writes_reproducible_yolo_dataset(tmp_path):
    counts = synthesize(tmp_path / "a", count=5, seed=7, val_fraction=0.2, progress=False)
    assert counts == {"train": 4, "val": 1}
    cfg = load_data_config(tmp_path / "a")
    assert cfg.names == list(OBJECT_CLASSES)
    train = load_split(cfg, "train")
    assert len(train) == 4 and all(1 <= len(s.boxes) <= 4 for s in train)
    assert (tmp_path / "a" / "synth_meta.jsonl").read_text().count("\n") == 5
    synthesize(tmp_path / "b", count=2, seed=7, split="train", progress=False)
    for name in ("s7_000000.txt", "s7_000001.txt"):
        assert (tmp_path / "a/labels/train" / name).read_text() == (
            tmp_path / "b/labels/train" / name
        ).read_text()
    with pytest.raises(ValueError, match="--count must be positive"):
        synthesize(tmp_path / "c", count=0)


def test_a_lab_catalogue_object_is_in_every_scene_with_include(tmp_path):
    cat = load_catalogue(Path(__file__).resolve().parents[3] / "test" / "data" / "spam_catalogue.yaml")
    counts = synthesize(tmp_path, 3, seed=4, split="train", width=160, height=120, progress=False,
                        catalogue=cat, include="spam")
    assert counts == {"train": 3}
    cfg = load_data_config(tmp_path)
    assert cfg.names == list(cat.classes) and cfg.names[-1] == "spam"
    assert all(any(b.class_index == 5 for b in s.boxes) for s in load_split(cfg, "train"))

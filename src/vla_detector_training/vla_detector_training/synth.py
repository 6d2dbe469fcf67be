"""Programmatically annotated training images rendered from the MuJoCo scene (the paper's 1000 renders).

Each image: a random layout of 1-4 objects (`PandaSim.reset(seed=...)`), a random collision-free arm
configuration (the arm may occlude objects), jittered camera pose / field of view and lighting.
Boxes come from the objects' 3-D geometry projected with `PandaSim.project` (every geom of the
object: box corners, cylinder rims), clipped to the image. A segmentation render measures how much
of each object is actually visible; scenes where an object is mostly hidden or out of frame are
resampled, so every label marks something a detector can see.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import mujoco
import numpy as np
from tqdm import tqdm
from vla_common.catalogue import Catalogue, default_catalogue
from vla_common.kinematics import PandaKinematics
from vla_common.layout import LAYOUT_MAX_OBJECTS, random_layout
from vla_common.robot import Q_MAX, Q_MIN, READY_POSE
from vla_sim.scene import CAMERA_NAME
from vla_sim.sim import PandaSim

from vla_detector_training.dataset import SPLITS, Box, write_data_config, write_sample

MIN_VISIBLE = 0.4  # fraction of an object's silhouette that must be seen (unoccluded and in frame)
MIN_BOX_PX = 4.0
CAM_POS_JITTER = 0.04  # m, per axis (std)
CAM_ROT_JITTER_DEG = 2.0  # std of a small random rotation
FOVY_JITTER_DEG = 3.0  # uniform +-
REACH_PROB = 0.35  # share of arm poses with the gripper next to an object
ARM_SPAN = np.array([1.4, 0.7, 1.0, 0.9, 1.8, 0.9, 2.0])  # rad, uniform +- around the ready pose


@dataclass
class ObjectLabel:
    class_id: str
    class_index: int
    box: Box  # pixels, clipped to the image
    projected_centre: tuple[float, float]  # the object's 3-D centre projected (may be off-image)
    visible: float  # fraction of the silhouette not occluded
    geom_ids: list[int]


def _unit_circle(n: int) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.stack([np.cos(a), np.sin(a)], 1)


def geom_surface_points(model: mujoco.MjModel, data: mujoco.MjData, g: int) -> np.ndarray:
    """World points whose projections bound the geom's image silhouette (box corners, rim circles)."""
    t = model.geom_type[g]
    s = model.geom_size[g]
    if t == mujoco.mjtGeom.mjGEOM_BOX:
        local = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * s
    elif t == mujoco.mjtGeom.mjGEOM_CYLINDER:
        c = _unit_circle(32) * s[0]
        local = np.concatenate([np.c_[c, np.full(32, z)] for z in (-s[1], s[1])])
    elif t in (mujoco.mjtGeom.mjGEOM_ELLIPSOID, mujoco.mjtGeom.mjGEOM_SPHERE):
        r = s if t == mujoco.mjtGeom.mjGEOM_ELLIPSOID else np.array([s[0]] * 3)
        pts = []
        for lat in np.linspace(-np.pi / 2, np.pi / 2, 9):
            c = _unit_circle(24) * math.cos(lat)
            pts.append(np.c_[c, np.full(24, math.sin(lat))])
        local = np.concatenate(pts) * r
    else:  # any other shape: its bounding box
        local = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * s
    return data.geom_xpos[g] + local @ data.geom_xmat[g].reshape(3, 3).T


class SceneSampler:
    """Renders random annotated scenes from a PandaSim at a given image size."""

    def __init__(self, width: int = 320, height: int = 240, catalogue: Catalogue | None = None,
                 include: str | None = None) -> None:
        os.environ.setdefault("MUJOCO_GL", "egl")
        catalogue = catalogue or default_catalogue()
        if include is not None:
            catalogue.spec(include)  # CatalogueError lists the known classes
        self.catalogue, self.include = catalogue, include
        self.classes = list(catalogue.classes)
        self.sim = PandaSim(camera_width=width, camera_height=height, render=True, catalogue=catalogue)
        self.kin = PandaKinematics()
        self.width, self.height = width, height
        self.q_min, self.q_max, self.q_ready = np.asarray(Q_MIN), np.asarray(Q_MAX), np.asarray(READY_POSE)
        m = self.sim.model
        self.model, self.data = m, self.sim.data
        self.cam = self._cam_id()
        self.cam_pos0 = m.cam_pos[self.cam].copy()
        self.cam_quat0 = m.cam_quat[self.cam].copy()
        self.fovy0 = float(m.cam_fovy[self.cam])
        self.light_diffuse0 = m.light_diffuse.copy()
        self.light_dir0 = m.light_dir.copy()
        self.head_ambient0 = m.vis.headlight.ambient.copy()
        self.head_diffuse0 = m.vis.headlight.diffuse.copy()
        body_names = [m.body(b).name for b in range(m.nbody)]
        self.obj_geoms = {
            c: [g for g in range(m.ngeom) if body_names[m.geom_bodyid[g]] == f"obj_{c}"] for c in self.classes
        }
        self.robot_geoms = {g for g in range(m.ngeom) if body_names[m.geom_bodyid[g]].startswith("panda_")}
        self.seg = mujoco.Renderer(m, height=height, width=width)
        self.seg.enable_segmentation_rendering()

    def _cam_id(self) -> int:
        return self.model.camera(CAMERA_NAME).id

    # ------------------------------------------------------------------ randomisation
    def _jitter_view(self, rng: np.random.Generator) -> None:
        m = self.model
        m.cam_pos[self.cam] = self.cam_pos0 + rng.normal(0, CAM_POS_JITTER, 3)
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        dq = np.zeros(4)
        mujoco.mju_axisAngle2Quat(dq, axis, math.radians(rng.normal(0, CAM_ROT_JITTER_DEG)))
        q = np.zeros(4)
        mujoco.mju_mulQuat(q, self.cam_quat0, dq)
        m.cam_quat[self.cam] = q
        m.cam_fovy[self.cam] = self.fovy0 + rng.uniform(-FOVY_JITTER_DEG, FOVY_JITTER_DEG)
        m.light_diffuse[:] = self.light_diffuse0 * rng.uniform(0.6, 1.5, size=(len(self.light_diffuse0), 1))
        d = self.light_dir0 + rng.normal(0, 0.15, self.light_dir0.shape)
        m.light_dir[:] = d / np.linalg.norm(d, axis=1, keepdims=True)
        m.vis.headlight.ambient[:] = self.head_ambient0 * rng.uniform(0.6, 1.6)
        m.vis.headlight.diffuse[:] = self.head_diffuse0 * rng.uniform(0.6, 1.6)

    def _random_q(self, rng: np.random.Generator, poses) -> np.ndarray:
        """Near the ready pose, anywhere, or the gripper reaching down next to an object (as when
        pushing it) - the last is where the arm occludes objects."""
        u = rng.random()
        if u < REACH_PROB and poses:
            p = poses[int(rng.integers(len(poses)))]
            target = np.array([p.x, p.y, 0.0]) + (*rng.uniform(-0.12, 0.12, 2), rng.uniform(0.06, 0.35))
            yaw = rng.uniform(-np.pi, np.pi)
            c, s = math.cos(yaw), math.sin(yaw)
            rot = np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])  # gripper pointing down
            q, ok = self.kin.ik(target, rot, self.q_ready)
            if ok:
                return np.clip(q, self.q_min + 1e-3, self.q_max - 1e-3)
        span = ARM_SPAN * (0.25 if u < REACH_PROB + 0.25 else 1.0)
        q = self.q_ready + rng.uniform(-1, 1, 7) * span
        return np.clip(q, self.q_min + 1e-3, self.q_max - 1e-3)

    def _layout_with(self, include: str, layout_seed: int) -> list:
        """A random layout of 1-4 objects, `include` among them."""
        rng = np.random.default_rng(layout_seed)
        others = [c for c in self.classes if c != include]
        n = int(rng.integers(1, LAYOUT_MAX_OBJECTS + 1))
        chosen = [include] + [others[i] for i in rng.permutation(len(others))[: n - 1]]
        return random_layout(rng, classes=chosen, catalogue=self.catalogue)

    def _arm_collides(self) -> bool:
        d = self.data
        for i in range(d.ncon):
            c = d.contact[i]
            if c.dist < 0 and (c.geom1 in self.robot_geoms) != (c.geom2 in self.robot_geoms):
                return True
        return False

    # ------------------------------------------------------------------ labels
    def labels(self, seg_ids: np.ndarray | None = None) -> list[ObjectLabel]:
        """Boxes of the current scene's objects, and how visible each one is."""
        w, h = self.width, self.height
        out = []
        for pose in self.sim.object_poses():
            geoms = self.obj_geoms[pose.class_id]
            pts = np.concatenate([geom_surface_points(self.model, self.data, g) for g in geoms])
            uv = self.sim.project(pts)
            uv = uv[np.isfinite(uv).all(axis=1)]
            if len(uv) < 3:
                continue
            x1, y1 = uv.min(axis=0)
            x2, y2 = uv.max(axis=0)
            cx1, cy1, cx2, cy2 = max(x1, 0.0), max(y1, 0.0), min(x2, w), min(y2, h)
            ci = self.classes.index(pose.class_id)
            if cx2 - cx1 < MIN_BOX_PX or cy2 - cy1 < MIN_BOX_PX:  # out of frame: never accepted
                out.append(ObjectLabel(pose.class_id, ci, Box(ci, 0, 0, 0, 0), (np.nan, np.nan), 0.0, geoms))
                continue
            centre = self.sim.project(np.array([[pose.x, pose.y, pose.z]]))[0]
            visible = 1.0
            if seg_ids is not None:
                # Silhouette of a convex-ish object = convex hull of its projected surface points.
                full_area = max(cv2.contourArea(cv2.convexHull(uv.astype(np.float32))), 1.0)
                visible = min(float(np.isin(seg_ids, geoms).sum()) / full_area, 1.0)
            box = Box(ci, (cx1 + cx2) / 2, (cy1 + cy2) / 2, cx2 - cx1, cy2 - cy1)
            out.append(
                ObjectLabel(pose.class_id, ci, box, (float(centre[0]), float(centre[1])), visible, geoms)
            )
        return out

    def segmentation(self) -> np.ndarray:
        """(H, W) geom id per pixel (-1: background) of the current scene."""
        self.seg.update_scene(self.data, camera=self.cam)
        s = self.seg.render()
        ids = s[..., 0].copy()
        ids[s[..., 1] != int(mujoco.mjtObj.mjOBJ_GEOM)] = -1
        return ids

    def sample(
        self, rng: np.random.Generator, max_tries: int = 50
    ) -> tuple[np.ndarray, list[ObjectLabel], dict]:
        """One annotated scene: (RGB image, labels, facts for reproduction)."""
        for _ in range(max_tries):
            layout_seed = int(rng.integers(0, 2**31 - 1))
            self._jitter_view(rng)
            objects = self._layout_with(self.include, layout_seed) if self.include else None
            poses = self.sim.reset(seed=layout_seed, objects=objects)
            for _ in range(10):  # arm configurations for this layout
                q = self._random_q(rng, poses)
                self.sim.reset(seed=layout_seed, objects=objects, q0=q)
                if self._arm_collides():
                    continue
                seg = self.segmentation()
                labels = self.labels(seg)
                if labels and all(lb.visible >= MIN_VISIBLE for lb in labels):
                    rgb = self.sim.render()
                    info = {
                        "layout_seed": layout_seed,
                        "q": [round(float(v), 5) for v in q],
                        "camera_pos": [round(float(v), 4) for v in self.model.cam_pos[self.cam]],
                        "fovy": round(float(self.model.cam_fovy[self.cam]), 3),
                        "objects": [
                            {
                                "class_id": lb.class_id,
                                "visible": round(lb.visible, 3),
                                "projected_centre": [round(v, 2) for v in lb.projected_centre],
                            }
                            for lb in labels
                        ],
                    }
                    return rgb, labels, info
        raise RuntimeError(f"no valid scene after {max_tries} layouts (camera or scene changed?)")

    def close(self) -> None:
        self.seg.close()
        self.sim.close()


def split_of(i: int, count: int, split: str, val_fraction: float) -> str:
    """'auto': the last round(count * val_fraction) images go to val, the rest to train."""
    if split != "auto":
        return split
    n_val = int(round(count * val_fraction))
    return "val" if i >= count - n_val else "train"


def synthesize(
    out: str | os.PathLike,
    count: int,
    seed: int = 0,
    split: str = "auto",
    val_fraction: float = 0.1,
    width: int = 320,
    height: int = 240,
    progress: bool = True,
    catalogue: Catalogue | None = None,
    include: str | None = None,
) -> dict[str, int]:
    """Render `count` annotated images into a YOLO dataset at `out`; returns images per split.

    Image i of seed s is drawn from its own generator (seed s, i), so runs are reproducible and a
    different seed gives different scenes. The scene holds the catalogue's objects (default: the
    paper's five), and data.yaml names its classes; with `include`, every scene has that object.
    """
    if count <= 0:
        raise ValueError(f"--count must be positive, got {count}")
    if split not in (*SPLITS, "auto"):
        raise ValueError(f"--split must be one of {(*SPLITS, 'auto')}, got {split!r}")
    root = Path(out)
    root.mkdir(parents=True, exist_ok=True)
    sampler = SceneSampler(width, height, catalogue, include)
    counts: dict[str, int] = {}
    meta_path = root / "synth_meta.jsonl"
    try:
        with open(meta_path, "a", encoding="utf-8") as meta:
            for i in tqdm(range(count), desc="rendering", disable=not progress, dynamic_ncols=True):
                rng = np.random.default_rng([seed, i])
                rgb, labels, info = sampler.sample(rng)
                sp = split_of(i, count, split, val_fraction)
                stem = f"s{seed}_{i:06d}"
                write_sample(root, sp, stem, rgb, [lb.box for lb in labels])
                meta.write(
                    json.dumps({"image": f"images/{sp}/{stem}.png", "seed": seed, "index": i, **info}) + "\n"
                )
                counts[sp] = counts.get(sp, 0) + 1
    finally:
        sampler.close()
    present = [s for s in SPLITS if (root / "images" / s).is_dir()]
    write_data_config(root, sampler.classes, present)
    return counts

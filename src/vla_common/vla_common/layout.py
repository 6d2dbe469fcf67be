"""Object layouts on the table: checking explicit layouts and sampling random ones (pure Python,
shared by the simulator, the task layouts and the tests)."""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np

from vla_common.catalogue import Catalogue, default_catalogue
from vla_common.objects import ObjectPose, yaw_quat

# Table top extents (the robot base is at the origin, x away from the robot).
TABLE_X = (-0.35, 1.05)
TABLE_Y = (-0.75, 0.75)
# Random layouts: object centres inside the reachable workspace, at least LAYOUT_GAP apart, 1..4 objects.
LAYOUT_X = (0.35, 0.70)
LAYOUT_Y = (-0.30, 0.30)
LAYOUT_GAP = 0.03
LAYOUT_MAX_OBJECTS = 4
# Explicit layouts may use more of the table, but objects must lie on it and clear of the robot base.
TABLE_MARGIN = 0.02
ROBOT_BASE_CLEARANCE = 0.15


def _as_pose(item) -> ObjectPose:
    if isinstance(item, ObjectPose):
        return ObjectPose(item.class_id, item.x, item.y, item.yaw)
    if isinstance(item, dict):
        cls = item.get("class_id", item.get("class"))
        missing = [k for k in ("x", "y") if k not in item]
        if cls is None or missing:
            raise ValueError(f"layout entry {item!r} needs 'class_id', 'x' and 'y' (and optional 'yaw')")
        return ObjectPose(cls, item["x"], item["y"], item.get("yaw", 0.0))
    if isinstance(item, (tuple, list)) and len(item) in (3, 4):
        return ObjectPose(item[0], item[1], item[2], item[3] if len(item) == 4 else 0.0)
    raise ValueError(f"layout entry {item!r} is not an ObjectPose, a dict or (class, x, y[, yaw])")


def validate_layout(objects: Iterable, catalogue: Catalogue | None = None) -> list[ObjectPose]:
    """Normalise an explicit layout to ObjectPose (z = 0, yaw-only quaternion) and check it: classes
    of the catalogue, distinct; finite numbers; on the table, clear of the robot base; no overlaps."""
    cat = catalogue or default_catalogue()
    if isinstance(objects, (str, bytes, dict)) or not isinstance(objects, Iterable):
        raise ValueError(f"objects must be a list of object poses, got {type(objects).__name__}")
    layout = [_as_pose(it) for it in objects]
    if len(layout) > len(cat.classes):
        raise ValueError(f"at most {len(cat.classes)} objects (one per class), got {len(layout)}")
    seen = set()
    out = []
    for p in layout:
        cat.spec(p.class_id)  # CatalogueError (a ValueError) lists the known classes
        if p.class_id in seen:
            raise ValueError(f"object class {p.class_id!r} appears twice; one object per class")
        seen.add(p.class_id)
        try:
            x, y, yaw = float(p.x), float(p.y), float(p.yaw)
        except (TypeError, ValueError):
            raise ValueError(f"{p.class_id}: x, y, yaw must be numbers, "
                             f"got {p.x!r}, {p.y!r}, {p.yaw!r}") from None
        if not all(math.isfinite(v) for v in (x, y, yaw)):
            raise ValueError(f"{p.class_id}: x, y, yaw must be finite, got {x}, {y}, {yaw}")
        r = cat.spec(p.class_id).footprint_radius
        if not (TABLE_X[0] + r + TABLE_MARGIN <= x <= TABLE_X[1] - r - TABLE_MARGIN
                and TABLE_Y[0] + r + TABLE_MARGIN <= y <= TABLE_Y[1] - r - TABLE_MARGIN):
            raise ValueError(f"{p.class_id} at ({x:.3f}, {y:.3f}) is off the table "
                             f"(x in {TABLE_X}, y in {TABLE_Y} minus its {r:.3f} m radius)")
        if math.hypot(x, y) < ROBOT_BASE_CLEARANCE + r:
            raise ValueError(f"{p.class_id} at ({x:.3f}, {y:.3f}) overlaps the robot base")
        out.append(ObjectPose(p.class_id, x, y, yaw, 0.0, yaw_quat(yaw)))
    for i, a in enumerate(out):
        for b in out[i + 1:]:
            if overlap(a, b, 0.0, cat):
                raise ValueError(f"{a.class_id} at ({a.x:.3f}, {a.y:.3f}) overlaps {b.class_id} at "
                                 f"({b.x:.3f}, {b.y:.3f})")
    return out


def _corners(p: ObjectPose, spec) -> np.ndarray:
    c, s = math.cos(p.yaw), math.sin(p.yaw)
    hx, hy = spec.size[0] / 2, spec.size[1] / 2
    local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
    return local @ np.array([[c, s], [-s, c]]) + (p.x, p.y)


def overlap(a: ObjectPose, b: ObjectPose, gap: float, catalogue: Catalogue | None = None) -> bool:
    """Footprints (boxes as oriented rectangles, cylinders as discs) closer than `gap`."""
    cat = catalogue or default_catalogue()
    sa, sb = cat.spec(a.class_id), cat.spec(b.class_id)
    d = math.hypot(a.x - b.x, a.y - b.y)
    if d >= sa.footprint_radius + sb.footprint_radius + gap:
        return False
    if sa.shape == "cylinder" and sb.shape == "cylinder":
        return True
    # Separating-axis test on the footprints grown by gap/2 each (discs as their bounding squares
    # aligned with the other shape: conservative).
    shapes = []
    for p, s in ((a, sa), (b, sb)):
        if s.shape == "cylinder":
            other = b if p is a else a
            shapes.append(_disc_square(p, s.size[0], other.yaw))
        else:
            shapes.append(_corners(p, s))
    axes = []
    for poly in shapes:
        for k in range(2):
            e = poly[k + 1] - poly[k]
            axes.append(np.array([-e[1], e[0]]) / np.linalg.norm(e))
    for ax in axes:
        pa, pb = shapes[0] @ ax, shapes[1] @ ax
        if pa.max() + gap / 2 < pb.min() - gap / 2 or pb.max() + gap / 2 < pa.min() - gap / 2:
            return False
    return True


def _disc_square(p: ObjectPose, r: float, yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    local = np.array([[r, r], [-r, r], [-r, -r], [r, -r]])
    return local @ np.array([[c, s], [-s, c]]) + (p.x, p.y)


def random_layout(rng: np.random.Generator, n_objects: int | None = None,
                  classes: Sequence[str] | None = None, max_tries: int = 200,
                  catalogue: Catalogue | None = None) -> list[ObjectPose]:
    """Random non-overlapping layout in the reachable workspace (x 0.35-0.70, |y| <= 0.30) with
    random yaw. n_objects defaults to 1..4; classes (distinct) default to a random choice from the
    catalogue."""
    cat = catalogue or default_catalogue()
    if classes is None:
        n = int(rng.integers(1, LAYOUT_MAX_OBJECTS + 1)) if n_objects is None else int(n_objects)
        if not 1 <= n <= len(cat.classes):
            raise ValueError(f"n_objects must be 1..{len(cat.classes)}, got {n}")
        classes = [cat.classes[i] for i in rng.permutation(len(cat.classes))[:n]]
    out: list[ObjectPose] = []
    for c in classes:
        cat.spec(c)  # CatalogueError (a ValueError) lists the known classes
        for _ in range(max_tries):
            x = float(rng.uniform(*LAYOUT_X))
            y = float(rng.uniform(*LAYOUT_Y))
            yaw = float(rng.uniform(-math.pi, math.pi))
            cand = ObjectPose(c, x, y, yaw, 0.0, yaw_quat(yaw))
            if not any(overlap(cand, o, LAYOUT_GAP, cat) for o in out):
                out.append(cand)
                break
        else:
            raise ValueError(f"could not place {c} without overlap after {max_tries} tries")
    return out

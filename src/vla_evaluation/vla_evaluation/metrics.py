"""Per-episode metrics and reports (plain Python).

- final state error: joint-space L2 distance from the final joint state to the final waypoint, the
  paper's metric (after its 30 s limit);
- task success: the object displaced >= 10 cm within +-30 deg of the intended direction
  (`vla_common.tasks.task_success`), and the first time it held;
- safety: interventions the bridge's safety layer reported, and limit violations measured on the
  joint states themselves (positions outside the Panda's range, speeds over dq_max).
"""
from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from vla_common.robot import DQ_MAX, Q_MAX, Q_MIN
from vla_common.tasks import parse_task, task_success


def final_state_error(q: np.ndarray, final_waypoint: np.ndarray) -> float:
    """Joint-space L2 distance (rad) between a joint state and the final waypoint."""
    q = np.asarray(q, dtype=float).reshape(-1)
    w = np.asarray(final_waypoint, dtype=float).reshape(-1)
    if q.shape != w.shape:
        raise ValueError(f"joint state {q.shape} and waypoint {w.shape} differ in length")
    return float(np.linalg.norm(w - q))


def judge_task(task, start, end, path_xy=None) -> tuple[bool, float, float]:
    """(success, displacement_m, angle_err_deg) of a task from the object's start and end poses; a
    circle also needs the TCP's (x, y) path (`vla_common.tasks.task_success`)."""
    ok, disp, ang = task_success(task, start, end, path_xy)
    return bool(ok), float(disp), float(ang)


class SuccessTracker:
    """Watches the goal object's pose during an episode and remembers when the task first held."""

    def __init__(self, task, start_pose) -> None:
        self.task = task
        self.start = start_pose
        self.is_circle = (parse_task(task) if isinstance(task, str) else task).kind == "circle"
        self.time_to_success: float | None = None
        self.last: tuple[bool, float, float] = (False, 0.0, float("nan"))

    def update(self, t: float, pose) -> bool:
        """Judge the pose at time t. A circle is never judged here: an unmoved object is all it can
        see, and that also holds for an arm that never moved; the circle is judged at the end with
        the arm's path."""
        if self.is_circle:
            return False
        self.last = judge_task(self.task, self.start, pose)
        if self.last[0] and self.time_to_success is None:
            self.time_to_success = float(t)
        return self.last[0]


class LimitMonitor:
    """Counts joint-state samples outside the robot's position range or over its speed limits (the
    Panda's; `spec`: another robot's table, e.g. vla_common.robot.FR3).

    Tolerances absorb the simulator's servo overshoot and float noise; anything beyond is a real
    violation that the safety layer should have prevented.
    """

    def __init__(self, position_tol: float = 1e-3, velocity_tol: float = 0.02, spec=None) -> None:
        self.q_min, self.q_max, self.dq_max = ((Q_MIN, Q_MAX, DQ_MAX) if spec is None else
                                               (spec.q_min, spec.q_max, spec.dq_max))
        self.position_tol = position_tol
        self.velocity_tol = velocity_tol
        self.samples = 0
        self.position_violations = 0
        self.velocity_violations = 0
        self.max_speed_ratio = 0.0

    def update(self, q: Sequence[float], dq: Sequence[float] | None = None) -> None:
        q = np.asarray(q, dtype=float)
        if q.shape != (7,):
            return
        self.samples += 1
        if np.any(q < self.q_min - self.position_tol) or np.any(q > self.q_max + self.position_tol):
            self.position_violations += 1
        if dq is not None and len(dq) == 7:
            ratio = float(np.max(np.abs(np.asarray(dq, dtype=float)) / self.dq_max))
            self.max_speed_ratio = max(self.max_speed_ratio, ratio)
            if ratio > 1.0 + self.velocity_tol:
                self.velocity_violations += 1

    @property
    def violations(self) -> int:
        return self.position_violations + self.velocity_violations


class SafetyTally:
    """Interventions reported on the bridge's `~/status` during one episode, by status text/code.

    The status carries a running `interventions` counter; the episode's count is its increase, which
    is robust to status messages lost in transit.
    """

    def __init__(self) -> None:
        self.first_counter: int | None = None
        self.last_counter: int | None = None
        self.first_rejected: int | None = None
        self.last_rejected: int | None = None
        self.by_code: dict[int, int] = {}
        self.estop_seen = False

    def update(self, code: int, interventions: int, estop_active: bool = False,
               rejected: int | None = None) -> None:
        if self.first_counter is None:
            self.first_counter = int(interventions)
        self.last_counter = int(interventions)
        if rejected is not None:
            if self.first_rejected is None:
                self.first_rejected = int(rejected)
            self.last_rejected = int(rejected)
        if code != 0:
            self.by_code[int(code)] = self.by_code.get(int(code), 0) + 1
        self.estop_seen = self.estop_seen or bool(estop_active)

    @property
    def interventions(self) -> int:
        if self.first_counter is None or self.last_counter is None:
            return 0
        return max(0, self.last_counter - self.first_counter)

    @property
    def rejected(self) -> int:
        """Commands the bridge rejected (non-finite, wrong length) during the episode."""
        if self.first_rejected is None or self.last_rejected is None:
            return 0
        return max(0, self.last_rejected - self.first_rejected)


@dataclass
class EpisodeResult:
    """Everything measured in one evaluation episode (one row of the report)."""

    task: str
    layout_seed: int
    mode: str = "kinematic"
    encoder: str = ""
    model: str = ""
    final_state_error: float = float("nan")
    success: bool | None = None
    displacement_m: float | None = None
    angle_err_deg: float | None = None
    time_to_success: float | None = None
    duration_s: float = 0.0
    safety_interventions: int | None = None
    limit_violations: int | None = None
    detected_class: str = ""
    note: str = ""
    ee_path: np.ndarray | None = field(default=None, repr=False)  # (T, 3) TCP positions
    object_start: dict | None = None
    object_end: dict | None = None
    extra: dict = field(default_factory=dict)

    def row(self) -> dict:
        """Flat values for CSV (no paths)."""
        d = asdict(self)
        for key in ("ee_path", "object_start", "object_end", "extra"):
            d.pop(key)
        d.update({f"x_{k}": v for k, v in self.extra.items()})
        return d

    def to_json(self, include_path: bool = False) -> dict:
        d = self.row()
        d["object_start"] = self.object_start
        d["object_end"] = self.object_end
        if include_path and self.ee_path is not None:
            d["ee_path"] = np.round(np.asarray(self.ee_path), 4).tolist()
        return _jsonable(d)


def mean_sem(values: Iterable[float]) -> tuple[float, float, int]:
    """Mean and standard error of the finite values (sem 0 for a single value)."""
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    if v.size == 0:
        return float("nan"), float("nan"), 0
    sem = float(v.std(ddof=1) / math.sqrt(v.size)) if v.size > 1 else 0.0
    return float(v.mean()), sem, int(v.size)


def summarize(results: Sequence[EpisodeResult], keys: Sequence[str] = ("task",)) -> list[dict]:
    """Group results by `keys` (attributes or `extra` entries): n, success rate, mean +- sem of the
    final state error, median time to success, total interventions and violations."""
    groups: dict[tuple, list[EpisodeResult]] = {}
    for r in results:
        groups.setdefault(tuple(_key(r, k) for k in keys), []).append(r)
    out = []
    for gkey, rs in groups.items():
        fse, fse_sem, _ = mean_sem(r.final_state_error for r in rs)
        judged = [r.success for r in rs if r.success is not None]
        tts = [r.time_to_success for r in rs if r.time_to_success is not None]
        row = dict(zip(keys, gkey))
        row.update({
            "episodes": len(rs),
            "success_rate": (sum(judged) / len(judged)) if judged else None,
            "final_state_error": fse,
            "final_state_error_sem": fse_sem,
            "time_to_success_median": float(np.median(tts)) if tts else None,
            "safety_interventions": _sum_or_none(r.safety_interventions for r in rs),
            "limit_violations": _sum_or_none(r.limit_violations for r in rs),
        })
        out.append(row)
    return out


def _key(r: EpisodeResult, k: str):
    return getattr(r, k) if hasattr(r, k) else r.extra.get(k)


def _sum_or_none(values: Iterable[int | None]) -> int | None:
    vals = [v for v in values if v is not None]
    return int(sum(vals)) if vals else None


def write_csv(rows: Sequence[dict], path: str | os.PathLike) -> Path:
    """Rows of dicts to CSV; the header is the union of keys in first-seen order."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    header: list[str] = []
    for r in rows:
        header.extend(k for k in r if k not in header)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=header)
        w.writeheader()
        for r in rows:
            w.writerow({k: _csv_value(r.get(k)) for k in header})
    return path


def read_csv(path: str | os.PathLike) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def write_json(obj, path: str | os.PathLike) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_jsonable(obj), indent=2) + "\n")
    return path


def _csv_value(v):
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    return "" if v is None else v


def _jsonable(obj):
    """Plain JSON types; NaN/inf become null (JSON has no NaN)."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer, int)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        return float(obj) if math.isfinite(float(obj)) else None
    return obj

"""One detected object: the one type the detector produces, the recorder stores, the controller and
training read. Box centre and size in pixels of the image it was found in (plain Python, no ROS;
`vla_common.ros.convert` turns it into and out of messages)."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class Detection:
    class_id: str
    score: float
    cx: float
    cy: float
    width: float = 0.0
    height: float = 0.0
    class_index: int = -1  # index in the detector's class list; -1: unknown

    def as_dict(self) -> dict:
        """The JSON shape bags and reports store."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping) -> Detection:
        """Inverse of as_dict; also reads the older `w`/`h` keys. ValueError names a missing key."""
        try:
            return cls(
                class_id=str(d["class_id"]),
                score=float(d.get("score", 1.0)),
                cx=float(d["cx"]),
                cy=float(d["cy"]),
                width=float(d.get("width", d.get("w", 0.0))),
                height=float(d.get("height", d.get("h", 0.0))),
                class_index=int(d.get("class_index", -1)),
            )
        except KeyError as err:
            raise ValueError(f"detection without {err.args[0]!r}: {dict(d)}") from None

    def is_finite(self) -> bool:
        return all(math.isfinite(v) for v in (self.score, self.cx, self.cy, self.width, self.height))


def best(detections: Iterable[Detection], prefer_class: str | None = None) -> Detection | None:
    """The highest-score detection, or None; with `prefer_class`, the best of that class when any."""
    dets = list(detections)
    preferred = [d for d in dets if prefer_class and d.class_id == prefer_class]
    return max(preferred or dets, key=lambda d: d.score, default=None)

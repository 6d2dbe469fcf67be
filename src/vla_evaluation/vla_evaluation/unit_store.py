"""A sweep's results on disk, one JSON line per finished unit: append-only, fsynced, resumable.

Only the driver writes it (vla_evaluation.sweep). On open it reads the units already recorded, so a
sweep stopped at any moment resumes with the units that are missing, none lost or duplicated; a
partial last line (a stop during the write) is set aside in `<name>.partial`, never deleted. The
header line names what the sweep is (its plan's digest): a store of another plan is refused.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any


def _plain(x: Any) -> Any:
    """numpy scalars and arrays as JSON numbers and lists."""
    if hasattr(x, "tolist"):
        return x.tolist()
    raise TypeError(f"{type(x).__name__} is not JSON serialisable")


def digest(plan: Any) -> str:
    """A short stable digest of a JSON-able plan: what decides every unit's result."""
    return hashlib.sha256(json.dumps(plan, sort_keys=True, default=str).encode()).hexdigest()[:16]


class UnitStore:
    """`done`: {key: result} of the units recorded so far; `record(key, result)` adds one."""

    def __init__(self, path: Path, plan_digest: str) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.done: dict[str, Any] = {}
        lines = self._whole_lines()
        if lines:
            head = json.loads(lines[0])
            if head.get("plan_digest") != plan_digest:
                raise SystemExit(f"{self.path} holds the units of another plan ({head.get('plan_digest')}, "
                                 f"not {plan_digest}); choose another folder")
            for line in lines[1:]:
                row = json.loads(line)
                self.done[row["key"]] = row["result"]
        else:
            self._append({"plan_digest": plan_digest})

    def _whole_lines(self) -> list[str]:
        if not self.path.exists():
            return []
        raw = self.path.read_bytes()
        good, _, tail = raw.rpartition(b"\n")
        if tail.strip():  # a stop during the write: keep the fragment aside, truncate to whole lines
            with open(self.path.with_name(self.path.name + ".partial"), "ab") as f:
                f.write(tail + b"\n")
            with open(self.path, "r+b") as f:
                f.truncate(len(good) + 1 if good else 0)
        return [x for x in (good.decode().splitlines() if good else []) if x.strip()]

    def _append(self, obj: dict) -> None:
        with open(self.path, "ab") as f:
            f.write((json.dumps(obj, sort_keys=True, default=_plain) + "\n").encode())
            f.flush()
            os.fsync(f.fileno())

    def record(self, key: str, result: Any) -> None:
        if key in self.done:  # exactly once, whatever a retry delivers
            return
        self._append({"key": key, "result": result})
        self.done[key] = json.loads(json.dumps(result, default=_plain))  # as a resumed run reads it

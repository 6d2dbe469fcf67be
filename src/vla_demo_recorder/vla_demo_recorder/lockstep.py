"""The recorder in the simulated Panda's lockstep (`lockstep: true`; vla_evaluation generate), without ROS.

The recorder is then one of the bridge's lockstep participants: it answers every joint state once it
has handled it, so when the simulation holds (where an orchestrator starts or stops an episode) the
recorder has handled every step the simulation made, and an episode's messages are those of the same
steps at any load. A message from another node (the detector's detections of a frame published before
the start) can still arrive after the start: a message stamped at or before the episode's start is
left out (`StampWindow`), as the loader would read it as the episode's context.

The stamp is read from the serialized message (CDR) without deserializing it: a message type whose
first field is a std_msgs/Header starts, after the 4-byte encapsulation, with the stamp's int32 sec
and uint32 nanosec.
"""
from __future__ import annotations

import struct


def has_header(cls: type) -> bool:
    """Whether a generated message class's first field is a std_msgs/Header."""
    fields = getattr(cls, "get_fields_and_field_types", lambda: {})()
    first = next(iter(fields.items()), ("", ""))
    return first == ("header", "std_msgs/Header")


def header_stamp_ns(data: bytes) -> int:
    """The header stamp (ns) of a CDR-serialized message whose first field is a std_msgs/Header."""
    if len(data) < 12:
        raise ValueError(f"a serialized message of {len(data)} bytes has no header stamp")
    order = "<" if data[1] & 1 else ">"   # encapsulation: CDR_LE (0x0001) or CDR_BE (0x0000)
    sec, nanosec = struct.unpack_from(order + "iI", data, 4)
    return sec * 1_000_000_000 + nanosec


class StampWindow:
    """Which stamped messages an episode keeps: those stamped after its start (ns)."""

    def __init__(self) -> None:
        self.start_ns: int | None = None

    def open(self, start_ns: int) -> None:
        self.start_ns = int(start_ns)

    def keeps(self, data: bytes) -> bool:
        return self.start_ns is None or header_stamp_ns(data) > self.start_ns

"""Latest-value slots in shared memory between the ROS node and the 1 kHz libfranka loop process.

No queues and no locks: each side writes only its own blocks and never waits for the other.
A block that holds several values is a seqlock (the writer makes the counter odd, writes, makes it
even; a reader retries while it is odd or changed), so a reader never sees half a command or half a
state. Single values (flags, request counters) are aligned 8-byte doubles, which x86-64 stores and
loads whole. The file lives in /dev/shm; the creating side (the ROS node) unlinks it on close.

Blocks (all float64 unless noted):
- command (ROS -> loop, seqlock): count of values, command sequence, arrival time, 7 values;
- control (ROS -> loop, plain): e-stop, shutdown, teaching wanted, request counters;
- state (loop -> ROS, seqlock): one robot sample and the loop's status, see `STATE_DTYPE`;
- history (loop -> ROS): the last HISTORY robot samples (cycle, stamp, q, dq, tau_J), each entry
  marked by its cycle number before and after it is written, so the ROS side publishes every robot
  state even when its timer runs late (a loaded machine) without the loop ever waiting;
- texts (loop -> ROS, seqlock each, UTF-8 bytes): the loop's status text and the filter's text;
- rings (loop -> bench, plain): per-cycle period, busy time and command latency.

The whole file is one NumPy structured record, `LAYOUT`, declared once below: every block is a named
field of it, every reader and writer goes through its field names.
"""

from __future__ import annotations

import mmap
import os
import tempfile

import numpy as np

NUM_JOINTS = 7
MAX_TEXT = 1024
RING = 1 << 16
HISTORY = 512
_F, _J = np.float64, (NUM_JOINTS,)

# Command block (ROS -> loop): the count of values, the command sequence, its arrival (monotonic s), 7
# values (only a 7-value command fits; the count tells the loop about a wrong length).
CMD_DTYPE = np.dtype([("n", _F), ("seq", _F), ("arrived", _F), ("values", _F, _J)])
# Control block: single values written by the ROS side only.
CONTROL_DTYPE = np.dtype([(name, _F) for name in
                          ("estop", "shutdown", "teaching", "teaching_req", "recover_req", "parent_pid")])
# State block (loop -> ROS): one robot sample and the loop's status.
STATE_DTYPE = np.dtype([
    ("cycle", _F),            # robot states received by this loop process
    ("robot_time", _F),       # the robot's own clock (s)
    ("stamp", _F),            # wall time (time.time()) when the state arrived
    ("q", _F, _J),
    ("dq", _F, _J),
    ("tau_J", _F, _J),
    ("O_T_EE", _F, (16,)),    # column-major 4x4, the robot's end-effector pose in its base frame
    ("dq_cmd", _F, _J),       # the velocity last commanded (after the safety filter)
    ("robot_mode", _F),       # franka RobotMode as an int
    ("success_rate", _F),     # control_command_success_rate (0..1)
    ("status", _F),           # libfranka_loop.LoopStatus
    ("filter_code", _F),      # safety filter code of the last cycle
    ("interventions", _F),    # safety filter interventions in this loop process
    ("last_intervention", _F),
    ("mode", _F),             # libfranka_loop.Mode: idle, velocity, torque (teaching)
    ("estop_active", _F),
    ("cmd_seq", _F),          # command sequence last taken by the loop
    ("latency", _F),          # s from that command's arrival to the first robot command with it
    ("recover_ack", _F),      # recover_req value last handled
    ("recover_ok", _F),
    ("teaching_ack", _F),     # teaching_req value last handled
    ("connects", _F),         # successful connections
    ("errors", _F),           # robot errors seen (reflexes, lost connections)
    ("missed", _F),           # robot cycles missed (sum of Durations minus cycles)
    ("motions", _F),          # motions started
    ("pid", _F),
])
# A history entry: marked by its cycle number before (`cycle`) and after (`end`) it is written.
HISTORY_DTYPE = np.dtype([("cycle", _F), ("stamp", _F), ("q", _F, _J), ("dq", _F, _J), ("tau_J", _F, _J),
                          ("end", _F)])
RINGS = ("period", "busy", "latency")
TEXTS = ("status", "filter")
# The file: every block, in order.
LAYOUT = np.dtype([
    ("cmd_seq", _F), ("cmd", CMD_DTYPE),
    ("control", CONTROL_DTYPE),
    ("state_seq", _F), ("state", STATE_DTYPE),
    ("text_seq", _F, (len(TEXTS),)), ("text_len", _F, (len(TEXTS),)),
    ("ring_idx", _F), ("rings", _F, (len(RINGS), RING)),
    ("history", HISTORY_DTYPE, (HISTORY,)),
    ("text", np.uint8, (len(TEXTS), MAX_TEXT)),
])
SIZE = LAYOUT.itemsize


def _shm_dir() -> str:
    return "/dev/shm" if os.path.isdir("/dev/shm") else tempfile.gettempdir()


class Slots:
    """The shared blocks over one mmap'ed file. `Slots.create()` on the ROS side, `Slots.attach(path)`
    in the loop process. Blocks are 0-d structured views (`slots.control["estop"]`)."""

    def __init__(self, path: str, owner: bool):
        self.path = path
        self.owner = owner
        fd = os.open(path, os.O_RDWR)
        try:
            self._mm = mmap.mmap(fd, SIZE)
        finally:
            os.close(fd)
        m = self._m = np.ndarray((), LAYOUT, buffer=self._mm)
        self._cmd_seq = m["cmd_seq"].reshape(1)
        self.cmd = m["cmd"]
        self.control = m["control"]
        self._state_seq = m["state_seq"].reshape(1)
        self.state = m["state"]
        self._text_seq = m["text_seq"]
        self._text_len = m["text_len"]
        self._ring_idx = m["ring_idx"].reshape(1)
        self.rings = {name: m["rings"][i] for i, name in enumerate(RINGS)}
        self.history = m["history"]
        self._text = m["text"]
        self._cmd_scratch = np.zeros((), CMD_DTYPE)
        self._state_scratch = np.zeros((), STATE_DTYPE)

    @classmethod
    def create(cls) -> Slots:
        fd, path = tempfile.mkstemp(prefix="vla-libfranka-", suffix=".shm", dir=_shm_dir())
        try:
            os.ftruncate(fd, SIZE)
        finally:
            os.close(fd)
        return cls(path, owner=True)

    @classmethod
    def attach(cls, path: str) -> Slots:
        if os.path.getsize(path) != SIZE:
            raise ValueError(f"{path} is {os.path.getsize(path)} bytes, expected {SIZE}: another layout")
        return cls(path, owner=False)

    def close(self) -> None:
        # Views into the map must go before the map itself can close.
        for name in ("_m", "_cmd_seq", "cmd", "control", "_state_seq", "state", "_text_seq", "_text_len",
                     "_ring_idx", "_text", "history"):
            setattr(self, name, None)
        self.rings = {}
        try:
            self._mm.close()
        except BufferError:
            pass  # a copy still refers to it; the OS frees it with the process
        if self.owner:
            try:
                os.unlink(self.path)
            except FileNotFoundError:
                pass

    # ------------------------------------------------------------------------------------ command
    def write_command(self, values, arrived: float) -> int:
        """ROS side: publish the latest command (any length; only 7 values fit, the count tells the
        loop about a wrong length). Returns its sequence number."""
        n = len(values)
        seq = self._cmd_seq
        seq[0] += 1.0
        c = self.cmd
        c["n"] = n
        c["seq"] += 1.0
        c["arrived"] = arrived
        if n == NUM_JOINTS:
            c["values"] = values
        seq[0] += 1.0
        return int(c["seq"])

    def read_command(self) -> np.ndarray | None:
        """Loop side: a consistent copy (a scratch array reused on every call: copy before keeping), or
        None while the ROS side is inside a write (it may be preempted there for milliseconds: the
        loop takes the command next cycle instead of waiting)."""
        return _read_seqlock(self._cmd_seq, self.cmd, self._cmd_scratch, tries=20)

    # -------------------------------------------------------------------------------------- state
    def claim_state_writer(self) -> None:
        """Loop side, at start: a predecessor killed inside a write leaves a counter odd; even it."""
        for seq in (self._state_seq, self._text_seq):
            for i in range(len(seq)):
                if int(seq[i]) % 2:
                    seq[i] += 1.0

    def begin_state(self) -> np.ndarray:
        """Loop side: open the state block for writing; fill the returned record (`b["q"] = ...`), then
        `end_state()`."""
        self._state_seq[0] += 1.0
        return self.state

    def end_state(self) -> None:
        self._state_seq[0] += 1.0

    @property
    def state_seq(self) -> float:
        """Changes with every write of the loop (also status-only ones): its liveness."""
        return float(self._state_seq[0])

    def read_state(self) -> np.record | None:
        """ROS side: a consistent copy of the latest state (fields of STATE_DTYPE, also as attributes:
        `s.q`, `s.status`), or None while the loop is inside a write."""
        out = _read_seqlock(self._state_seq, self.state, self._state_scratch, tries=1000)
        return None if out is None else out.copy().view(np.recarray)[()]

    # ------------------------------------------------------------------------------------ history
    def push_history(self, cycle: int, stamp: float, q, dq, tau) -> None:
        """Loop side: one robot sample into its entry (the oldest is overwritten)."""
        e = self.history[cycle % HISTORY]            # a view of the entry
        e["cycle"] = -1.0                            # being written
        e["end"] = -1.0
        e["stamp"] = stamp
        e["q"] = q
        e["dq"] = dq
        e["tau_J"] = tau
        e["end"] = cycle
        e["cycle"] = cycle

    def read_history(self, cycle: int) -> np.void | None:
        """ROS side: a copy of the sample of robot cycle `cycle` (fields of HISTORY_DTYPE), or None if
        it has been overwritten (or is being written)."""
        k = cycle % HISTORY
        e = self.history[k]
        if e["end"] != cycle:
            return None
        out = self.history[k:k + 1].copy()[0]
        return out if out["cycle"] == cycle and e["end"] == cycle else None

    # -------------------------------------------------------------------------------------- texts
    def write_text(self, which: str, text: str) -> None:
        i = TEXTS.index(which)
        data = text.encode("utf-8", "replace")[:MAX_TEXT]
        seq = self._text_seq
        seq[i] += 1.0
        self._text[i, :len(data)] = np.frombuffer(data, dtype=np.uint8)
        self._text_len[i] = len(data)
        seq[i] += 1.0

    def read_text(self, which: str) -> str | None:
        """ROS side: the text, or None while the loop is inside a write."""
        i = TEXTS.index(which)
        seq = self._text_seq
        for _ in range(1000):
            s1 = seq[i]
            if int(s1) % 2 == 0:
                n = int(self._text_len[i])
                data = self._text[i, :n].tobytes()
                if seq[i] == s1:
                    return data.decode("utf-8", "replace")
        return None

    # -------------------------------------------------------------------------------------- rings
    def ring_push(self, period: float, busy: float, latency: float) -> None:
        """Loop side: one cycle's figures (NaN where a figure does not apply)."""
        k = int(self._ring_idx[0]) % RING
        r = self.rings
        r["period"][k] = period
        r["busy"][k] = busy
        r["latency"][k] = latency
        self._ring_idx[0] += 1.0

    def ring_snapshot(self) -> dict[str, np.ndarray]:
        """The last min(RING, pushes) entries of every ring, oldest first (bench side)."""
        n = int(self._ring_idx[0])
        count = min(n, RING)
        order = (np.arange(n - count, n) % RING) if count else np.zeros(0, dtype=int)
        return {name: ring[order].copy() for name, ring in self.rings.items()}

    @property
    def ring_count(self) -> int:
        return int(self._ring_idx[0])


def _read_seqlock(seq: np.ndarray, block: np.ndarray, out: np.ndarray, tries: int) -> np.ndarray | None:
    """A consistent copy of `block` into `out`, or None if every try met a write in progress."""
    for _ in range(tries):
        s1 = seq[0]
        if int(s1) % 2 == 0:
            np.copyto(out, block)
            if seq[0] == s1:
                return out
    return None

"""Latest-value slots in shared memory between the ROS node and the 1 kHz libfranka loop process.

No queues and no locks: each side writes only its own blocks and never waits for the other.
A block that holds several values is a seqlock (the writer makes the counter odd, writes, makes it
even; a reader retries while it is odd or changed), so a reader never sees half a command or half a
state. Single values (flags, request counters) are aligned 8-byte doubles, which x86-64 stores and
loads whole. The file lives in /dev/shm; the creating side (the ROS node) unlinks it on close.

Blocks (all float64 unless noted):
- command (ROS -> loop, seqlock): count of values, command sequence, arrival time, 7 values;
- control (ROS -> loop, plain): e-stop, shutdown, teaching wanted, request counters;
- state (loop -> ROS, seqlock): one robot sample and the loop's status, see `STATE_LAYOUT`;
- history (loop -> ROS): the last HISTORY robot samples (cycle, stamp, q, dq, tau_J), each entry
  marked by its cycle number before and after it is written, so the ROS side publishes every robot
  state even when its timer runs late (a loaded machine) without the loop ever waiting;
- texts (loop -> ROS, seqlock each, UTF-8 bytes): the loop's status text and the filter's text;
- rings (loop -> bench, plain): per-cycle period, busy time and command latency.
"""

from __future__ import annotations

import mmap
import os
import tempfile
from dataclasses import dataclass

import numpy as np

NUM_JOINTS = 7
MAX_TEXT = 1024
RING = 1 << 16

# Command block payload: [n, cmd_seq, arrived (monotonic s), v0..v6]
CMD_N, CMD_SEQ, CMD_ARRIVED, CMD_VALUES = 0, 1, 2, 3
CMD_SIZE = CMD_VALUES + NUM_JOINTS

# Control block: single values written by the ROS side only.
CONTROL_FIELDS = ("estop", "shutdown", "teaching", "teaching_req", "recover_req", "parent_pid")
CONTROL = {name: i for i, name in enumerate(CONTROL_FIELDS)}

# State block payload layout: (name, length).
STATE_LAYOUT: tuple[tuple[str, int], ...] = (
    ("cycle", 1),            # robot states received by this loop process
    ("robot_time", 1),       # the robot's own clock (s)
    ("stamp", 1),            # wall time (time.time()) when the state arrived
    ("q", NUM_JOINTS),
    ("dq", NUM_JOINTS),
    ("tau_J", NUM_JOINTS),
    ("O_T_EE", 16),          # column-major 4x4, the robot's end-effector pose in its base frame
    ("dq_cmd", NUM_JOINTS),  # the velocity last commanded (after the safety filter)
    ("robot_mode", 1),       # franka RobotMode as an int
    ("success_rate", 1),     # control_command_success_rate (0..1)
    ("status", 1),           # libfranka_loop.LoopStatus
    ("filter_code", 1),      # safety filter code of the last cycle
    ("interventions", 1),    # safety filter interventions in this loop process
    ("last_intervention", 1),
    ("mode", 1),             # libfranka_loop.Mode: idle, velocity, torque (teaching)
    ("estop_active", 1),
    ("cmd_seq", 1),          # command sequence last taken by the loop
    ("latency", 1),          # s from that command's arrival to the first robot command with it
    ("recover_ack", 1),      # recover_req value last handled
    ("recover_ok", 1),
    ("teaching_ack", 1),     # teaching_req value last handled
    ("connects", 1),         # successful connections
    ("errors", 1),           # robot errors seen (reflexes, lost connections)
    ("missed", 1),           # robot cycles missed (sum of Durations minus cycles)
    ("motions", 1),          # motions started
    ("pid", 1),
)
STATE = {}
_offset = 0
for _name, _len in STATE_LAYOUT:
    STATE[_name] = slice(_offset, _offset + _len) if _len > 1 else _offset
    _offset += _len
STATE_SIZE = _offset

RINGS = ("period", "busy", "latency")

# History entries: [cycle, stamp, q(7), dq(7), tau_J(7), cycle again]
HISTORY = 512
H_CYCLE, H_STAMP, H_Q, H_DQ, H_TAU = 0, 1, 2, 2 + NUM_JOINTS, 2 + 2 * NUM_JOINTS
H_END = 2 + 3 * NUM_JOINTS
H_SIZE = H_END + 1

# Float64 area: [cmd seq | cmd payload] [control] [state seq | state payload] [text seqs] [ring idx, rings]
_CMD_AT = 0
_CONTROL_AT = _CMD_AT + 1 + CMD_SIZE
_STATE_AT = _CONTROL_AT + len(CONTROL_FIELDS)
_TEXT_SEQ_AT = _STATE_AT + 1 + STATE_SIZE
_TEXT_LEN_AT = _TEXT_SEQ_AT + 2
_RING_IDX_AT = _TEXT_LEN_AT + 2
_RING_AT = _RING_IDX_AT + 1
_HIST_AT = _RING_AT + len(RINGS) * RING
_N_DOUBLES = _HIST_AT + HISTORY * H_SIZE
_TEXT_BYTES_AT = 8 * _N_DOUBLES
SIZE = _TEXT_BYTES_AT + 2 * MAX_TEXT
TEXTS = ("status", "filter")


def _shm_dir() -> str:
    return "/dev/shm" if os.path.isdir("/dev/shm") else tempfile.gettempdir()


@dataclass
class StateView:
    """A consistent copy of the state block (see `STATE_LAYOUT`); `raw` is the flat array."""

    raw: np.ndarray

    def __getattr__(self, name: str):
        try:
            index = STATE[name]
        except KeyError:
            raise AttributeError(name) from None
        return self.raw[index].copy() if isinstance(index, slice) else float(self.raw[index])


class Slots:
    """The shared blocks over one mmap'ed file. `Slots.create()` on the ROS side, `Slots.attach(path)`
    in the loop process."""

    def __init__(self, path: str, owner: bool):
        self.path = path
        self.owner = owner
        fd = os.open(path, os.O_RDWR)
        try:
            self._mm = mmap.mmap(fd, SIZE)
        finally:
            os.close(fd)
        d = np.frombuffer(self._mm, dtype=np.float64, count=_N_DOUBLES)
        self._d = d
        self._cmd_seq = d[_CMD_AT:_CMD_AT + 1]
        self.cmd = d[_CMD_AT + 1:_CMD_AT + 1 + CMD_SIZE]
        self.control = d[_CONTROL_AT:_CONTROL_AT + len(CONTROL_FIELDS)]
        self._state_seq = d[_STATE_AT:_STATE_AT + 1]
        self.state = d[_STATE_AT + 1:_STATE_AT + 1 + STATE_SIZE]
        self._text_seq = d[_TEXT_SEQ_AT:_TEXT_SEQ_AT + 2]
        self._text_len = d[_TEXT_LEN_AT:_TEXT_LEN_AT + 2]
        self._ring_idx = d[_RING_IDX_AT:_RING_IDX_AT + 1]
        self.rings = {name: d[_RING_AT + i * RING:_RING_AT + (i + 1) * RING] for i, name in enumerate(RINGS)}
        self.history = d[_HIST_AT:_HIST_AT + HISTORY * H_SIZE].reshape(HISTORY, H_SIZE)
        self._text = np.frombuffer(self._mm, dtype=np.uint8, count=2 * MAX_TEXT, offset=_TEXT_BYTES_AT)
        self._cmd_scratch = np.zeros(CMD_SIZE)
        self._state_scratch = np.zeros(STATE_SIZE)

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
        for name in ("_d", "_cmd_seq", "cmd", "control", "_state_seq", "state", "_text_seq", "_text_len",
                     "_ring_idx", "_text", "history"):
            setattr(self, name, None)
        self.rings = {}
        try:
            self._mm.close()
        except BufferError:
            pass  # a StateView still refers to it; the OS frees it with the process
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
        c[CMD_N] = n
        c[CMD_SEQ] += 1.0
        c[CMD_ARRIVED] = arrived
        if n == NUM_JOINTS:
            c[CMD_VALUES:] = values
        seq[0] += 1.0
        return int(c[CMD_SEQ])

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
        """Loop side: open the state block for writing; fill the returned array, then `end_state()`."""
        self._state_seq[0] += 1.0
        return self.state

    def end_state(self) -> None:
        self._state_seq[0] += 1.0

    @property
    def state_seq(self) -> float:
        """Changes with every write of the loop (also status-only ones): its liveness."""
        return float(self._state_seq[0])

    def read_state(self) -> StateView | None:
        """ROS side: a consistent copy of the latest state, or None while the loop is inside a write."""
        out = _read_seqlock(self._state_seq, self.state, self._state_scratch, tries=1000)
        return None if out is None else StateView(out.copy())

    # ------------------------------------------------------------------------------------ history
    def push_history(self, cycle: int, stamp: float, q, dq, tau) -> None:
        """Loop side: one robot sample into its entry (the oldest is overwritten)."""
        e = self.history[cycle % HISTORY]
        e[H_CYCLE] = -1.0                            # being written
        e[H_END] = -1.0
        e[H_STAMP] = stamp
        e[H_Q:H_DQ] = q
        e[H_DQ:H_TAU] = dq
        e[H_TAU:H_END] = tau
        e[H_END] = cycle
        e[H_CYCLE] = cycle

    def read_history(self, cycle: int) -> np.ndarray | None:
        """ROS side: a copy of the sample of robot cycle `cycle`, or None if it has been overwritten
        (or is being written)."""
        e = self.history[cycle % HISTORY]
        if e[H_END] != cycle:
            return None
        out = e.copy()
        return out if out[H_CYCLE] == cycle and e[H_END] == cycle else None

    # -------------------------------------------------------------------------------------- texts
    def write_text(self, which: str, text: str) -> None:
        i = TEXTS.index(which)
        data = text.encode("utf-8", "replace")[:MAX_TEXT]
        seq = self._text_seq
        seq[i] += 1.0
        self._text[i * MAX_TEXT:i * MAX_TEXT + len(data)] = np.frombuffer(data, dtype=np.uint8)
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
                data = self._text[i * MAX_TEXT:i * MAX_TEXT + n].tobytes()
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

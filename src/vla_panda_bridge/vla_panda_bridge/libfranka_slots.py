"""Latest-value slots in shared memory between the ROS node and the 1 kHz libfranka loop process: the
loop's layout of the bridge's one IPC (`shm.py`: seqlocked blocks, flags, texts; the hand's process
has its own layout, `hand_slots.py`).

Blocks (all float64 unless noted):
- command (ROS -> loop, seqlock): count of values, command sequence, arrival time, 7 values;
- control (ROS -> loop, plain): e-stop, shutdown, teaching wanted, request counters;
- state (loop -> ROS, seqlock): one robot sample and the loop's status, see `STATE_DTYPE`;
- history (loop -> ROS): the last HISTORY robot samples (cycle, stamp, q, dq, tau_J), each entry
  marked by its cycle number before and after it is written, so the ROS side publishes every robot
  state even when its timer runs late (a loaded machine) without the loop ever waiting;
- texts (loop -> ROS, seqlock each, UTF-8 bytes): the loop's status text and the filter's text;
- rings (loop -> bench, plain): per-cycle period, busy time and command latency.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vla_panda_bridge.shm import SharedFile, Texts, read_seqlock

NUM_JOINTS = 7
MAX_TEXT = 1024
RING = 1 << 16

_F, _J = np.float64, (NUM_JOINTS,)
HISTORY = 512
RINGS = ("period", "busy", "latency")
TEXTS = ("status", "filter")

# The layout, declared once: NumPy structured dtypes. Every index below is derived from them; the
# loop and the ROS side read and write through flat float64 views with those indices (a structured
# field access costs tens of microseconds per cycle, a flat index well under one).
CMD_DTYPE = np.dtype([("n", _F), ("seq", _F), ("arrived", _F), ("values", _F, _J)])   # ROS -> loop
CONTROL_DTYPE = np.dtype([(name, _F) for name in                                      # ROS -> loop
                          ("estop", "shutdown", "teaching", "teaching_req", "recover_req", "parent_pid")])
STATE_DTYPE = np.dtype([                                                               # loop -> ROS
    ("cycle", _F),            # robot states received by this loop process
    ("robot_time", _F),       # the robot's own clock (s)
    ("stamp", _F),            # wall time (time.time()) when the state arrived
    ("q", _F, _J),
    ("dq", _F, _J),
    ("tau_J", _F, _J),
    ("tau_ext_hat_filtered", _F, _J),   # the robot's estimate of the external torque (Nm), low-passed
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
# A history entry, marked by its cycle number before (`cycle`) and after (`end`) it is written.
HISTORY_DTYPE = np.dtype([("cycle", _F), ("stamp", _F), ("q", _F, _J), ("dq", _F, _J), ("tau_J", _F, _J),
                          ("end", _F)])
LAYOUT = np.dtype([                                        # the whole file, block after block
    ("cmd_seq", _F), ("cmd", CMD_DTYPE),
    ("control", CONTROL_DTYPE),
    ("state_seq", _F), ("state", STATE_DTYPE),
    ("text_seq", _F, (len(TEXTS),)), ("text_len", _F, (len(TEXTS),)),
    ("ring_idx", _F), ("rings", _F, (len(RINGS), RING)),
    ("history", HISTORY_DTYPE, (HISTORY,)),
    ("text", np.uint8, (len(TEXTS), MAX_TEXT)),
])
SIZE = LAYOUT.itemsize


def _index(dtype: np.dtype) -> dict[str, int | slice]:
    """Each field of an all-float64 dtype as an index into a flat float64 view of it."""
    out = {}
    for name, (sub, offset) in dtype.fields.items():
        i, n = offset // 8, sub.itemsize // 8
        out[name] = slice(i, i + n) if sub.shape else i
    return out


def _at(block: str) -> int:
    return LAYOUT.fields[block][1] // 8


_CMD = _index(CMD_DTYPE)
CMD_N, CMD_SEQ, CMD_ARRIVED, CMD_VALUES = _CMD["n"], _CMD["seq"], _CMD["arrived"], _CMD["values"].start
CMD_SIZE = CMD_DTYPE.itemsize // 8
CONTROL_FIELDS = CONTROL_DTYPE.names
CONTROL = _index(CONTROL_DTYPE)
STATE = _index(STATE_DTYPE)
STATE_SIZE = STATE_DTYPE.itemsize // 8
_H = _index(HISTORY_DTYPE)
H_CYCLE, H_STAMP, H_Q, H_DQ, H_TAU, H_END = (_H["cycle"], _H["stamp"], _H["q"].start, _H["dq"].start,
                                             _H["tau_J"].start, _H["end"])
H_SIZE = HISTORY_DTYPE.itemsize // 8
_CMD_AT, _CONTROL_AT, _STATE_AT = _at("cmd_seq"), _at("control"), _at("state_seq")
_TEXT_SEQ_AT, _TEXT_LEN_AT, _RING_IDX_AT = _at("text_seq"), _at("text_len"), _at("ring_idx")
_RING_AT, _HIST_AT = _at("rings"), _at("history")
_N_DOUBLES = _at("text")
_TEXT_BYTES_AT = LAYOUT.fields["text"][1]


@dataclass
class StateView:
    """A consistent copy of the state block: its fields (STATE_DTYPE) as attributes (`s.q`, `s.status`),
    the one way the ROS side reads the loop's state."""

    raw: np.ndarray

    def __getattr__(self, name: str):
        try:
            index = STATE[name]
        except KeyError:
            raise AttributeError(name) from None
        return self.raw[index].copy() if isinstance(index, slice) else float(self.raw[index])


class Slots(SharedFile):
    """The shared blocks over one mmap'ed file. `Slots.create()` on the ROS side, `Slots.attach(path)`
    in the loop process."""

    SIZE = SIZE
    PREFIX = "vla-libfranka-"
    VIEWS = ("_d", "_cmd_seq", "cmd", "control", "_state_seq", "state", "_text_seq", "_text_len",
             "_ring_idx", "_text", "history", "texts")

    def _views(self) -> None:
        d = self.doubles(_N_DOUBLES)
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
        self.texts = Texts(TEXTS, self._text_seq, self._text_len, self._text, MAX_TEXT)
        self._cmd_scratch = np.zeros(CMD_SIZE)
        self._state_scratch = np.zeros(STATE_SIZE)

    def close(self) -> None:
        self.rings = {}
        super().close()

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
        return read_seqlock(self._cmd_seq, self.cmd, self._cmd_scratch, tries=20)

    # -------------------------------------------------------------------------------------- state
    def claim_state_writer(self) -> None:
        """Loop side, at start: a predecessor killed inside a write leaves a counter odd; even it."""
        if int(self._state_seq[0]) % 2:
            self._state_seq[0] += 1.0
        self.texts.even()

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
        out = read_seqlock(self._state_seq, self.state, self._state_scratch, tries=1000)
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
        self.texts.write(which, text)

    def read_text(self, which: str) -> str | None:
        """ROS side: the text, or None while the loop is inside a write."""
        return self.texts.read(which)

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

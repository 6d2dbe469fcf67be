"""The shared-memory slots between the bridge and the libfranka loop: values round-trip, a reader
never sees half a write (also across processes), a dead writer's odd counter is repaired."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest
from vla_panda_bridge.libfranka_slots import (
    CMD_N,
    CMD_SEQ,
    CMD_VALUES,
    H_CYCLE,
    H_Q,
    H_STAMP,
    HISTORY,
    RING,
    STATE,
    Slots,
)


@pytest.fixture
def slots():
    s = Slots.create()
    yield s
    s.close()


def test_commands_round_trip_with_their_count_and_sequence(slots):
    assert slots.write_command([0.1] * 7, 5.0) == 1
    c = slots.read_command()
    assert c[CMD_N] == 7 and c[CMD_SEQ] == 1 and np.allclose(c[CMD_VALUES:], 0.1)
    assert slots.write_command([1.0] * 6, 6.0) == 2          # a wrong length keeps its count only
    c = slots.read_command()
    assert c[CMD_N] == 6 and c[CMD_SEQ] == 2 and np.allclose(c[CMD_VALUES:], 0.1)


def test_the_state_and_texts_round_trip(slots):
    b = slots.begin_state()
    b[STATE["cycle"]] = 3
    b[STATE["q"]] = np.arange(7)
    slots.end_state()
    s = slots.read_state()
    assert s.cycle == 3.0 and np.array_equal(s.q, np.arange(7))
    slots.write_text("status", "réflexe ✓")
    slots.write_text("filter", "x" * 5000)                   # truncated to the slot
    assert slots.read_text("status") == "réflexe ✓"
    assert len(slots.read_text("filter")) == 1024


def test_a_writer_killed_inside_a_write_is_repaired_by_the_next_loop(slots):
    slots.begin_state()                                       # and never end_state()
    slots.write_command([0.0] * 7, 1.0)
    assert slots.read_state() is None                         # busy: the reader does not wait
    slots.claim_state_writer()
    assert slots.read_state().cycle == 0.0


def test_a_command_write_in_progress_is_skipped_not_waited_for(slots):
    slots.write_command([0.1] * 7, 1.0)
    slots._cmd_seq[0] += 1.0                                  # the ROS side preempted mid-write
    assert slots.read_command() is None
    slots._cmd_seq[0] += 1.0
    assert slots.read_command()[CMD_SEQ] == 1


def test_rings_keep_the_newest_entries_oldest_first(slots):
    for k in range(RING + 5):
        slots.ring_push(float(k), 0.0, np.nan)
    r = slots.ring_snapshot()["period"]
    assert len(r) == RING and r[0] == 5.0 and r[-1] == RING + 4.0


def test_attach_refuses_another_layout_and_only_the_owner_unlinks(slots, tmp_path):
    other = tmp_path / "other.shm"
    other.write_bytes(b"\0" * 100)
    with pytest.raises(ValueError, match="another layout"):
        Slots.attach(str(other))
    peer = Slots.attach(slots.path)
    peer.close()
    assert os.path.exists(slots.path)


_WRITER = """
import sys, time
from vla_panda_bridge.libfranka_slots import Slots, STATE
s = Slots.attach(sys.argv[1])
for k in range(1, 5001):
    t = time.perf_counter() + 50e-6                         # a write every 50 us (the loop: every 1 ms)
    while time.perf_counter() < t:
        pass
    b = s.begin_state()
    b[STATE["cycle"]] = k
    b[STATE["q"]] = k
    b[STATE["dq"]] = -k
    s.end_state()
s.close()
"""


def test_a_reader_never_sees_half_a_state_written_by_another_process(slots):
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, slots.path])
    seen = set()
    try:
        while proc.poll() is None or not seen:
            s = slots.read_state()
            if s is None:
                continue                                      # caught inside a write: try again
            k = s.cycle
            assert np.all(s.q == k) and np.all(s.dq == -k), (k, s.q, s.dq)
            seen.add(k)
            time.sleep(0)
    finally:
        proc.wait(30)
    assert proc.returncode == 0
    assert len(seen) > 10                                     # it read while the other wrote


def test_the_history_holds_every_recent_state_and_refuses_overwritten_ones(slots):
    for k in range(1, HISTORY + 11):
        slots.push_history(k, 1000.0 + k, [k] * 7, [-k] * 7, [0.5] * 7)
    e = slots.read_history(HISTORY + 10)
    assert e[H_CYCLE] == HISTORY + 10 and e[H_STAMP] == 1000.0 + HISTORY + 10
    assert np.all(e[H_Q:H_Q + 7] == HISTORY + 10)
    assert slots.read_history(10) is None                    # overwritten by cycle HISTORY + 10
    assert slots.read_history(11) is not None


def test_new_samples_gives_every_robot_state_once_on_the_decimation_grid():
    from vla_panda_bridge.libfranka_loop import LoopSettings
    from vla_panda_bridge.libfranka_process import LoopProcess

    p = LoopProcess(LoopSettings(robot={"robot_ip": "192.0.2.1"}))    # not started: its slots only
    try:
        def publish(upto):
            for k in range(publish.last + 1, upto + 1):
                p.slots.push_history(k, 2000.0 + k * 0.001, [k] * 7, [0.0] * 7, [0.0] * 7)
            b = p.slots.begin_state()
            b[STATE["cycle"]], b[STATE["pid"]] = upto, 1
            p.slots.end_state()
            publish.last = upto
        publish.last = 0
        publish(7)
        assert [s.cycle for s in p.new_samples()] == list(range(1, 8))
        assert p.new_samples() == []                          # nothing new: nothing (the robot is silent)
        publish(20)
        assert [s.cycle for s in p.new_samples(every=5)] == [10, 15, 20]
        publish(HISTORY * 3)                                  # far behind: the newest HISTORY states
        cycles = [s.cycle for s in p.new_samples()]
        assert cycles == list(range(HISTORY * 2 + 1, HISTORY * 3 + 1))
        assert p.new_samples() == []
    finally:
        p.slots.close()

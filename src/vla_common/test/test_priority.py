"""Background priority: only the calling thread is lowered, and what it starts inherits it."""
import os
import sys
import threading

import pytest
from vla_common.priority import BACKGROUND_NICE, MAX_NICE, run_in_background, thread_nice

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread nice is Linux's")


def in_thread(fn):
    out = {}
    t = threading.Thread(target=lambda: out.update(value=fn()))
    t.start()
    t.join()
    return out["value"]


def test_only_the_calling_thread_is_lowered_and_its_children_inherit():
    here = thread_nice()

    def lowered():
        before = thread_nice()
        assert run_in_background() is None
        return before, thread_nice(), in_thread(thread_nice)

    before, after, child = in_thread(lowered)
    assert before == here
    assert after == min(MAX_NICE, here + BACKGROUND_NICE)
    assert child == after                       # a thread it starts (ONNX Runtime's pool) inherits it
    assert thread_nice() == here                # this thread, and the process, are untouched
    assert os.getpriority(os.PRIO_PROCESS, os.getpid()) == here


def test_the_nice_value_is_capped():
    def twice():
        run_in_background(15)
        run_in_background(15)
        return thread_nice()
    assert in_thread(twice) == MAX_NICE


def test_the_whole_process_is_lowered_on_request():
    """Run in a child process: this one's priority is not ours to lower."""
    import subprocess
    code = ("import threading, time\n"
            "from vla_common.priority import run_in_background, thread_nice\n"
            "ev = threading.Event(); seen = []\n"
            "t = threading.Thread(target=lambda: (ev.wait(), seen.append(thread_nice()))); t.start()\n"
            "run_in_background(process=True); ev.set(); t.join()\n"
            "print(thread_nice(), seen[0])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    lowered = min(MAX_NICE, thread_nice() + BACKGROUND_NICE)
    assert out.split() == [str(lowered), str(lowered)]   # the main thread and one started before


def _can_run_realtime() -> bool:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except OSError:
        return False
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    return True


REALTIME = ("import os, threading\n"
            "try:\n    os.setpriority(os.PRIO_PROCESS, 0, 0)   # a niced pytest: the node at nice 0\n"
            "except OSError:\n    pass\n"
            "from vla_common.priority import run_in_background, run_realtime, thread_policy\n"
            "go, bg_ready, seen = threading.Event(), threading.Event(), {}\n"
            "def bulk():\n"
            "    run_in_background(); bg_ready.set(); go.wait(); seen['bulk'] = thread_policy()\n"
            "def waiter():\n"
            "    go.wait(); seen['waiter'] = thread_policy()\n"
            "    t = threading.Thread(target=lambda: seen.update(later=thread_policy()))\n"
            "    t.start(); t.join()\n"
            "b = threading.Thread(target=bulk); w = threading.Thread(target=waiter); b.start(); w.start()\n"
            "bg_ready.wait()\n"
            "print(run_realtime({prio}))\n"
            "go.set(); b.join(); w.join()\n"
            "print(thread_policy(), seen['waiter'], seen['bulk'], seen['later'])\n")


def _child(code: str) -> list[str]:
    import subprocess
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True).stdout.splitlines()


def test_realtime_puts_the_threads_but_the_background_ones_at_fifo_and_nothing_inherits_it():
    """Run in a child process. The main thread and a thread started before are SCHED_FIFO; a background
    thread (nice raised) stays normal; a thread started afterwards by a real-time one starts normal
    (SCHED_RESET_ON_FORK). Where the machine does not allow it, the reason is given and nothing changes."""
    allowed = _can_run_realtime()
    out = _child(REALTIME.replace("{prio}", "10"))
    fifo, other = str(os.SCHED_FIFO), str(os.SCHED_OTHER)
    if allowed:
        assert out == ["None", f"{fifo} {fifo} {other} {other}"]
    else:
        assert out[1] == " ".join([other] * 4)     # and why, unless this test runs niced
        assert "SCHED_FIFO 10 was refused" in out[0] or os.getpriority(os.PRIO_PROCESS, 0) > 0
    out = _child(REALTIME.replace("{prio}", "0"))
    assert out == ["None", " ".join([other] * 4)]    # 0: normal scheduling


def test_a_background_thread_started_by_a_realtime_one_is_normal():
    if not _can_run_realtime():
        pytest.skip("SCHED_FIFO is not allowed here")   # the refusal is checked above
    def inherited_then_lowered():
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))   # inherited, without the reset flag
        run_in_background()
        return os.sched_getscheduler(0)
    assert in_thread(inherited_then_lowered) == os.SCHED_OTHER


def test_a_niced_process_is_left_at_normal_priority():
    """An evaluation or batch run started with `nice` asked to yield: it never becomes real time."""
    import subprocess
    code = ("from vla_common.priority import run_realtime, thread_policy\n"
            "print(run_realtime(10), thread_policy())")
    out = subprocess.run(["nice", "-n", "5", sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["None", str(os.SCHED_OTHER)]

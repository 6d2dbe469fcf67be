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

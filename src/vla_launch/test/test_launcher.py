"""`vla launch` process supervision with plain processes (fast): output, exit codes, teardown."""
import contextlib
import io
import os
import re
import signal
import sys
import textwrap
import threading
import time

import pytest


class Screen(io.StringIO):
    """A launcher's screen (everything its processes print) that knows when proc.py said it is ready."""

    def __init__(self) -> None:
        super().__init__()
        self.ready = threading.Event()

    def write(self, text: str) -> int:
        if "ready" in text:
            self.ready.set()
        return super().write(text)


def launch_file(tmp_path, fixtures_dir, *procs, extra=""):
    """A launch file of `executable` actions running fixtures/proc.py with the given arguments."""
    script = os.path.join(fixtures_dir, "proc.py")
    body = "".join(
        f"  - executable:\n      name: {name}\n      cmd: \"{sys.executable} {script} {args}\"\n{attrs}"
        for name, args, attrs in procs)
    path = tmp_path / "t.launch.yaml"
    path.write_text("launch:\n" + body + textwrap.dedent(extra))
    return str(path)


def proc(name, args, **attrs):
    """An executable action; a str attribute is written quoted, anything else as a YAML value."""
    return name, args, "".join(f"      {k}: {f'{chr(34)}{v}{chr(34)}' if isinstance(v, str) else v}\n"
                               for k, v in attrs.items())


def test_output_goes_to_stdout_tagged_exec_n_and_partial_lines_flushed(tmp_path, fixtures_dir, launch):
    """As ros2 launch: both streams of a child on stdout, tagged `[<name>-<n>]`, n counting starts."""
    f = launch_file(tmp_path, fixtures_dir,
                    proc("a", "--out 'hello out' --err 'hello err' --partial tail --exit-after 0.2"),
                    proc("b", "--out 'b out' --exit-after 0.2"))
    run = launch(f)
    assert run.finish() == 0
    out = run.text("out")
    assert "[a-1] hello out" in out and "[a-1] tail" in out and "[a-1] hello err" in out, out
    assert "[b-2] b out" in out
    assert "[INFO] [a-1]: process started with pid [" in out
    assert re.search(r"\[INFO\] \[a-1\]: process has finished cleanly \[pid \d+\]", out)
    assert run.text("err") == ""


def test_sigint_tears_every_child_down(tmp_path, fixtures_dir, launch):
    f = launch_file(tmp_path, fixtures_dir, proc("a", "--grandchild"), proc("b", ""))
    run = launch(f)
    run.wait_for(r"ready \d+", count=2)
    grandchild = int(run.wait_for(r"grandchild (\d+)")[0].group(1))
    pids = run.child_pids()
    assert len(pids) == 2 and all(launch.alive(p) for p in pids + [grandchild])
    run.send(signal.SIGINT)
    assert run.finish() == 0, run.text()
    # the grandchild ignores SIGINT/SIGTERM; the final sweep of the children's groups kills it
    assert launch.wait_dead(pids + [grandchild], 2.0) == []
    assert "[WARNING] [launch]: user interrupted with ctrl-c (SIGINT)" in run.text()
    for tag in ("a-1", "b-2"):  # as launch 3.4 words it (a death by a signal: a negative exit code)
        assert f"[INFO] [{tag}]: sending signal 'SIGINT' to process[{tag}]" in run.text()
        assert re.search(rf"\[ERROR\] \[{tag}\]: process has died \[pid \d+, exit code -2, cmd '.*'\]\.",
                         run.text()), run.text()


def test_abort_on_exit_tears_the_rest_down_and_sets_the_exit_code(tmp_path, fixtures_dir, launch):
    f = launch_file(tmp_path, fixtures_dir, proc("ok", ""), proc("bad", "--exit-after 0.3 --code 3"))
    run = launch("--abort-on-exit", f)
    assert run.finish() == 3, run.text()
    assert launch.wait_dead(run.child_pids(), 1.0) == []
    assert re.search(r"\[bad-2\]: process has died \[pid \d+, exit code 3, cmd", run.text())
    assert "process[bad-2] has died: shutting down launched system" in run.text()


def test_a_crash_leaves_the_others_running_and_the_exit_code_0(tmp_path, fixtures_dir, launch):
    """ros2 launch's default: a process dying is reported; the others run on; rc 0 at the end."""
    f = launch_file(tmp_path, fixtures_dir, proc("bad", "--exit-after 0.1 --code 4"),
                    proc("slow", "--exit-after 0.8"))
    run = launch(f)
    assert run.finish() == 0, run.text()
    died = r"\[ERROR\] \[bad-1\]: process has died \[pid \d+, exit code 4, cmd '\S+python\S* \S+proc.py "
    assert re.search(died + r"--exit-after 0.1 --code 4'\]\.$", run.text(), re.M), run.text()
    assert "[INFO] [slow-2]: process has finished cleanly [pid" in run.text()  # slow was not torn down


def test_a_clean_exit_leaves_the_others_running(tmp_path, fixtures_dir, launch):
    f = launch_file(tmp_path, fixtures_dir, proc("quick", "--exit-after 0.1"),
                    proc("slow", "--exit-after 0.8"))
    run = launch(f)
    assert run.finish() == 0
    assert run.text().count("has finished cleanly") == 2


def test_on_exit_shutdown(tmp_path, fixtures_dir, launch):
    f = launch_file(tmp_path, fixtures_dir, proc("main", "--exit-after 0.3", on_exit="shutdown"),
                    proc("other", ""))
    run = launch(f)
    assert run.finish() == 0
    assert "[INFO] [launch]: process[main-1] was required: shutting down launched system" in run.text()


def test_stubborn_process_is_escalated_to_sigkill_and_reported(tmp_path, fixtures_dir, launch):
    f = launch_file(tmp_path, fixtures_dir, proc("stubborn", "--ignore INT --ignore TERM"))
    run = launch("--sigterm-timeout", "0.3", "--sigkill-timeout", "0.3", f)
    run.wait_for(r"ready \d+")
    run.send(signal.SIGINT)
    assert run.finish() == 128 + signal.SIGKILL
    assert ("[ERROR] [stubborn-1]: process[stubborn-1] failed to terminate '0.3' seconds after receiving "
            "'SIGINT', escalating to 'SIGTERM'") in run.text()
    assert ("process[stubborn-1] failed to terminate '0.6' seconds after receiving 'SIGTERM', escalating to "
            "'SIGKILL'") in run.text()
    assert "sending signal 'SIGKILL' to process[stubborn-1]" in run.text()
    assert launch.wait_dead(run.child_pids(), 1.0) == []


def test_sigterm_to_launch_is_forwarded(tmp_path, fixtures_dir, launch):
    run = launch(launch_file(tmp_path, fixtures_dir, proc("a", "")))
    run.wait_for(r"ready \d+")
    run.send(signal.SIGTERM)
    assert run.finish() == 0
    assert "[WARNING] [launch]: user interrupted with SIGTERM" in run.text()
    assert "sending signal 'SIGTERM' to process[a-1]" in run.text() and "exit code -15" in run.text()


def test_children_die_when_launch_is_killed(tmp_path, fixtures_dir, launch):
    """PR_SET_PDEATHSIG: even a SIGKILLed `vla launch` leaves no orphans behind."""
    run = launch(launch_file(tmp_path, fixtures_dir, proc("a", ""), proc("b", "")))
    run.wait_for(r"ready \d+", count=2)
    pids = run.child_pids()
    run.send(signal.SIGKILL)
    run.finish()
    assert launch.wait_dead(pids, 5.0) == []


def _ignores_sigterm(pid: int) -> bool:
    """From the kernel's record of the process (SigIgn mask), not from how long it lives."""
    with open(f"/proc/{pid}/status") as f:
        mask = next(int(line.split()[1], 16) for line in f if line.startswith("SigIgn:"))
    return bool(mask >> (signal.SIGTERM - 1) & 1)


def test_a_child_that_ignores_its_parent_death_signal_is_reaped(tmp_path, fixtures_dir, launch):
    """The launch is SIGKILLed and its child ignores the SIGTERM of PR_SET_PDEATHSIG (as a node stuck
    in its DDS teardown does): the reaper SIGKILLs it `sigkill_timeout` later, with its grandchild."""
    run = launch("--sigkill-timeout", "2",
                 launch_file(tmp_path, fixtures_dir, proc("stuck", "--ignore TERM --grandchild")))
    run.wait_for(r"ready \d+")
    grandchild = int(run.wait_for(r"grandchild (\d+)")[0].group(1))
    pids = run.child_pids()
    assert all(_ignores_sigterm(p) for p in pids + [grandchild])  # PR_SET_PDEATHSIG cannot stop them
    run.send(signal.SIGKILL)
    run.proc.wait()
    assert launch.wait_dead(pids + [grandchild], 6.0) == []
    run.finish()  # the reaper held the launch's stderr; it has said what it did
    assert "SIGKILLed [" in run.text("err")


def test_shutdown_signals_every_process_at_once(tmp_path, fixtures_dir, launch):
    """Each process takes 3 s to stop after its SIGINT: all three have it before the first has
    stopped (one at a time, the second would get it only once the first had ended)."""
    f = launch_file(tmp_path, fixtures_dir, *(proc(n, "--hold-on-int 3") for n in ("a", "b", "c")))
    run = launch(f)
    run.wait_for(r"ready \d+", count=3)
    run.send(signal.SIGINT)
    assert run.finish() == 0, run.text()
    lines = run.text().splitlines()
    first_stop = next(i for i, t in enumerate(lines) if re.search(r"\[\w-\d\]: process has", t))
    assert sum("got INT" in t for t in lines[:first_stop]) == 3, run.text()
    assert run.text().count("process has finished cleanly") == 3


def test_a_stuck_process_is_escalated_without_holding_the_others(tmp_path, fixtures_dir, launch):
    f = launch_file(tmp_path, fixtures_dir, proc("first", ""), proc("stuck", "--ignore INT"))
    run = launch("--sigterm-timeout", "30", f)
    run.wait_for(r"ready \d+", count=2)
    run.send(signal.SIGINT)
    run.wait_for(r"\[first-1\]: process has", timeout=25)  # not after stuck's SIGTERM at 30 s
    assert "SIGTERM" not in run.text()
    for _ in range(20):  # a second Ctrl-C (1 s or more after the first) escalates stuck at once
        run.send(signal.SIGINT)
        with contextlib.suppress(AssertionError):
            run.wait_for("sending signal 'SIGTERM'", timeout=1.5)
            break
    assert run.finish() == 0, run.text()
    assert "user interrupted with ctrl-c (SIGINT) again: escalating" in run.text()
    assert re.search(r"\[stuck-2\]: process has died \[pid \d+, exit code -15", run.text())


def test_respawn_keeps_the_process_label(tmp_path, fixtures_dir, launch):
    """As ros2 launch: a respawned process keeps its `[flaky-1]`; the next process is `-2`. (The labels
    were `[flaky-3]`, `[flaky-4]`, ... one per start.)"""
    f = launch_file(tmp_path, fixtures_dir, proc("flaky", "--out hi --exit-after 0.1 --code 1",
                                                 respawn="true", respawn_delay=0.1), proc("other", ""))
    run = launch(f)
    run.wait_for(r"\[flaky-1\] hi", count=3)  # its third start's output
    run.send(signal.SIGINT)
    assert run.finish() == 0  # respawned crashes are not failures; the stop was clean
    assert run.text().count("[INFO] [flaky-1]: process started with pid") >= 3
    assert "[INFO] [other-2]: process started" in run.text()
    assert not re.search(r"\[(flaky|other)-[3-9]\]", run.text()), run.text()


def test_start_failure_and_launch_errors(tmp_path, launch):
    bad = tmp_path / "bad.launch.yaml"
    bad.write_text("launch:\n  - executable: {cmd: /no/such/program}\n")
    run = launch(str(bad))
    assert run.finish() == 127 and ("[ERROR] [program-1]: exception occurred while executing process: "
                                    "[Errno 2] No such file or directory: '/no/such/program'") in run.text()
    bad.write_text("launch:\n  - node: {pkg: vla_launch, exec: nope}\n")
    run = launch(str(bad))
    assert run.finish() == 1 and "vla_launch nope: No executable found" in run.text()
    run = launch(str(bad), "oops")
    assert run.finish() == 1 and "name:=value" in run.text()


@pytest.mark.parametrize("args,expected", [
    (["--dry-run", "vla_bringup", "sim.launch.yaml", "real_time_factor:=2.0"], "-p real_time_factor:=2.0"),
    (["vla_bringup", "teleop.launch.yaml", "--show-args"], "'use_joy':"),
    (["vla_bringup", "no.launch.yaml"], "file 'no.launch.yaml' was not found in the share directory"),
    (["no_such_pkg", "x.launch.yaml"], "Package 'no_such_pkg' not found"),
])
def test_package_mode_and_inspection(launch, args, expected):
    run = launch(*args)
    run.finish()
    assert expected in run.text()


def test_launcher_api_from_a_thread(fixtures_dir):
    """Programmatic use (e.g. an evaluation harness): run() in a thread, stop() from another."""
    from vla_launch.launcher import Launcher, ProcessSpec

    out, err = Screen(), io.StringIO()
    script = os.path.join(fixtures_dir, "proc.py")
    launcher = Launcher([ProcessSpec("a", [sys.executable, script, "--out", "hi"])], stdout=out, stderr=err)
    result = {}
    t = threading.Thread(target=lambda: result.setdefault("rc", launcher.run()))
    t.start()
    assert out.ready.wait(20), out.getvalue()
    launcher.stop()
    t.join(20)
    assert result == {"rc": 0}
    assert "[a-1] hi" in out.getvalue() and err.getvalue() == ""
    assert launcher.tags == {launcher.all_pids[0]: "a-1"}


def test_children_hear_the_stop_when_the_caller_ignores_sigint(fixtures_dir):
    """A harness that runs the launcher from a thread of a process ignoring SIGINT (a `&` job of a
    script, `nohup`) still stops its children with SIGINT: they must not inherit SIG_IGN, which would
    cost every stop the SIGTERM grace (and a child's own shutdown on SIGINT)."""

    from vla_launch.launcher import Launcher, ProcessSpec

    script = os.path.join(fixtures_dir, "proc.py")
    out = Screen()
    launcher = Launcher([ProcessSpec("a", [sys.executable, script], sigterm_timeout=60.0)], stdout=out)
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        t = threading.Thread(target=launcher.run)
        t.start()
        started = time.monotonic()
        while not launcher.all_pids and time.monotonic() - started < 20:
            time.sleep(0.01)
    finally:
        signal.signal(signal.SIGINT, before)
    pid = launcher.all_pids[0]
    with open(f"/proc/{pid}/status") as f:   # the child's ignored-signal mask, before it runs Python
        ignored = int(next(x for x in f if x.startswith("SigIgn:")).split()[1], 16)
    # stopped once it runs proc.py: a SIGINT while Python still starts ends it with 1, not by the signal
    # (CI: "init_import_site: Failed to import the site module ... KeyboardInterrupt")
    assert out.ready.wait(20), out.getvalue()
    launcher.stop()
    t.join(60)
    assert not ignored & (1 << (signal.SIGINT - 1)), "the child inherited SIGINT ignored"
    assert launcher.ended == [("a", -signal.SIGINT)]

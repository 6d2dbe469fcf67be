"""`vla launch` process supervision with plain processes (fast): output, exit codes, teardown."""
import os
import re
import signal
import sys
import textwrap
import time

import pytest


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
    return name, args, "".join(f"      {k}: \"{v}\"\n" for k, v in attrs.items())


def test_output_is_prefixed_per_stream_and_partial_lines_flushed(tmp_path, fixtures_dir, launch):
    f = launch_file(tmp_path, fixtures_dir,
                    proc("a", "--out 'hello out' --err 'hello err' --partial tail --exit-after 0.2"))
    run = launch(f)
    assert run.finish() == 0
    (pid,) = run.child_pids()
    assert f"[a-{pid}] hello out" in run.text("out")
    assert f"[a-{pid}] tail" in run.text("out")
    assert f"[a-{pid}] hello err" in run.text("err")
    assert "hello err" not in run.text("out")
    assert "has finished cleanly" in run.text("err")


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
    assert run.text().count("stopped (killed by SIGINT)") == 2


def test_a_crash_tears_the_rest_down_and_sets_the_exit_code(tmp_path, fixtures_dir, launch):
    f = launch_file(tmp_path, fixtures_dir, proc("ok", ""), proc("bad", "--exit-after 0.3 --code 3"))
    run = launch(f)
    assert run.finish() == 3, run.text()
    assert launch.wait_dead(run.child_pids(), 1.0) == []
    assert "has died (exit code 3)" in run.text()
    assert "shutting down (bad died)" in run.text()


def test_keep_going(tmp_path, fixtures_dir, launch):
    f = launch_file(tmp_path, fixtures_dir, proc("bad", "--exit-after 0.1 --code 4"),
                    proc("slow", "--exit-after 0.8"))
    run = launch("--keep-going", f)
    assert run.finish() == 4
    assert "[slow-" in run.text() and "has finished cleanly" in run.text()  # slow was not torn down


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
    assert "has on_exit: shutdown" in run.text()


def test_stubborn_process_is_escalated_to_sigkill_and_reported(tmp_path, fixtures_dir, launch):
    f = launch_file(tmp_path, fixtures_dir, proc("stubborn", "--ignore INT --ignore TERM"))
    run = launch("--sigterm-timeout", "0.3", "--sigkill-timeout", "0.3", f)
    run.wait_for(r"ready \d+")
    run.send(signal.SIGINT)
    assert run.finish() == 128 + signal.SIGKILL
    assert "sending SIGTERM" in run.text() and "sending SIGKILL" in run.text()
    assert launch.wait_dead(run.child_pids(), 1.0) == []


def test_sigterm_to_launch_is_forwarded(tmp_path, fixtures_dir, launch):
    run = launch(launch_file(tmp_path, fixtures_dir, proc("a", "")))
    run.wait_for(r"ready \d+")
    run.send(signal.SIGTERM)
    assert run.finish() == 0
    assert "stopped (killed by SIGTERM)" in run.text()


def test_children_die_when_launch_is_killed(tmp_path, fixtures_dir, launch):
    """PR_SET_PDEATHSIG: even a SIGKILLed `vla launch` leaves no orphans behind."""
    run = launch(launch_file(tmp_path, fixtures_dir, proc("a", ""), proc("b", "")))
    run.wait_for(r"ready \d+", count=2)
    pids = run.child_pids()
    run.send(signal.SIGKILL)
    run.finish()
    assert launch.wait_dead(pids, 5.0) == []


def test_a_child_that_ignores_its_parent_death_signal_is_reaped(tmp_path, fixtures_dir, launch):
    """The launch is SIGKILLed and its child ignores the SIGTERM of PR_SET_PDEATHSIG (as a node stuck
    in its DDS teardown does): the reaper SIGKILLs it `sigkill_timeout` later, with its grandchild."""
    run = launch("--sigkill-timeout", "2",
                 launch_file(tmp_path, fixtures_dir, proc("stuck", "--ignore TERM --grandchild")))
    run.wait_for(r"ready \d+")
    grandchild = int(run.wait_for(r"grandchild (\d+)")[0].group(1))
    pids = run.child_pids()
    run.send(signal.SIGKILL)
    run.proc.wait()
    time.sleep(0.5)
    assert all(launch.alive(p) for p in pids + [grandchild])  # SIGTERM ignored: only the reaper helps
    assert launch.wait_dead(pids + [grandchild], 6.0) == []
    run.finish()  # the reaper held the launch's stderr; it has said what it did
    assert "SIGKILLed [" in run.text("err")


def test_shutdown_goes_one_process_at_a_time_in_reverse_start_order(tmp_path, fixtures_dir, launch):
    f = launch_file(tmp_path, fixtures_dir, proc("first", ""), proc("second", ""), proc("third", ""))
    run = launch(f)
    run.wait_for(r"ready \d+", count=3)
    run.send(signal.SIGINT)
    assert run.finish() == 0, run.text()
    rx = re.compile(r"process \[(\w+)-\d+\] stopped")
    stopped = [m.group(1) for _, line in run.lines if (m := rx.search(line))]
    assert stopped == ["third", "second", "first"], run.text()


def test_a_stuck_process_delays_the_next_one_by_the_stagger_only(tmp_path, fixtures_dir, launch):
    f = launch_file(tmp_path, fixtures_dir, proc("first", ""), proc("stuck", "--ignore INT"))
    run = launch("--sigterm-timeout", "3", f)
    run.wait_for(r"ready \d+", count=2)
    t0 = time.monotonic()
    run.send(signal.SIGINT)
    run.wait_for(r"process \[first-\d+\] stopped")
    assert time.monotonic() - t0 < 2.9  # signalled 1 s (the stagger) after `stuck`, not after its SIGTERM
    assert run.finish() == 0, run.text()  # `stuck` stopped by the SIGTERM at 3 s


def test_respawn(tmp_path, fixtures_dir, launch):
    f = launch_file(tmp_path, fixtures_dir, proc("flaky", "--exit-after 0.1 --code 1", respawn="true",
                                                 respawn_delay="0.1"))
    run = launch(f)
    run.wait_for(r"process started with pid", count=3)
    run.send(signal.SIGINT)
    assert run.finish() == 0  # respawned crashes are not failures; the stop was clean
    assert "respawning" in run.text()


def test_start_failure_and_launch_errors(tmp_path, launch):
    bad = tmp_path / "bad.launch.yaml"
    bad.write_text("launch:\n  - executable: {cmd: /no/such/program}\n")
    run = launch(str(bad))
    assert run.finish() == 127 and "cannot start /no/such/program" in run.text()
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
    import io
    import threading
    import time

    from vla_launch.launcher import Launcher, ProcessSpec

    out, err = io.StringIO(), io.StringIO()
    script = os.path.join(fixtures_dir, "proc.py")
    launcher = Launcher([ProcessSpec("a", [sys.executable, script, "--out", "hi"])], stdout=out, stderr=err)
    result = {}
    t = threading.Thread(target=lambda: result.setdefault("rc", launcher.run()))
    t.start()
    deadline = time.monotonic() + 20
    while "ready" not in err.getvalue() and time.monotonic() < deadline:
        time.sleep(0.02)
    launcher.stop()
    t.join(20)
    assert result == {"rc": 0}
    assert f"[a-{launcher.all_pids[0]}] hi" in out.getvalue()

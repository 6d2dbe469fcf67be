"""LaunchSession: a launch file's processes from Python, as `vla launch` starts them."""
import os
import signal
import sys
import time

import pytest
from vla_launch.session import LaunchError, LaunchSession, argument_text


def _file(tmp_path, fixtures_dir, *procs):
    script = os.path.join(fixtures_dir, "proc.py")
    body = "".join(f"  - executable:\n      name: {name}\n      cmd: \"{sys.executable} {script} {args}\"\n"
                   for name, args in procs)
    path = tmp_path / "s.launch.yaml"
    path.write_text("launch:\n  - arg: {name: word, default: hello}\n" + body)
    return str(path)


def _wait(predicate, timeout=20.0):
    deadline = time.monotonic() + timeout
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.05)
    return predicate()


def test_arguments_are_written_as_launch_text():
    assert [argument_text(v) for v in (True, False, 2.0, 3, "x")] == ["true", "false", "2.0", "3", "x"]


def test_a_session_runs_logs_and_stops_cleanly(tmp_path, fixtures_dir):
    log = tmp_path / "logs" / "launch.log"
    f = _file(tmp_path, fixtures_dir, ("a", "--out $(var word)"), ("b", ""))
    with LaunchSession(None, f, {"word": "bonjour"}, env={"VLA_TEST_X": "1"}, log_path=log) as s:
        assert _wait(lambda: s.tail().count("ready") == 2), s.tail()
        s.check()  # both running
        assert set(s.pids) == {"a", "b"}
        assert "[a-1] bonjour" in s.tail("a") and s.output("a") == ["bonjour", f"ready {s.pids['a']}"]
    assert s.stop() == 0
    assert "[INFO] [a-1]: sending signal 'SIGINT' to process[a-1]" in log.read_text()
    assert not os.path.exists(s._tmpdir)  # its temporary parameter files are gone, the log is kept


def test_check_names_the_process_that_ended_with_its_output(tmp_path, fixtures_dir):
    f = _file(tmp_path, fixtures_dir, ("ok", ""), ("bad", "--err 'bad news' --exit-after 0.2 --code 3"))
    s = LaunchSession(None, f, log_path=tmp_path / "launch.log").start()
    try:
        assert _wait(lambda: bool(s.ended()))
        with pytest.raises(LaunchError, match=r"bad ended \(exit code 3\)(.|\n)*bad news"):
            s.check()
    finally:
        assert s.stop() == 3  # the launch's exit code: the first failure's


def test_given_processes_with_their_own_environments_keep_going_past_a_failure(tmp_path, fixtures_dir):
    """of_processes: commands as given (a prefix such as `ip netns exec` is part of cmd), each spec's
    env over the session's; with keep_going one process failing leaves the others running."""
    from vla_launch.launcher import ProcessSpec

    script = os.path.join(fixtures_dir, "proc.py")
    show = [sys.executable, "-c", "import os; print(os.environ['VLA_SIDE'], os.environ.get('VLA_BASE'))"]
    specs = [ProcessSpec("robot", show, env={"VLA_SIDE": "robot"}),
             ProcessSpec("vision", show, env={"VLA_SIDE": "vision", "VLA_BASE": None}),
             ProcessSpec("bad", [sys.executable, script, "--exit-after", "0.2", "--code", "3"]),
             # a generous SIGINT grace: at load ~80 a process waited past the default for the CPU
             # and got the launcher's SIGTERM (what is tested here is that the stop is a SIGINT)
             ProcessSpec("long", [sys.executable, script], sigterm_timeout=120.0)]
    s = LaunchSession.of_processes(specs, env={"VLA_BASE": "base"}, log_path=tmp_path / "p.log",
                                   keep_going=True)
    with s:
        assert s.wait("robot", 20) == 0 and s.wait("vision", 20) == 0 and s.wait("bad", 20) == 3
        assert s.output("robot") == ["robot base"] and s.output("vision") == ["vision None"]
        assert s.alive("long") and not s.alive("bad")
        assert "--- bad (exit code 3)" in s.describe() and "--- long (running)" in s.describe()
        s.stop(timeout=150.0)   # longer than the grace above (the default 60 s cut it short at load ~10)
    assert s.exit_codes()["long"] == -signal.SIGINT and not s.alive("long")  # stopped by our SIGINT

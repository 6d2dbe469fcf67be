"""run_node: signals stop the spin, on_shutdown runs while the context lives, exit codes, bounded shutdown."""
import subprocess
import sys
import textwrap
import time

import pytest

NODE = textwrap.dedent('''
    import sys, time
    from rclpy.node import Node
    from vla_common.ros.node_main import SHUTDOWN_GRACE_S, ConfigError, run_node

    class N(Node):
        def __init__(self):
            super().__init__("n")
            if "slow_exit" in sys.argv:  # Python's finalization would never end
                import atexit
                atexit.register(time.sleep, 600)
            if "config" in sys.argv:
                raise ConfigError("parameter 'x' refused")
            if "slow" in sys.argv:
                self.shutdown_timeout_s = 4 * SHUTDOWN_GRACE_S
            self.create_timer(0.05, lambda: None)
            print("ready", flush=True)
        def on_shutdown(self):
            print("zero sent", time.monotonic(), flush=True)  # CLOCK_MONOTONIC: the test's clock too
            if "hang" in sys.argv:
                time.sleep(60)      # a teardown that never returns
            if "slow" in sys.argv:  # work that takes longer than the teardown's own bound (a bag to close)
                time.sleep(SHUTDOWN_GRACE_S + 1.0)
                print("closed", flush=True)
        def destroy_node(self):
            if "stuck_teardown" in sys.argv:  # as Fast DDS busy-waiting in C, the GIL held
                import ctypes
                ctypes.PyDLL(None).sleep(600)
            super().destroy_node()

    sys.exit(run_node(N, "n", ["--ros-args", "-p", "use_sim_time:=true"]))
''')


def start(*args):
    p = subprocess.Popen([sys.executable, "-c", NODE, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)
    assert p.stdout.readline().strip() in ("ready", ""), p.stderr.read()
    return p


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_a_signal_stops_the_node_on_sim_time_and_sends_zero(sig):
    import signal
    p = start()
    t0 = time.monotonic()
    p.send_signal(getattr(signal, sig))
    out, err = p.communicate(timeout=10)
    assert p.returncode == 0 and "zero sent" in out and "Traceback" not in err, err
    # Exit code 0 also says the teardown ended within SHUTDOWN_GRACE_S on the node's own watchdog
    # (which would exit 1). What run_node controls is how soon the signal is seen: the node's
    # on_shutdown stamps that on the shared monotonic clock. Measured: 0.100 s median and max (one
    # SPIN_SLICE_S, as a clock that never advances leaves it) over 10 runs at load 9 on the 2 cores;
    # the 2 s requirement is a 20x margin over it. (Signal to process exit: 0.29-0.32 s there.)
    seen = float(out.split("zero sent", 1)[1].split()[0]) - t0
    assert seen < 2.0, f"the signal was seen {seen:.2f} s after it was sent"


def test_a_refused_parameter_exits_2_with_one_line():
    p = subprocess.run([sys.executable, "-c", NODE, "config"], capture_output=True, text=True, timeout=30)
    assert p.returncode == 2 and p.stderr.strip() == "n: parameter 'x' refused"


def test_a_shutdown_that_hangs_is_ended_by_the_watchdog():
    import signal
    p = start("hang")
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=15)
    assert p.returncode == 1 and "zero sent" in out and "Thread" in err  # where it hung, then exit


def test_the_process_ends_after_its_teardown_without_pythons_finalization():
    """run_node ends the process once rclpy is down: Python's finalization (atexit, module teardown,
    the garbage collection of everything) ran unbounded after the watchdog and took 2.0-2.9 s of a
    Ctrl-C of the teleop graph in 4 of 8 runs (load 12), and crashed the bridge once (exit -11). Here
    an atexit handler that never returns stands for it."""
    import signal
    p = start("slow_exit")
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=30)   # a hang guard: the handler would hold the process 600 s
    assert p.returncode == 0 and "zero sent" in out and "Thread" not in err, err


def test_a_teardown_that_hangs_ends_the_process_with_its_exit_code_and_the_stacks():
    """After the zero command, a teardown stuck in C with the GIL held (Fast DDS's participant deletion
    can busy-wait, #6513) is ended within 2 s of the signal with the node's exit code (0 after a signal), its
    threads' stacks printed: it is not a failure of the node (the watchdog said exit code 1 after 3 s,
    and at load 38 a starved teardown did so in rclpy's logging shutdown)."""
    import signal
    p = start("stuck_teardown")
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=30)
    assert p.returncode == 0 and "zero sent" in out, err
    assert "Timeout" in err and "in destroy_node" in err, err


def test_a_node_that_declares_a_longer_shutdown_gets_it_and_the_teardown_its_own_bound():
    """on_shutdown of a node with `shutdown_timeout_s` may take longer than SHUTDOWN_GRACE_S: the
    recorder closing an episode's bag took most of the 3 s under load, and the watchdog then ended it
    with exit code 1 in destroy_publisher (issue 21). The sleep is the work, not a synchronisation."""
    import signal
    p = start("slow")
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=30)
    assert p.returncode == 0 and "closed" in out and "Thread" not in err, err


TABLE_NODE = textwrap.dedent('''
    import sys
    from rclpy.node import Node
    from vla_common.ros.node_main import run_node
    from vla_common.ros.parameters import Param, ParameterTable

    TABLE = ParameterTable([Param("rate", 100.0, "rate (Hz)")])

    class N(Node):
        def __init__(self):
            super().__init__("n")
            print("rate", TABLE.declare(self)["rate"], flush=True)
            self.finished = True

    sys.exit(run_node(N, "n", ["--ros-args", "--params-file", sys.argv[1]]))
''')


@pytest.mark.parametrize("key, code", [("/**", 0), ("/n", 2)])
def test_run_node_tells_a_shared_section_from_the_nodes_own(tmp_path, key, code):
    """run_node remembers the command line, so the table knows which section gave a name: under `/**`
    (shared by several nodes) an unknown one is a warning, under the node's own key a refusal."""
    path = tmp_path / "params.yaml"
    path.write_text(f"{key}:\n  ros__parameters:\n    rate: 50\n    camera_fps: 30\n")
    p = subprocess.run([sys.executable, "-c", TABLE_NODE, str(path)], capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == code, p.stderr
    if code == 0:
        assert "rate 50.0" in p.stdout
        assert f"parameter 'camera_fps' given under '/**' in {path} is not a parameter of /n" in p.stderr
    else:
        assert "/n has no parameter 'camera_fps'" in p.stderr


def test_a_command_line_rcl_cannot_read_exits_2_with_one_line_and_a_hint():
    """`-p 'ee_axes:=[x, y, z]'`: rcl reads the bare y as a boolean and refuses the mixed list; before,
    rclpy.init's RCLError came out as a traceback with rcl's source locations."""
    script = "import sys; from vla_common.ros.node_main import run_node; " \
             "sys.exit(run_node(None, 'n', ['n', '--ros-args', '-p', 'axes:=[x, y, z]']))"
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=30)
    assert p.returncode == 2, p.stderr
    line = [x for x in p.stderr.splitlines() if x.startswith("n: ")]
    assert line == ["n: Couldn't parse parameter override rule: '-p axes:=[x, y, z]'. Error: Sequence should "
                    "be of same type. Value type 'bool' do not belong at line_num 1 (rcl reads a bare y, n, "
                    "yes, no, on, off, true or false as a boolean: quote such strings in a list, ['x', 'y'])"]
    assert "Traceback" not in p.stderr


class _Params:
    """A node's has_parameter/get_parameter over a dict, and a logger that keeps its warnings."""

    def __init__(self, **values):
        self.values, self.warnings = values, []

    def has_parameter(self, name):
        return name in self.values

    def get_parameter(self, name):
        return type("P", (), {"value": self.values[name]})()

    def get_logger(self):
        return type("L", (), {"warning": lambda _, text: self.warnings.append(text)})()


@pytest.mark.parametrize(("values", "asked"), [
    ({"thread_priority": 10}, [10]),
    ({"thread_priority": 10, "lockstep": False}, [10]),
    ({"thread_priority": 10, "lockstep": True}, []),   # the simulation owns time: no person waits
    ({"rate": 5.0}, []),                               # a node off the operator's path
])
def test_the_thread_priority_is_applied_once_the_node_is_built_and_never_in_lockstep(monkeypatch, values,
                                                                                      asked):
    from vla_common.ros import node_main
    calls = []
    monkeypatch.setattr(node_main, "run_realtime", lambda p: calls.append(p) or "refused here")
    node = _Params(**values)
    node_main._run_realtime(node)
    assert calls == asked
    assert node.warnings == ["refused here"] * len(asked)    # why not, said once

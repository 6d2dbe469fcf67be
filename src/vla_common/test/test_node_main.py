"""run_node: signals stop the spin, on_shutdown runs while the context lives, exit codes, bounded shutdown."""
import subprocess
import sys
import textwrap
import time

import pytest

NODE = textwrap.dedent('''
    import sys, time
    from rclpy.node import Node
    from vla_common.ros.node_main import ConfigError, run_node

    class N(Node):
        def __init__(self):
            super().__init__("n")
            if "config" in sys.argv:
                raise ConfigError("parameter 'x' refused")
            self.create_timer(0.05, lambda: None)
            print("ready", flush=True)
        def on_shutdown(self):
            print("zero sent", flush=True)
            if "hang" in sys.argv:
                time.sleep(60)      # a teardown that never returns

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
    assert time.monotonic() - t0 < 2.0


def test_a_refused_parameter_exits_2_with_one_line():
    p = subprocess.run([sys.executable, "-c", NODE, "config"], capture_output=True, text=True, timeout=30)
    assert p.returncode == 2 and p.stderr.strip() == "n: parameter 'x' refused"


def test_a_shutdown_that_hangs_is_ended_by_the_watchdog():
    import signal
    p = start("hang")
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=15)
    assert p.returncode == 1 and "zero sent" in out and "Thread" in err  # where it hung, then exit

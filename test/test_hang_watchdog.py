"""The run's hang watchdog (conftest.py): a test blocked in C past its timeout, where pytest-timeout's
signal never lands, ends the run with every thread's stack instead of holding CI to its own limit."""
import os
import subprocess
import sys
from pathlib import Path

DEADLOCK = '''
import ctypes
import pytest


@pytest.mark.timeout(1)
def test_blocked_in_c():
    libc = ctypes.CDLL(None)
    mutex = ctypes.create_string_buffer(64)
    libc.pthread_mutex_lock(mutex)
    libc.pthread_mutex_lock(mutex)
'''


def test_a_test_blocked_in_c_ends_the_run_with_the_stacks(tmp_path):
    (tmp_path / "test_blocked.py").write_text(DEADLOCK)
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, VLA_TEST_HANG_MARGIN_S="2", PYTHONPATH=f"{root}{os.pathsep}"
               + os.environ.get("PYTHONPATH", ""))
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "conftest", "-p", "no:cacheprovider",
                          str(tmp_path / "test_blocked.py")], cwd=tmp_path, env=env, capture_output=True,
                         text=True, timeout=120)
    assert run.returncode != 0
    assert "Timeout (0:00:03)!" in run.stderr and "test_blocked_in_c" in run.stderr

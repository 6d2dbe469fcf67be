"""Every node with a `catalogue` parameter refuses a hostile path at startup with exit code 2 and a
message that names the file and quotes nothing of it (issue 20 item 9); the recorder, whose catalogue
changes at run time, is tested in vla_demo_recorder's test_recorder_node.py.

Each node runs as users start it (`vla run`), with 4 GiB of address space and a timeout, so a node
that reads /dev/zero until memory runs out fails the test instead of the machine."""
from __future__ import annotations

import resource
import subprocess
import sys

import pytest

SECRET = "sk-live-7f3c9a1b2d4e"
NODES = [("vla_demo_recorder", "recorder"), ("vla_detector", "detector_node"),
         ("vla_panda_bridge", "panda_bridge"), ("vla_evaluation", "sim_teleoperator")]


def _limit_memory():
    resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))


def start(pkg: str, exe: str, catalogue: str, timeout: float = 90.0) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "vla_launch.cli", "run", pkg, exe, "--ros-args",
           "-p", f"catalogue:={catalogue}"]
    try:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, preexec_fn=_limit_memory)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{exe} with catalogue:={catalogue} neither started nor refused within {timeout} s")


@pytest.mark.slow
@pytest.mark.parametrize("pkg, exe", NODES, ids=[n[1] for n in NODES])
def test_a_hostile_catalogue_stops_the_node_with_exit_code_2(tmp_path, pkg, exe):
    res = start(pkg, exe, "/dev/zero")
    assert res.returncode == 2 and "/dev/zero is not a regular file" in res.stderr, res.stderr[-2000:]
    secret = tmp_path / "credentials.yaml"
    secret.write_text(f"objects:\n  a: {{shape: {SECRET}}}\n")
    res = start(pkg, exe, str(secret))
    assert res.returncode == 2 and f"{secret}: objects.a lacks size" in res.stderr, res.stderr[-2000:]
    assert SECRET not in res.stderr

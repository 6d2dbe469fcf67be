"""Issue 33: the study's simulated participants through the launched graph give the same rows at any load.

A small slice (one simulated participant, latent-YOLO and the end-effector baseline, a base task and a
few-shot one) runs twice through `vla_study` on the graph (lockstep, as fast as the CPU allows): once
as the machine is, once beside two busy loops this test starts. Every row and every trial's path must
be identical apart from the fields that name wall time (before lockstep the graph ran in real time
and the same trials changed outcome and SPARC with the machine's load).
"""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from busy_loops import BusyLoops

pytestmark = [pytest.mark.slow, pytest.mark.ros]
# The fields that name wall time: how long it took, where the time went, the pace, the bag's folder
# (named with the wall-clock date and time it was opened).
WALL_FIELDS = {"wall_s", "wall_phases", "trial_rtf", "bag"}
SLICE = """study: ci-lockstep
participants: sim:1
strategies: [latent-YOLO, end-effector]
settings:
  base: bread/push_east
  Seen: cereal_box/push_south
trials: 1
practice: {trials: 0, reset_seed: 7}
time_limit: 8
rate: 20
"""


def _run(protocol: Path, out: Path) -> list[dict]:
    # serially: this test is about load (a local Ray may not even start beside the busy loops on a loaded
    # machine); that Ray gives the serial rows is test/test_ray_sweeps.py's
    cmd = [sys.executable, "-m", "vla_study.cli", "--protocol", str(protocol), "--out", str(out), "--serial"]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=1200)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    return [json.loads(x) for x in (out / "trials.jsonl").read_text().splitlines() if x.strip()]


@pytest.mark.timeout(2700)
def test_the_same_study_slice_gives_the_same_rows_quiet_and_beside_two_busy_loops(tmp_path):
    protocol = tmp_path / "slice.yaml"
    protocol.write_text(SLICE)
    quiet = _run(protocol, tmp_path / "quiet")
    with BusyLoops():
        busy = _run(protocol, tmp_path / "busy")
    assert len(quiet) == 4
    # by key (the order a sweep writes rows in is the order they finish)
    assert {r["key"]: {k: v for k, v in r.items() if k not in WALL_FIELDS} for r in quiet} == \
           {r["key"]: {k: v for k, v in r.items() if k not in WALL_FIELDS} for r in busy}
    for r in quiet:
        a = np.load(tmp_path / "quiet" / "trials" / f"{r['file']}.npz")
        b = np.load(tmp_path / "busy" / "trials" / f"{r['file']}.npz")
        assert a.files == b.files and all(np.array_equal(a[k], b[k]) for k in a.files), r["key"]
    assert any(r["path_length_m"] > 0.1 for r in quiet)          # the participants drove
    busy_wall = {r["key"]: r["wall_s"] for r in busy}
    print("wall s per trial (quiet, busy):", [(r["wall_s"], busy_wall[r["key"]]) for r in quiet])

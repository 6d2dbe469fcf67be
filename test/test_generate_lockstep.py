"""Issue 33 and 35: `vla_evaluation generate` in lockstep gives the same demonstrations at any load and
however its episodes are spread over workers.

A small generation (two episodes through record.launch.yaml: the bridge, the detector and the recorder,
with the demonstrator and the recorder answering every joint state) runs serially as the machine is,
serially beside two busy loops this test starts, and on a local Ray of 2 CPUs (a graph per worker, each
episode the first on its graph). Serially, every bag holds the very same messages (bytes, stamps
included); on Ray the episodes start at other simulated times, so there every message must be the same
with its stamp taken from the episode's start, and the loaded demonstrations (what training reads) the
same arrays. Before lockstep the bags followed the machine's pace (the recorder and the detector fell
behind, the demonstrator's commands came late).
"""
import json
from pathlib import Path

import numpy as np
import pytest
from busy_loops import BusyLoops

pytestmark = [pytest.mark.slow, pytest.mark.ros]
TASK, EPISODES, SEED = "bread/push_east", 2, 3
REPORT_WALL_FIELDS = {"wall_s", "bag"}   # how long it took, the bag's folder (named with the wall date)


def _generate(out: Path, engine=None):
    from vla_common.catalogue import default_catalogue
    from vla_evaluation.generate import GenerateConfig, run_generation
    from vla_evaluation.sweep import SERIAL

    cfg = GenerateConfig(tasks=[default_catalogue().task(TASK)], episodes=EPISODES, out=out / "demos",
                         seed=SEED, log_dir=out / "logs")
    records = run_generation(cfg, progress=print, engine=engine or SERIAL)
    assert len(records) == EPISODES and all(not r.error for r in records), [r.error for r in records]
    return records


def _messages(bag: str, relative: bool) -> dict[str, list]:
    """Per topic, in order: (the header stamp, the message with a zero stamp, deserialized: the bytes
    hold uninitialised CDR padding); with `relative` the stamp from the episode's start (every recorded
    type starts with a std_msgs/Header)."""
    from rclpy.serialization import deserialize_message
    from rosbags.rosbag2 import Reader
    from vla_common.ros.convert import ns_from_stamp
    from vla_demo_recorder.bag_writer import EpisodeInfo, read_metadata_yaml
    from vla_demo_recorder.recorder_node import import_message

    start = EpisodeInfo.from_custom_data(read_metadata_yaml(Path(bag))["custom_data"]).start_time_ns
    out: dict[str, list] = {}
    with Reader(bag) as reader:
        for conn, _t, raw in reader.messages():
            msg = deserialize_message(bytes(raw), import_message(conn.msgtype))
            stamp = ns_from_stamp(msg.header.stamp) - (start if relative else 0)
            msg.header.stamp.sec = msg.header.stamp.nanosec = 0
            out.setdefault(conn.topic, []).append((stamp, repr(msg)))   # repr: a nan field equals itself
    return out


def _difference(a: dict[str, list], b: dict[str, list]) -> list[str]:
    """Per topic whose messages differ: the counts and the first differing message's index and stamps."""
    out = []
    for topic in sorted(set(a) | set(b)):
        x, y = a.get(topic, []), b.get(topic, [])
        if x != y:
            i = next((i for i, (p, q) in enumerate(zip(x, y)) if p != q), min(len(x), len(y)))
            stamps = [m[i][0] if i < len(m) else None for m in (x, y)]
            out.append(f"{topic}: {len(x)} and {len(y)} messages, first differing #{i} (stamps {stamps})")
    return out


def _report(records) -> list[dict]:
    from dataclasses import asdict

    return [{k: v for k, v in asdict(r).items() if k not in REPORT_WALL_FIELDS} for r in records]


def _same_demos(a, b) -> None:
    from vla_demo_recorder.dataset import load_demo

    for ra, rb in zip(a, b):
        da, db = load_demo(ra.bag), load_demo(rb.bag)
        assert np.array_equal(da.t, db.t) and np.array_equal(da.q, db.q), ra.index
        assert np.array_equal(da.first_image, db.first_image) and da.detection == db.detection, ra.index


@pytest.mark.timeout(1500)
def test_the_same_generation_gives_the_same_bags_quiet_beside_busy_loops_and_on_ray(tmp_path):
    from vla_evaluation.sweep import Engine

    quiet = _generate(tmp_path / "quiet")
    with BusyLoops():
        busy = _generate(tmp_path / "busy")
    on_ray = _generate(tmp_path / "ray", Engine(cpus=2))
    assert _report(quiet) == _report(busy) == _report(on_ray)
    for a, b in zip(quiet, busy):
        assert not (d := _difference(_messages(a.bag, False), _messages(b.bag, False))), (a.index, d)
    for a, b in zip(quiet, on_ray):
        assert not (d := _difference(_messages(a.bag, True), _messages(b.bag, True))), (a.index, d)
    _same_demos(quiet, busy)
    _same_demos(quiet, on_ray)
    messages = _messages(quiet[0].bag, relative=False)
    frames = len(messages["/camera/camera_info"])
    assert frames > 10 and len(messages["/detections"]) == frames   # every frame's detection, none skipped
    assert any(r.success for r in quiet)                             # it pushed the bread
    assert len({Path(r.bag).parent for r in on_ray}) == 1            # the workers' bags in one folder
    report = json.loads((tmp_path / "ray" / "demos" / "generate_report.json").read_text())
    assert [e["index"] for e in report["episodes"]] == [1, 2]
    print("wall s per episode (quiet, busy, ray):", [(a.wall_s, b.wall_s, c.wall_s)
                                                     for a, b, c in zip(quiet, busy, on_ray)])

"""BagWriter: rosbag2 MCAP layout, readable by rosbags and mcap alike, episode metadata, errors."""
import errno
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from recorder_testing import detections, joint_state, string
from require import missing
from rosbags.highlevel import AnyReader
from vla_demo_recorder.bag_files import find_mcap, has_footer
from vla_demo_recorder.bag_writer import (
    BagError,
    BagWriteError,
    BagWriter,
    EpisodeInfo,
    make_qos,
    read_metadata_yaml,
)
from vla_demo_recorder.recorder import Recorder, RecorderError
from vla_demo_recorder.recover import recover

NAMES = [f"panda_joint{i}" for i in range(1, 8)]
JS = "sensor_msgs/msg/JointState"


def write_sample(path: Path, n: int = 50, episode: EpisodeInfo | None = None) -> BagWriter:
    bag = BagWriter(path, episode or EpisodeInfo(task="bread/push_east", index=7, note="hello"))
    bag.open()
    bag.add_topic("/joint_states", "sensor_msgs/msg/JointState", [make_qos("best_effort", depth=5)])
    bag.add_topic("/detections", "vla_interfaces/msg/DetectionArray", [make_qos()])
    bag.add_topic("/chatter", "std_msgs/String")
    for i in range(n):
        bag.write("/joint_states", 10**9 + i * 10**6, joint_state(10**9 + i * 10**6, NAMES, np.full(7, i)))
    bag.write("/detections", 10**9, detections(10**9, [("bread", 0, 0.9, 100.0, 200.0, 30.0, 40.0)]))
    bag.write("/chatter", 10**9 + 5, string("hi"))
    return bag


def counts_rosbags(path: Path) -> dict[str, int]:
    counts: dict[str, int] = {}
    with AnyReader([path]) as reader:
        for conn, _t, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
    return counts


def counts_mcap(mcap_file: Path) -> dict[str, int]:
    counts: dict[str, int] = {}
    with mcap_file.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _s, channel, _m, _msg in reader.iter_decoded_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    return counts


def test_layout_and_both_readers_agree(tmp_path):
    bag = write_sample(tmp_path / "ep")
    bag.close("kept", end_time_ns=123)
    meta = read_metadata_yaml(bag.path)
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap"
    assert meta["relative_file_paths"] == ["ep.mcap"] and meta["message_count"] == 52
    topics = {t["topic_metadata"]["name"]: t for t in meta["topics_with_message_count"]}
    assert topics["/joint_states"]["message_count"] == 50
    assert topics["/detections"]["topic_metadata"]["type"] == "vla_interfaces/msg/DetectionArray"
    qos = topics["/joint_states"]["topic_metadata"]["offered_qos_profiles"]
    assert qos[0]["reliability"] == "best_effort"
    # the type hash is the one rosidl generated for the installed package
    assert topics["/joint_states"]["topic_metadata"]["type_description_hash"] == (
        "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e")
    expected = {"/joint_states": 50, "/detections": 1, "/chatter": 1}
    assert counts_rosbags(bag.path) == expected
    assert counts_mcap(bag.mcap_path) == expected
    with bag.mcap_path.open("rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        schemas = {s.name: s for s in summary.schemas.values()}
        assert schemas["vla_interfaces/msg/DetectionArray"].encoding == "ros2msg"
        assert b"MSG: vla_interfaces/Detection" in schemas["vla_interfaces/msg/DetectionArray"].data
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
        assert all("offered_qos_profiles" in c.metadata for c in summary.channels.values())
        assert [m.name for m in reader.iter_metadata()] == ["rosbag2"]


def test_episode_metadata_round_trip(tmp_path):
    bag = write_sample(tmp_path / "ep")
    bag.close("discarded", end_time_ns=99)
    ep = EpisodeInfo.from_custom_data(read_metadata_yaml(bag.path)["custom_data"])
    assert (ep.task, ep.object_class, ep.index, ep.outcome, ep.note, ep.end_time_ns) == (
        "bread/push_east", "bread", 7, "discarded", "hello", 99)
    # the same metadata sits in the MCAP file's rosbag2 metadata record
    with bag.mcap_path.open("rb") as f:
        record = next(make_reader(f).iter_metadata())
    assert "episode.task: bread/push_east" in record.metadata["serialized_metadata"]


def test_never_overwrites(tmp_path):
    write_sample(tmp_path / "ep").close()
    before = {p.name: p.read_bytes() for p in (tmp_path / "ep").iterdir()}
    late = BagWriter(tmp_path / "ep", EpisodeInfo(task="bread/push_east"))
    with pytest.raises(BagError, match="never overwritten"):
        late.open()
    late.abort("gave up")
    assert {p.name: p.read_bytes() for p in (tmp_path / "ep").iterdir()} == before


def test_unknown_type_is_a_clear_error(tmp_path):
    with BagWriter(tmp_path / "ep") as bag:
        with pytest.raises(BagError, match="not_a_pkg"):
            bag.add_topic("/x", "not_a_pkg/msg/Thing")


def test_unwritable_output_folder(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(BagError, match="cannot create output folder"):
        BagWriter(blocker / "sub" / "ep").open()
    with pytest.raises(RecorderError, match="cannot create output_dir"):
        Recorder(blocker / "demos").start("bread/push_east")
    if os.geteuid() != 0:  # root ignores permission bits
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        with pytest.raises(BagError, match="not writable"):
            BagWriter(locked / "ep").open()


def test_flush_leaves_complete_chunks_for_recovery(tmp_path):
    bag = write_sample(tmp_path / "ep", n=40)
    bag.flush()
    for i in range(10):  # not flushed: lost in a crash
        bag.write("/joint_states", 2 * 10**9 + i, joint_state(0, NAMES, np.zeros(7)))
    bag._writer.storage.bio.flush()  # what the OS has when the process dies: no footer, no pending chunk
    snapshot = tmp_path / "crashed"
    snapshot.mkdir()
    (snapshot / "metadata.yaml").write_bytes((bag.path / "metadata.yaml").read_bytes())
    (snapshot / "ep.mcap").write_bytes(bag.mcap_path.read_bytes() + b"\x06\x10\x00")  # + a torn record
    bag.abort()
    assert not has_footer(snapshot / "ep.mcap")
    with pytest.raises(Exception, match="(?i)mcap|footer|magic|summary|invalid"):
        counts_rosbags(snapshot)
    report = recover(snapshot)
    assert report.counts == {"/joint_states": 40, "/detections": 1, "/chatter": 1}
    assert counts_rosbags(snapshot) == report.counts == counts_mcap(find_mcap(snapshot))
    meta = read_metadata_yaml(snapshot)
    assert meta["message_count"] == 42
    ep = EpisodeInfo.from_custom_data(meta["custom_data"])
    assert ep.outcome == "recovered" and ep.task == "bread/push_east"
    assert recover(snapshot).complete  # a second run leaves the good bag alone


class _FullDisk:
    """A file object that raises ENOSPC once `budget` bytes were written."""

    def __init__(self, inner, budget: int):
        self.inner, self.budget = inner, budget

    def write(self, data):
        self.budget -= len(data)
        if self.budget < 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return self.inner.write(data)

    def __getattr__(self, name):
        return getattr(self.inner, name)


def test_disk_full_injected_ends_episode_with_clear_error(tmp_path):
    rec = Recorder(tmp_path, flush_period_s=0.05, fsync=False)
    rec.start("bread/push_east")
    for i in range(20):
        rec.record("/joint_states", JS, [], i, joint_state(i, NAMES, np.zeros(7)))
    first = rec.stop()
    assert first.outcome == "kept" and first.messages == 20
    path = rec.start("soda_can/push_south")
    ep = rec._episode
    ep.writer._writer.storage.bio = _FullDisk(ep.writer._writer.storage.bio, budget=3000)
    for i in range(50):
        rec.record("/chatter", "std_msgs/msg/String", [], i, string("x" * 2000 + str(i)))
    assert _wait(lambda: not rec.recording)
    state = rec.state()
    assert "disk full" in state.last_error and str(path) in state.last_error
    with pytest.raises(RecorderError, match="disk full"):
        rec.stop()
    rec.shutdown()
    assert counts_rosbags(first.path) == {"/joint_states": 20}  # the earlier bag is intact
    assert EpisodeInfo.from_custom_data(read_metadata_yaml(path)["custom_data"]).outcome == "failed"


def test_disk_full_on_a_real_tiny_filesystem(tmp_path):
    mnt = tmp_path / "tiny"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=600k", "tmpfs", str(mnt)],
                      capture_output=True).returncode != 0:
        missing("TMPFS", "cannot mount a tmpfs here (needs root); the injected ENOSPC test covers it")
    try:
        rec = Recorder(mnt, flush_period_s=0.05, fsync=True)
        rec.start("bread/push_east")
        for i in range(30):
            rec.record("/joint_states", JS, [], i, joint_state(i, NAMES, np.zeros(7)))
        first = rec.stop()
        path = rec.start("bread/push_east")
        for i in range(5):
            rec.record("/joint_states", JS, [], i, joint_state(i, NAMES, np.zeros(7)))
        writer = rec._episode.writer                  # the five are on disk as a complete chunk
        assert _wait(lambda: writer.message_count >= 5 and not writer._unflushed)
        for i in range(200):  # 2 MB into 600 kB
            if not rec.record("/chatter", "std_msgs/msg/String", [], i, string("y" * 10_000)):
                break
        assert _wait(lambda: not rec.recording, 10)
        assert "disk full" in rec.state().last_error
        rec.shutdown()
        assert counts_rosbags(first.path) == {"/joint_states": 30}
        with pytest.raises(BagError, match="disk full"):  # no room to rewrite it in place
            recover(path)
        copy = tmp_path / path.name
        shutil.copytree(path, copy)
        report = recover(copy)  # whatever reached the disk before it filled up
        assert report.counts["/joint_states"] == 5 and counts_rosbags(copy) == report.counts
    finally:
        subprocess.run(["umount", str(mnt)], check=False)


def test_bag_write_error_is_raised_by_the_writer(tmp_path):
    bag = write_sample(tmp_path / "ep", n=1)
    bag._writer.storage.bio = _FullDisk(bag._writer.storage.bio, budget=0)
    with pytest.raises(BagWriteError, match="disk full"):
        for i in range(2000):
            bag.write("/chatter", i, string("z" * 1000))
    with pytest.raises(BagError, match="not open"):
        bag.write("/chatter", 0, string("after"))


def _wait(cond, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.01)
    return cond()

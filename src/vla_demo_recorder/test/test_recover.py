"""`recover` never destroys its input: storage it cannot rewrite and files with nothing to recover are
left as they were (exit non-zero); a recovered bag keeps the original beside it."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from recorder_testing import detections, joint_state, typestore
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from vla_demo_recorder.bag_files import find_mcap, has_footer
from vla_demo_recorder.bag_writer import BagError, BagWriter, EpisodeInfo, read_metadata_yaml
from vla_demo_recorder.dataset import load_demos
from vla_demo_recorder.recover import recover

NAMES = [f"panda_joint{i}" for i in range(1, 8)]
JS = "sensor_msgs/msg/JointState"


def snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vla_demo_recorder.cli", *args],
                          capture_output=True, text=True, timeout=120)


def rosbags_bag(path: Path, storage: StoragePlugin, n: int = 200) -> Path:
    """A bag written by rosbags (an independent writer), one chunk when MCAP."""
    ts = typestore()
    with Writer(path, version=9, storage_plugin=storage) as w:
        w.set_custom_data("episode.task", "bread/push_east")
        w.set_custom_data("episode.outcome", "kept")
        conn = w.add_connection("/joint_states", JS, typestore=ts)
        for i in range(n):
            w.write(conn, 10**9 + i * 10**7, joint_state(10**9 + i * 10**7, NAMES, np.full(7, 0.001 * i)))
    return path


def crashed_bag(path: Path, chunks: int = 3, per_chunk: int = 20) -> Path:
    """What a killed recorder leaves: flushed chunks, no footer, the interim metadata.yaml."""
    bag = BagWriter(path, EpisodeInfo(task="bread/push_east", index=3)).open()
    bag.add_topic("/joint_states", JS)
    for c in range(chunks):
        for i in range(per_chunk):
            t = 10**9 + (c * per_chunk + i) * 10**7
            bag.write("/joint_states", t, joint_state(t, NAMES, np.zeros(7)))
        bag.flush()
    bag.abort()
    return path


def test_a_sqlite3_bag_is_refused_unchanged(tmp_path):
    bag = rosbags_bag(tmp_path / "db3bag", StoragePlugin.SQLITE3)
    before = snapshot(bag)
    with pytest.raises(BagError, match="sqlite3"):
        recover(bag)
    out = run_cli("recover", str(bag))
    assert out.returncode != 0 and "sqlite3" in out.stderr, out
    assert snapshot(bag) == before and sorted(p.name for p in bag.iterdir()) == sorted(before)


def test_a_truncated_single_chunk_bag_is_left_alone_and_the_exit_code_says_so(tmp_path):
    bag = rosbags_bag(tmp_path / "torn", StoragePlugin.MCAP)
    mcap = find_mcap(bag)
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) * 3 // 5])  # a copy cut off inside its only chunk
    before = snapshot(bag)
    with pytest.raises(BagError, match="nothing to recover"):
        recover(bag)
    out = run_cli("recover", str(bag))
    assert out.returncode != 0 and "nothing to recover" in out.stderr, out
    assert snapshot(bag) == before and sorted(p.name for p in bag.iterdir()) == sorted(before)


def test_an_empty_file_is_left_alone(tmp_path):
    bag = crashed_bag(tmp_path / "empty", chunks=0)
    before = snapshot(bag)
    with pytest.raises(BagError, match="nothing to recover"):
        recover(bag)
    assert snapshot(bag) == before


def test_the_original_is_kept_beside_the_recovered_bag(tmp_path):
    bag = crashed_bag(tmp_path / "ep0003")
    before = snapshot(bag)
    report = recover(bag)
    assert report.messages == 60 and report.backup == bag / "ep0003.mcap.orig"
    after = snapshot(bag)
    assert after["ep0003.mcap.orig"] == before["ep0003.mcap"]
    assert after["metadata.yaml.orig"] == before["metadata.yaml"]
    assert has_footer(find_mcap(bag)) and not (bag / ".recover").exists()
    with AnyReader([bag]) as reader:
        assert sum(1 for _ in reader.messages()) == 60
    assert EpisodeInfo.from_custom_data(read_metadata_yaml(bag)["custom_data"]).outcome == "recovered"

    # forced again on the now complete bag: the first backup is not overwritten
    again = recover(bag, force=True)
    assert again.messages == 60 and again.backup == bag / "ep0003.mcap.orig.1"
    assert snapshot(bag)["ep0003.mcap.orig"] == before["ep0003.mcap"]


def test_a_bare_mcap_file_is_recovered_beside_it(tmp_path):
    bag = crashed_bag(tmp_path / "ep")
    loose = tmp_path / "loose"
    loose.mkdir()
    (loose / "crashed.mcap").write_bytes((bag / "ep.mcap").read_bytes())
    report = recover(loose / "crashed.mcap")
    assert report.messages == 60
    assert sorted(p.name for p in loose.iterdir()) == ["crashed.mcap", "crashed.recovered.mcap"]
    assert (loose / "crashed.mcap").read_bytes() == (bag / "ep.mcap").read_bytes()
    assert has_footer(loose / "crashed.recovered.mcap")


def kept_then_cut_short(path: Path, seconds: int = 6, keep_chunks: int = 2) -> Path:
    """A 6 s demonstration closed as `kept` (one chunk per second), whose MCAP then lost its end (a
    copy cut short, a disk that failed after the episode): only the first `keep_chunks` chunks
    remain, the final metadata.yaml still says `kept`."""
    bag = BagWriter(path, EpisodeInfo(task="bread/push_east", index=7, start_time_ns=10**9)).open()
    bag.add_topic("/joint_states", JS)
    bag.add_topic("/detections", "vla_interfaces/msg/DetectionArray")
    bag.write("/detections", 10**9, detections(10**9, [("bread", 0, 0.9, 320, 240, 50, 40)]))
    sizes = []
    for c in range(seconds):
        for i in range(10):
            t = 10**9 + (c * 10 + i) * 10**8
            bag.write("/joint_states", t, joint_state(t, NAMES, np.full(7, 0.01 * (c * 10 + i))))
        bag.flush()
        sizes.append(find_mcap(path).stat().st_size)
    bag.close(outcome="kept", end_time_ns=10**9 + seconds * 10**9)
    mcap = find_mcap(path)
    mcap.write_bytes(mcap.read_bytes()[: sizes[keep_chunks - 1] + 7])  # a torn record after the chunks
    assert EpisodeInfo.from_custom_data(read_metadata_yaml(path)["custom_data"]).outcome == "kept"
    return path


def test_a_kept_episode_cut_short_is_recovered_as_recovered_and_training_says_so(tmp_path):
    """Issue 20 item 11: recovering a truncated bag whose outcome was `kept` wrote `kept`, so 2 s of a
    6 s demonstration trained as complete."""
    bag = kept_then_cut_short(tmp_path / "ep0007")
    report = recover(bag)
    assert report.messages == 21  # the detection and 2 s of joint states
    assert "; episode outcome recovered;" in report.summary()
    ep = EpisodeInfo.from_custom_data(read_metadata_yaml(bag)["custom_data"])
    assert ep.outcome == "recovered" and ep.task == "bread/push_east"
    assert "recovered from 2 complete chunks" in ep.error and "the outcome was 'kept'" in ep.error

    demos, skipped = load_demos([bag])
    assert demos == [] and len(skipped) == 1
    assert "episode outcome is 'recovered'" in skipped[0][1] and "--include-incomplete" in skipped[0][1]
    demos, skipped = load_demos([bag], include_incomplete=True)
    assert skipped == [] and demos[0].outcome == "recovered" and demos[0].t[-1] == pytest.approx(1.9)


def test_a_discarded_episode_stays_discarded_and_another_writers_bag_reads_as_recovered(tmp_path):
    bag = kept_then_cut_short(tmp_path / "ep0008")
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace("episode.outcome: kept", "episode.outcome: discarded"))
    recover(bag)
    assert EpisodeInfo.from_custom_data(read_metadata_yaml(bag)["custom_data"]).outcome == "discarded"

    other = BagWriter(tmp_path / "other").open()  # like another writer's: no episode metadata
    other.add_topic("/joint_states", JS)
    other.add_topic("/detections", "vla_interfaces/msg/DetectionArray")
    other.write("/detections", 10**9, detections(10**9, [("bread", 0, 0.9, 320, 240, 50, 40)]))
    for i in range(40):
        other.write("/joint_states", 10**9 + i * 10**8, joint_state(10**9 + i * 10**8, NAMES, np.zeros(7)))
        if i % 10 == 9:
            other.flush()
    other.abort()
    loose = tmp_path / "loose"
    loose.mkdir()
    (loose / "theirs.mcap").write_bytes(other.mcap_path.read_bytes())
    assert recover(loose / "theirs.mcap").messages == 41
    demos, skipped = load_demos([loose / "theirs.recovered.mcap"], task="bread/push_east")
    assert demos == [] and "episode outcome is 'recovered'" in skipped[0][1], skipped
    demos, _ = load_demos([loose / "theirs.recovered.mcap"], task="bread/push_east", include_incomplete=True)
    assert demos[0].task == "bread/push_east" and demos[0].detection.class_id == "bread"

"""Recorder (no ROS): recorders sharing one output_dir never crash and never share an index."""
import re
import threading

import numpy as np
import pytest
from recorder_testing import joint_state
from vla_demo_recorder.bag_writer import BagWriter, EpisodeInfo, _Rosbag2Writer, read_metadata_yaml
from vla_demo_recorder.recorder import Recorder, RecorderError, validate_task

NAMES = [f"panda_joint{i}" for i in range(1, 8)]
JS = "sensor_msgs/msg/JointState"


def test_a_folder_taken_between_the_check_and_the_creation_moves_to_the_next_index(tmp_path, monkeypatch):
    """Another recorder creates our episode folder just after we chose it: we take the next index."""
    real_init = _Rosbag2Writer.__init__
    stolen = []

    def racing_init(self, path, **kwargs):
        if not stolen:
            path.mkdir()  # the other recorder wins the race for this name
            stolen.append(path)
        real_init(self, path, **kwargs)

    monkeypatch.setattr(_Rosbag2Writer, "__init__", racing_init)
    rec = Recorder(tmp_path, fsync=False)
    try:
        path = rec.start("bread/push_east")
        assert path != stolen[0] and path.name.startswith("ep0002_") and stolen[0].name.startswith("ep0001_")
        assert rec.stop().outcome == "kept"
        assert list(stolen[0].iterdir()) == []  # the other recorder's folder is not touched
    finally:
        rec.shutdown()


def test_recorders_starting_at_once_on_one_folder_all_record(tmp_path):
    recorders = [Recorder(tmp_path, fsync=False) for _ in range(6)]
    tasks = ["bread/push_east", "soda_can/push_south", "bread/push_east"] * 2  # same and other names
    barrier = threading.Barrier(len(recorders))
    results: dict[int, object] = {}

    def start(i: int) -> None:
        barrier.wait()
        try:
            results[i] = recorders[i].start(tasks[i])
            recorders[i].record("/joint_states", JS, [], 1, joint_state(1, NAMES, np.zeros(7)))
        except Exception as err:  # what the test is about: nothing may escape
            results[i] = err

    try:
        for _round in range(3):
            results.clear()
            threads = [threading.Thread(target=start, args=(i,)) for i in range(len(recorders))]
            for t in threads:
                t.start()
            for t in threads:
                t.join(60)
            assert all(not isinstance(r, Exception) for r in results.values()), results
            for rec in recorders:
                assert rec.stop().outcome == "kept"
    finally:
        for rec in recorders:
            rec.shutdown()
    folders = sorted(p.name for p in tmp_path.iterdir() if p.is_dir())
    indices = [int(re.match(r"ep(\d+)_", name).group(1)) for name in folders]
    assert sorted(indices) == list(range(1, 19))  # 18 episodes, each its own index
    for name in folders:
        ep = EpisodeInfo.from_custom_data(read_metadata_yaml(tmp_path / name)["custom_data"])
        assert ep.outcome == "kept" and name.startswith(f"ep{ep.index:04d}_")


def test_tasks_are_checked_by_one_function():
    assert validate_task(" bread:push_east ") == "bread/push_east"
    with pytest.raises(RecorderError, match="unknown object class 'spaceship'"):
        validate_task("spaceship/push_east")
    with pytest.raises(RecorderError, match="must look like"):
        validate_task("../etc/push_east")


def test_shutdown_writes_the_queue_for_drain_s_then_counts_the_rest_dropped_and_closes_the_bag(
        tmp_path, monkeypatch):
    """Ctrl-C while the disk is behind: the bag must still be closed in time (the recorder was ended
    by its node's watchdog, exit code 1, bag left 'recording', under load: issue 21). Each write
    takes one second of the recorder's clock; the writer is stuck until shutdown(drain_s=3.5) is
    called: 4 of the 10 queued messages are written, 6 counted as dropped, the bag is closed."""
    now = [0.0]
    stuck = threading.Event()
    writer_thread = []

    def clock():
        if threading.current_thread() is threading.main_thread():
            stuck.set()  # shutdown reads the clock: the disk comes back from then on
        return now[0]

    real_write = BagWriter.write

    def slow_write(self, topic, t_ns, data):
        writer_thread.append(threading.current_thread())
        assert stuck.wait(60)
        now[0] += 1.0
        real_write(self, topic, t_ns, data)

    monkeypatch.setattr(BagWriter, "write", slow_write)
    rec = Recorder(tmp_path, fsync=False, clock=clock)
    path = rec.start("bread/push_east")
    for i in range(10):
        assert rec.record("/joint_states", JS, [], i + 1, joint_state(i + 1, NAMES, np.full(7, float(i))))
    result = rec.shutdown(drain_s=3.5)
    assert writer_thread and writer_thread[0] is not threading.main_thread()
    assert (result.outcome, result.messages, result.dropped) == ("interrupted", 4, 6), result.summary()
    ep = EpisodeInfo.from_custom_data(read_metadata_yaml(path)["custom_data"])
    assert ep.outcome == "interrupted" and ep.messages_dropped == 6
    assert read_metadata_yaml(path)["message_count"] == 4 and rec.state().messages_dropped == 6

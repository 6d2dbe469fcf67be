"""Bag -> Demo, from bags written by hand with rosbags (known joint states and context)."""
from pathlib import Path

import numpy as np
import pytest
from recorder_testing import detections, image, joint_state, string, typestore
from rosbags.rosbag2 import StoragePlugin, Writer
from vla_common.detection import Detection
from vla_demo_recorder.bag_writer import BagWriter, EpisodeInfo
from vla_demo_recorder.dataset import DemoError, load_demo, load_demos

NAMES = [f"panda_joint{i}" for i in range(1, 8)]
T0 = 1_700_000_000 * 10**9


def q_of(t: float) -> np.ndarray:
    """Known joint trajectory: joint j moves linearly at 0.1 * (j + 1) rad/s from j * 0.2."""
    return np.array([0.2 * j + 0.1 * (j + 1) * t for j in range(7)])


def write_rosbags_bag(path: Path, *, seconds=2.0, rate=100.0, with_image=True, with_detection=True,
                      encoding="rgb8", episode: EpisodeInfo | None = None, image_delay_s=0.0,
                      detection_logged_after_s=0.0, storage=StoragePlugin.MCAP) -> Path:
    """A bag written by rosbags directly (not our writer): shuffled joint order, an extra joint and
    an extra topic, padded image rows."""
    ts = typestore()
    names = ["finger_joint", *NAMES[::-1]]  # reversed plus an extra joint: resolved by name
    with Writer(path, version=9, storage_plugin=storage) as w:
        if episode is not None:
            for k, v in episode.to_custom_data().items():
                w.set_custom_data(k, v)
        js = w.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        other = w.add_connection("/rosout_like", "std_msgs/msg/String", typestore=ts)
        cam = w.add_connection("/camera/image_raw", "sensor_msgs/msg/Image", typestore=ts)
        det = w.add_connection("/detections", "vla_interfaces/msg/DetectionArray", typestore=ts)
        pixels = np.zeros((4, 6, 3), np.uint8)
        pixels[..., 0] = 200  # red in RGB
        pixels[1, 2] = (1, 2, 3)
        if encoding == "bgr8":
            pixels = pixels[..., ::-1].copy()
        t_img = T0 + int(image_delay_s * 1e9)
        if with_image:
            w.write(cam, t_img, image(t_img, pixels, encoding, pad=2))
            w.write(cam, t_img + 10**8, image(t_img, np.zeros_like(pixels), encoding))
        if with_detection:
            t_det = T0 + int(detection_logged_after_s * 1e9)   # the log time; stamped T0 all the same
            w.write(det, t_det, detections(T0, []))  # empty first: skipped
            w.write(det, t_det + 1, detections(T0, [("bread", 0, 0.4, 10, 20, 5, 5),
                                                 ("soda_can", 1, 0.8, 300.5, 200.25, 40, 60)]))
        for i in range(int(seconds * rate) + 1):
            t = i / rate
            w.write(js, T0 + int(t * 1e9), joint_state(T0 + int(t * 1e9), names, [0.04, *q_of(t)[::-1]]))
        w.write(other, T0, string("ignored"))
    return path


def test_loader_resamples_and_reads_context(tmp_path):
    ep = EpisodeInfo(task="soda_can/push_south", index=1, outcome="kept")
    demo = load_demo(write_rosbags_bag(tmp_path / "b", episode=ep))
    assert demo.task == "soda_can/push_south" and demo.object_class == "soda_can"
    assert demo.t.shape == (21,) and np.allclose(demo.t, np.arange(21) * 0.1)
    assert demo.q.shape == (21, 7)
    assert np.allclose(demo.q, np.stack([q_of(t) for t in demo.t]), atol=1e-9)
    assert demo.first_image.shape == (4, 6, 3) and demo.first_image.dtype == np.uint8
    assert tuple(demo.first_image[1, 2]) == (1, 2, 3) and demo.first_image[0, 0, 0] == 200
    assert demo.image_size == (6, 4)
    assert demo.detection == Detection("soda_can", 0.8, 300.5, 200.25, 40.0, 60.0, class_index=1)


def test_the_detection_is_the_common_detection_type(tmp_path):
    """One Detection type: a loaded demo's detection is a plain vla_common Detection (no dict view)."""
    ep = EpisodeInfo(task="soda_can/push_south", outcome="kept")
    det = load_demo(write_rosbags_bag(tmp_path / "b", episode=ep)).detection
    assert type(det) is Detection and det.class_id == "soda_can" and det.width == 40.0
    assert Detection.from_dict(det.as_dict()) == det


def test_a_sqlite3_bag_loads_like_its_mcap_twin(tmp_path):
    """rosbag2's other storage (`ros2 bag record -s sqlite3`), written by rosbags: same demo."""
    ep = EpisodeInfo(task="soda_can/push_south", index=1, outcome="kept")
    mcap = load_demo(write_rosbags_bag(tmp_path / "m", episode=ep))
    db3 = load_demo(write_rosbags_bag(tmp_path / "s", episode=ep, storage=StoragePlugin.SQLITE3))
    assert (tmp_path / "s" / "s.db3").is_file()
    assert db3.task == mcap.task and np.array_equal(db3.q, mcap.q) and np.array_equal(db3.t, mcap.t)
    assert np.array_equal(db3.first_image, mcap.first_image) and db3.image_size == mcap.image_size
    assert db3.detection == mcap.detection
    assert load_demo(tmp_path / "s" / "s.db3").task == "soda_can/push_south"  # the file alone
    plain = write_rosbags_bag(tmp_path / "p", storage=StoragePlugin.SQLITE3)  # no episode metadata
    assert load_demo(plain, task="bread/push_east").detection.class_id == "bread"


def test_a_file_of_another_kind_is_named_as_such(tmp_path):
    bag = tmp_path / "junk"
    bag.mkdir()
    (bag / "junk.mcap").write_bytes(b"not a bag at all, just text")
    with pytest.raises(DemoError, match="neither an MCAP nor a sqlite3"):
        load_demo(bag)


def test_detection_of_the_task_object_is_preferred(tmp_path):
    """bread scores lower than soda_can in the hand-made bag: a bread task takes the bread box."""
    ep = EpisodeInfo(task="bread/push_east", outcome="kept")
    demo = load_demo(write_rosbags_bag(tmp_path / "b", episode=ep))
    assert demo.detection.class_id == "bread" and demo.detection.score == 0.4
    ep = EpisodeInfo(task="cereal_box/push_south", outcome="kept")  # not detected: top detection
    assert load_demo(write_rosbags_bag(tmp_path / "c", episode=ep)).detection.class_id == "soda_can"


def test_a_frame_queued_before_the_start_is_not_the_context(tmp_path):
    ts = typestore()
    ep = EpisodeInfo(task="bread/push_east", outcome="kept", start_time_ns=T0)
    path = tmp_path / "stale"
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        for k, v in ep.to_custom_data().items():
            w.set_custom_data(k, v)
        js = w.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        cam = w.add_connection("/camera/image_raw", "sensor_msgs/msg/Image", typestore=ts)
        old_scene = np.full((2, 2, 3), 7, np.uint8)
        new_scene = np.full((2, 2, 3), 9, np.uint8)
        w.write(cam, T0, image(T0 - 3 * 10**9, old_scene))  # rendered 3 s before the start
        w.write(cam, T0 + 10**8, image(T0 + 10**8, new_scene))
        for i in range(11):
            w.write(js, T0 + i * 10**8, joint_state(T0 + i * 10**8, NAMES, q_of(i * 0.1)))
    assert load_demo(path).first_image[0, 0, 0] == 9


def _joint_state_bag(path: Path, stamps_q, start_ns: int) -> Path:
    ts = typestore()
    ep = EpisodeInfo(task="bread/push_east", outcome="kept", start_time_ns=start_ns)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        for k, v in ep.to_custom_data().items():
            w.set_custom_data(k, v)
        js = w.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        for i, (t_ns, q) in enumerate(stamps_q):
            w.write(js, T0 + i, joint_state(t_ns, NAMES, q))  # received late: log times all after T0
    return path


def test_states_queued_before_the_start_are_dropped(tmp_path):
    """A recorder behind a fast simulation receives the previous episode's last states (another
    pose, stamped before the start) after the reset: they are not part of the episode."""
    old = [(T0 - 10**9 + i * 10**7, np.full(7, 1.0)) for i in range(50)]  # 1 s before the start
    new = [(T0 + i * 10**7, q_of(i * 0.01)) for i in range(101)]
    demo = load_demo(_joint_state_bag(tmp_path / "b", old + new, start_ns=T0))
    assert demo.t[-1] == pytest.approx(1.0) and np.allclose(demo.q[0], q_of(0.0))


def test_lost_states_and_jumps_are_reported(tmp_path):
    gap = [(T0 + i * 10**7, q_of(i * 0.01)) for i in range(101) if not 20 <= i < 90]  # 0.7 s lost
    with pytest.raises(DemoError, match="missing for 0.71 s at 0.2 s"):
        load_demo(_joint_state_bag(tmp_path / "gap", gap, start_ns=T0))
    jump = [(T0 + i * 10**7, q_of(i * 0.01) + (0.5 if i >= 50 else 0.0)) for i in range(101)]
    with pytest.raises(DemoError, match=r"jump by 0.5\d rad in 10 ms at 0.5 s"):
        load_demo(_joint_state_bag(tmp_path / "jump", jump, start_ns=T0))
    # the same stamps under another clock than the recorder's: read as they are
    other_clock = [(t - 3600 * 10**9, q) for t, q in gap[:20]]
    assert load_demo(_joint_state_bag(tmp_path / "clock", other_clock, start_ns=T0)).q.shape == (2, 7)


def test_bgr_images_come_out_rgb(tmp_path):
    ep = EpisodeInfo(task="bread/push_east", outcome="kept")
    demo = load_demo(write_rosbags_bag(tmp_path / "b", episode=ep, encoding="bgr8"))
    assert tuple(demo.first_image[1, 2]) == (1, 2, 3) and demo.first_image[0, 0, 0] == 200


def test_bag_from_our_writer_and_without_metadata(tmp_path):
    """Our own writer works too; a bag from another writer without episode metadata needs a task."""
    bag = BagWriter(tmp_path / "ours", EpisodeInfo(task="cereal_box/circle")).open()
    bag.add_topic("/joint_states", "sensor_msgs/msg/JointState")
    for i in range(11):
        bag.write("/joint_states", T0 + i * 10**8, joint_state(T0 + i * 10**8, NAMES, q_of(i * 0.1)))
    bag.close("kept")
    demo = load_demo(bag.path)
    assert demo.task == "cereal_box/circle" and len(demo.q) == 11 and demo.first_image is None
    plain = write_rosbags_bag(tmp_path / "plain")
    with pytest.raises(DemoError, match="no task"):
        load_demo(plain)
    assert load_demo(plain, task="bread/push_east").task == "bread/push_east"
    own = load_demo(plain, task="spam:push_south")  # an object of a lab's own catalogue
    assert (own.task, own.object_class) == ("spam/push_south", "spam")
    assert own.detection.class_id == "soda_can"  # no spam detected: the top detection


def test_the_context_is_timed_by_its_stamp_not_by_when_it_was_logged(tmp_path):
    """A detection of the frame at the start that the recorder logged 5 s late (generated at real-time
    factor 0 beside two busy loops) is the demo's context: its stamp says which scene it shows."""
    kept = EpisodeInfo(task="bread/push_east", outcome="kept")
    demo = load_demo(write_rosbags_bag(tmp_path / "late_log", episode=kept, detection_logged_after_s=5.0))
    assert demo.detection is not None and demo.detection.class_id == "bread"


def test_unusable_bags_are_reported_and_skipped(tmp_path):
    kept = EpisodeInfo(task="bread/push_east", outcome="kept")
    root = tmp_path / "demos"
    write_rosbags_bag(root / "ep1_good", episode=kept)
    write_rosbags_bag(root / "ep2_no_context", episode=kept, with_image=False, with_detection=False)
    write_rosbags_bag(root / "ep3_image_only", episode=kept, with_detection=False)
    discarded = EpisodeInfo(task="bread/push_east", outcome="discarded")
    write_rosbags_bag(root / "ep4_discarded", episode=discarded)
    write_rosbags_bag(root / "ep5_late_image", episode=kept, with_detection=False, image_delay_s=5.0)
    crashed = BagWriter(root / "ep6_crashed", EpisodeInfo(task="bread/push_east")).open()
    crashed.add_topic("/joint_states", "sensor_msgs/msg/JointState")
    crashed.flush()
    crashed.abort()

    demos, skipped = load_demos(root)
    reasons = {Path(p).name: r for p, r in skipped}
    assert sorted(Path(d.bag_path).name for d in demos) == ["ep1_good", "ep3_image_only"]
    assert "no usable context" in reasons["ep2_no_context"]
    assert "discarded" in reasons["ep4_discarded"]
    assert "after the start" in reasons["ep5_late_image"]
    assert "recover" in reasons["ep6_crashed"]

    demos, skipped = load_demos(root, require="detection")
    assert [Path(d.bag_path).name for d in demos] == ["ep1_good"]
    assert "no detection" in dict((Path(p).name, r) for p, r in skipped)["ep3_image_only"]
    with pytest.raises(ValueError, match="require"):
        load_demos(root, require="depth")

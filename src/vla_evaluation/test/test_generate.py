"""generate: simulated demonstrations through record.launch.yaml (bridge, detector, recorder) and the
demonstrator in the test's process."""
from pathlib import Path

import pytest
from vla_common.catalogue import default_catalogue, load_catalogue
from vla_demo_recorder.bag_writer import BagWriter, EpisodeInfo, read_metadata_yaml
from vla_demo_recorder.dataset import load_demo


def test_parse_tasks(tmp_path):
    from vla_evaluation.generate import parse_tasks

    cat = default_catalogue()
    f = tmp_path / "tasks.txt"
    f.write_text("# base\nsoda_can:push_south\n\ncereal_box/circle  # far\n")
    tasks = parse_tasks(["bread:push_east"], f, cat)
    assert [t.name for t in tasks] == ["bread/push_east", "soda_can/push_south", "cereal_box/circle"]
    assert tasks[0] is cat.task("bread/push_east")  # parsed once, travels as the TaskSpec
    assert len(parse_tasks([], None, cat)) == 4  # the base tasks
    with pytest.raises(ValueError, match="unknown object class"):
        parse_tasks(["spaceship:push_east"], None, cat)
    spam = load_catalogue(Path(__file__).resolve().parents[3] / "test" / "data" / "spam_catalogue.yaml")
    assert [t.name for t in parse_tasks(["spam/push_south_east"], None, spam)] == ["spam/push_south_east"]


@pytest.mark.slow
@pytest.mark.ros
def test_one_generated_episode_is_a_demo_bag(tmp_path):
    from vla_evaluation.generate import GenerateConfig, run_generation

    cfg = GenerateConfig(tasks=[default_catalogue().task("bread/push_east")], episodes=1,
                         out=tmp_path / "demos", seed=3, log_dir=tmp_path / "logs")
    records = run_generation(cfg, progress=lambda text: None)
    assert len(records) == 1
    rec = records[0]
    assert not rec.error, rec.error
    bag = Path(rec.bag)
    meta = read_metadata_yaml(bag)
    episode = EpisodeInfo.from_custom_data(meta["custom_data"])
    assert episode.task == "bread/push_east"
    assert episode.outcome == ("kept" if rec.success else "discarded")
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    assert counts["/camera/image_raw"] >= 1 and counts["/joint_states"] > 100
    assert (tmp_path / "demos" / "generate_report.json").exists()
    assert counts["/detections"] >= 1  # the detector node's, recorded like the camera
    if rec.success:
        demo = load_demo(bag)
        assert demo.first_image is not None and demo.first_image.shape == (480, 640, 3)
        assert demo.q.shape[1] == 7 and len(demo.q) > 20
        assert demo.detection is not None and rec.detection["class_id"] == demo.detection.class_id


@pytest.mark.slow
@pytest.mark.ros
def test_generated_pick_and_place_records_the_hand(tmp_path):
    """A pick-and-place through record.launch.yaml: the demonstrator opens and grasps through the
    bridge's ~/gripper, the object ends within 5 cm of its target, and the bag holds the finger
    joints and the grasp events (HOLDING the can, then open)."""
    from vla_evaluation.generate import GenerateConfig, run_generation

    cfg = GenerateConfig(tasks=[default_catalogue().task("soda_can/pick_place_west")], episodes=1,
                         out=tmp_path / "demos", seed=5, real_time_factor=0.0)
    rec = run_generation(cfg, progress=lambda text: None)[0]
    assert rec.success and rec.displacement < 0.05, (rec.error, rec.displacement)
    demo = load_demo(rec.bag)
    assert demo.hand is not None and demo.hand.max() > 0.075 and demo.hand.min() < 0.002
    states = [state for _t, state, _held in demo.grasp_events]
    held = [h for _t, state, h in demo.grasp_events if state == 3]
    assert 2 in states and held == ["soda_can"]           # GRASPING, then HOLDING the can
    assert states.index(3) < len(states) - 1               # ... and opened after


def _kept_bag(path: Path, detection: bool) -> Path:
    """A kept bag of 3 s of joint states, with or without a detection at its start."""
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState
    from vla_common.robot import JOINT_NAMES

    from vla_interfaces.msg import Detection, DetectionArray

    t0 = 1_700_000_000 * 10**9
    bag = BagWriter(path, EpisodeInfo(task="bread/push_east")).open()
    bag.add_topic("/joint_states", "sensor_msgs/msg/JointState")
    bag.add_topic("/detections", "vla_interfaces/msg/DetectionArray")
    if detection:
        msg = DetectionArray(image_width=640, image_height=480, detections=[Detection(
            class_id="bread", class_index=0, score=0.9, center_x=320.0, center_y=240.0,
            size_x=30.0, size_y=30.0)])
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t0, 10**9)
        bag.write("/detections", t0, serialize_message(msg))
    for i in range(60):
        t = t0 + i * 5 * 10**7
        js = JointState(name=list(JOINT_NAMES), position=[0.01 * i] * len(JOINT_NAMES))
        js.header.stamp.sec, js.header.stamp.nanosec = divmod(t, 10**9)
        bag.write("/joint_states", t, serialize_message(js))
    bag.close("kept")
    return bag.path


def test_a_kept_bag_without_a_detection_counts_as_refused(tmp_path):
    """Training skips a bag without a detection near its start, so generation must not count it as a
    demonstration (at real-time factor 0 such bags were kept as successes)."""
    from vla_evaluation.generate import loaded_detection, recording_problem

    problem, det = loaded_detection(_kept_bag(tmp_path / "no_det", detection=False))
    assert "no detection" in problem and det is None
    assert recording_problem(_kept_bag(tmp_path / "no_det2", detection=False))
    problem, det = loaded_detection(_kept_bag(tmp_path / "det", detection=True))
    assert problem == "" and det["class_id"] == "bread"


def test_plan_pace_slows_the_plan_clock_while_the_arm_lags():
    """The demonstrator's plan clock: full speed while the arm follows, stopped when it lags far
    behind (a loaded machine), so that the hand events come where the arm is."""
    from vla_evaluation.generate import PLAN_LAG, plan_pace

    lo, hi = PLAN_LAG
    assert plan_pace(0.0) == 1.0 and plan_pace(lo) == 1.0
    assert 0.0 < plan_pace((lo + hi) / 2) < 1.0
    assert plan_pace(hi) == 0.0 and plan_pace(1.0) == 0.0
    assert plan_pace(float("nan")) == 0.0


def test_the_last_frame_at_a_hold_comes_from_the_counts_since_the_reset():
    """Lockstep: the frame the recording waits for before it stops is known from the counts (frames at
    the reset's step and every round(1 / (camera_rate * unit)) steps), not from what has arrived: the
    held step's own frame may still be rendering when the hold is reported."""
    from vla_evaluation.generate import last_frame_stamp

    unit, rate, reset = 0.02, 5.0, 3.14          # 50 Hz states, a frame every 10 steps
    assert last_frame_stamp(reset, reset, unit, rate) == pytest.approx(reset)
    assert last_frame_stamp(reset + 9 * unit, reset, unit, rate) == pytest.approx(reset)
    assert last_frame_stamp(reset + 10 * unit, reset, unit, rate) == pytest.approx(reset + 0.2)  # its own
    assert last_frame_stamp(reset + 71 * unit, reset, unit, rate) == pytest.approx(reset + 1.4)

"""generate: simulated demonstrations through record.launch.yaml (bridge, detector, recorder) and the
demonstrator in the test's process."""
from pathlib import Path

import pytest
from vla_common.catalogue import default_catalogue, load_catalogue
from vla_demo_recorder.bag_writer import EpisodeInfo, read_metadata_yaml
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


def test_plan_pace_slows_the_plan_clock_while_the_arm_lags():
    """The demonstrator's plan clock: full speed while the arm follows, stopped when it lags far
    behind (a loaded machine), so that the hand events come where the arm is."""
    from vla_evaluation.generate import PLAN_LAG, plan_pace

    lo, hi = PLAN_LAG
    assert plan_pace(0.0) == 1.0 and plan_pace(lo) == 1.0
    assert 0.0 < plan_pace((lo + hi) / 2) < 1.0
    assert plan_pace(hi) == 0.0 and plan_pace(1.0) == 0.0
    assert plan_pace(float("nan")) == 0.0

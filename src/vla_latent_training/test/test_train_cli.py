"""`vla_latent_controller train` on real MCAP bags written like the recorder writes them."""

import json

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from vla_latent_controller.testing import CLASSES, make_demo
from vla_latent_training.cli import main

from vla_interfaces.msg import Detection, DetectionArray

T0 = 1_700_000_000 * 10**9


def write_bag(path, demo):
    from vla_demo_recorder.bag_writer import BagWriter, EpisodeInfo

    bag = BagWriter(path, EpisodeInfo(task=demo.task)).open()
    bag.add_topic("/joint_states", "sensor_msgs/msg/JointState")
    bag.add_topic("/detections", "vla_interfaces/msg/DetectionArray")
    d = demo.detection
    msg = DetectionArray(image_width=640, image_height=480)
    msg.detections = [
        Detection(
            class_id=d["class_id"],
            class_index=d["class_index"],
            score=0.9,
            center_x=d["cx"],
            center_y=d["cy"],
            size_x=30.0,
            size_y=30.0,
        )
    ]
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(T0, 10**9)
    bag.write("/detections", T0, serialize_message(msg))
    for i, q in enumerate(demo.q):
        t = T0 + i * 10**8
        js = JointState(name=[f"panda_joint{j}" for j in range(1, 8)], position=[float(v) for v in q])
        js.header.stamp.sec, js.header.stamp.nanosec = divmod(t, 10**9)
        bag.write("/joint_states", t, serialize_message(js))
    bag.close("kept")
    return bag.path


@pytest.mark.slow
def test_train_from_bags(tmp_path, capsys):
    rng = np.random.default_rng(0)
    tasks = {"bread": "bread/push_east", "soda_can": "soda_can/push_south"}
    for k, cls in enumerate(tasks):
        for i in range(2):
            demo = make_demo(cls, rng, T=30)
            demo.task = tasks[cls]
            write_bag(tmp_path / "demos" / f"ep{k}{i}", demo)
    (tmp_path / "demos" / "broken").mkdir()
    (tmp_path / "demos" / "broken" / "broken.mcap").write_bytes(b"\x89MCAP0\r\n" + b"junk" * 10)
    out = tmp_path / "model"
    rc = main(["train", "--bags", str(tmp_path / "demos"), "--out", str(out), "--epochs", "5", "--quiet",
               "--hidden", "16"])
    text = capsys.readouterr()
    assert rc == 0, text
    assert "loaded 4 demos" in text.out and "bread/push_east" in text.out and "gain" in text.out
    assert "broken" in text.err  # the unusable bag is named with its reason
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["dims"]["hidden"] == 16
    assert cfg["classes"] == list(CLASSES) and cfg["training"]["demos_per_task"] == {
        t: 2 for t in tasks.values()
    }
    assert (
        cfg["fingerprint"]["bags"] == ["ep00", "ep01", "ep10", "ep11"]
        and len(cfg["fingerprint"]["sha256"]) == 64
    )
    rc = main(
        [
            "train",
            "--bags",
            str(tmp_path / "demos"),
            "--out",
            str(tmp_path / "m2"),
            "--epochs",
            "2",
            "--quiet",
            "--task",
            "bread:push_east",
            "--max-per-task",
            "1",
            "--paper-exact",
        ]
    )
    assert rc == 0
    cfg2 = json.loads((tmp_path / "m2" / "config.json").read_text())
    assert (
        cfg2["training"]["demos_per_task"] == {"bread/push_east": 1}
        and cfg2["hyper_parameters"]["paper_exact"]
        and cfg2["dims"]["hidden"] == 30  # --paper-exact: the paper's 30 units
    )
    assert cfg2["fingerprint"]["sha256"] != cfg["fingerprint"]["sha256"]


def test_bad_position_scale_is_an_error(tmp_path, capsys):
    rng = np.random.default_rng(0)
    demo = make_demo("bread", rng, T=30)
    demo.task = "bread/push_east"
    write_bag(tmp_path / "demos" / "ep0", demo)
    args = ["train", "--bags", str(tmp_path / "demos"), "--out", str(tmp_path / "m"), "--quiet",
            "--epochs", "1"]
    for bad in ("wide", "-1", "0", "inf"):
        with pytest.raises(SystemExit) as e:
            main(args + ["--position-scale", bad])
        assert e.value.code == 2
        assert "--position-scale: must be 'demos' or a positive number" in capsys.readouterr().err
    for value, want in (([], None), (["--position-scale", "0.3"], 0.3)):  # default: the demos' spread
        assert main(args + value + ["--hidden", "8"]) == 0
        hp = json.loads((tmp_path / "m" / "config.json").read_text())["hyper_parameters"]
        assert hp["position_scale"] == want


def test_no_demos_is_an_error(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["train", "--bags", str(tmp_path / "empty"), "--out", str(tmp_path / "m"), "--quiet"]) == 1
    assert "no usable demonstrations" in capsys.readouterr().err

"""`vla_latent_training train` on real MCAP bags: written like the recorder writes them, and written by
rosbags (an independent writer) without episode metadata, as `ros2 bag record` leaves them."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from ament_index_python.packages import get_package_share_directory
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from sensor_msgs.msg import JointState
from vla_demo_recorder.bag_writer import BagWriter, EpisodeInfo
from vla_latent_controller.testing import CLASSES, make_demo
from vla_latent_training.cli import main

from vla_interfaces.msg import Detection, DetectionArray

T0 = 1_700_000_000 * 10**9


def write_bag(path, demo):
    bag = BagWriter(path, EpisodeInfo(task=demo.task)).open()
    bag.add_topic("/joint_states", "sensor_msgs/msg/JointState")
    bag.add_topic("/detections", "vla_interfaces/msg/DetectionArray")
    d = demo.detection
    msg = DetectionArray(image_width=640, image_height=480)
    msg.detections = [
        Detection(
            class_id=d.class_id,
            class_index=d.class_index,
            score=0.9,
            center_x=d.cx,
            center_y=d.cy,
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


def _typestore():
    """rosbags' Jazzy types plus vla_interfaces' Detection messages, from the installed .msg files."""
    ts = get_typestore(Stores.ROS2_JAZZY)
    share = Path(get_package_share_directory("vla_interfaces")) / "msg"
    for name in ("Detection", "DetectionArray"):
        ts.register(get_types_from_msg((share / f"{name}.msg").read_text(), f"vla_interfaces/msg/{name}"))
    return ts


def write_recorded_bag(path, demo, cls_index):
    """A bag as `ros2 bag record /joint_states /detections` writes it: no episode metadata."""
    ts = _typestore()
    t = ts.types
    header = lambda ns: t["std_msgs/msg/Header"](  # noqa: E731
        stamp=t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9), frame_id="")
    d = demo.detection
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        js = w.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        det = w.add_connection("/detections", "vla_interfaces/msg/DetectionArray", typestore=ts)
        box = t["vla_interfaces/msg/Detection"](class_id=d.class_id, class_index=cls_index, score=0.9,
                                                center_x=d.cx, center_y=d.cy, size_x=30.0, size_y=30.0)
        msg = t["vla_interfaces/msg/DetectionArray"](header=header(T0), image_width=640, image_height=480,
                                                     detections=[box])
        w.write(det, T0, ts.serialize_cdr(msg, "vla_interfaces/msg/DetectionArray"))
        for i, q in enumerate(demo.q):
            ns = T0 + i * 10**8
            state = t["sensor_msgs/msg/JointState"](
                header=header(ns), name=[f"panda_joint{j}" for j in range(1, 8)],
                position=np.asarray(q, np.float64), velocity=np.zeros(0), effort=np.zeros(0))
            w.write(js, ns, ts.serialize_cdr(state, "sensor_msgs/msg/JointState"))
    return path


def test_bags_without_episode_metadata_train_with_one_task(tmp_path, capsys):
    rng = np.random.default_rng(0)
    for i in range(2):
        write_recorded_bag(tmp_path / "recorded" / f"rec{i}", make_demo("bread", rng, T=30), 0)
    args = ["train", "--bags", str(tmp_path / "recorded"), "--epochs", "1", "--hidden", "8", "--quiet"]
    assert main(args + ["--out", str(tmp_path / "none")]) == 1  # no task: each bag says why
    err = capsys.readouterr().err
    assert "no episode metadata and no task was given" in err and "--default-task" in err
    assert main(args + ["--out", str(tmp_path / "m"), "--task", "bread/push_east"]) == 0
    cfg = json.loads((tmp_path / "m" / "config.json").read_text())
    assert cfg["training"]["demos_per_task"] == {"bread/push_east": 2}
    assert cfg["fingerprint"]["bags"] == ["rec0", "rec1"]
    assert main(args + ["--out", str(tmp_path / "x"), "--task", "bread/push_nowhere"]) == 2
    assert "bread has no task 'push_nowhere'" in capsys.readouterr().err


def test_pairs_reads_untagged_bags_with_a_task(tmp_path, capsys):
    write_recorded_bag(tmp_path / "recorded" / "rec0", make_demo("bread", np.random.default_rng(3), T=30), 0)
    assert main(["pairs", str(tmp_path / "recorded")]) == 1
    assert "no task was given" in capsys.readouterr().out
    assert main(["pairs", str(tmp_path / "recorded"), "--task", "bread:push_east"]) == 0
    out = capsys.readouterr().out
    assert "bread/push_east, 30 samples at 10 Hz" in out and "1 demos, 0 skipped" in out


def test_transfer_is_base_bags_plus_new_untagged_ones(tmp_path):
    """The paper's transfer variant: all base demonstrations plus k new ones, in one model."""
    rng = np.random.default_rng(1)
    for i, (cls, task) in enumerate((("bread", "bread/push_east"), ("soda_can", "soda_can/push_south"))):
        demo = make_demo(cls, rng, T=30)
        demo.task = task
        write_bag(tmp_path / "base" / f"ep{i}", demo)
    for i in range(2):
        write_recorded_bag(tmp_path / "new" / f"new{i}", make_demo("cereal_box", rng, T=30), 4)
    rc = main(["train", "--bags", str(tmp_path / "base"), str(tmp_path / "new"), "--default-task",
               "cereal_box/push_south", "--out", str(tmp_path / "m"), "--epochs", "1", "--hidden", "8",
               "--quiet"])
    assert rc == 0
    cfg = json.loads((tmp_path / "m" / "config.json").read_text())
    assert cfg["training"]["demos_per_task"] == {
        "bread/push_east": 1, "soda_can/push_south": 1, "cereal_box/push_south": 2}
    assert set(cfg["latent"]["gain"]) == {"bread", "soda_can", "cereal_box"}


def test_catalogue_brings_new_classes_and_tasks(tmp_path, capsys):
    (tmp_path / "lab.yaml").write_text(
        "extends: default\n"
        "objects:\n"
        "  teapot: {shape: cylinder, size: [0.06, 0.06, 0.12], rgba: [0.9, 0.9, 0.2, 1.0], mass: 0.4,\n"
        "           friction: 0.5, tasks: [push_north]}\n")
    rng = np.random.default_rng(2)
    demo = make_demo("bread", rng, T=30)
    demo.detection = replace(demo.detection, class_id="teapot", class_index=5)
    write_recorded_bag(tmp_path / "recorded" / "rec0", demo, 5)
    args = ["train", "--bags", str(tmp_path / "recorded"), "--task", "teapot/push_north", "--epochs", "1",
            "--hidden", "8", "--quiet"]
    assert main(args + ["--out", str(tmp_path / "no")]) == 2  # the default catalogue has no teapot
    assert "unknown object class 'teapot'" in capsys.readouterr().err
    assert main(args + ["--out", str(tmp_path / "m"), "--catalogue", str(tmp_path / "lab.yaml")]) == 0
    cfg = json.loads((tmp_path / "m" / "config.json").read_text())
    assert cfg["classes"] == [*CLASSES, "teapot"]
    assert cfg["training"]["demos_per_task"] == {"teapot/push_north": 1}


def test_recovered_episodes_are_left_out_unless_asked_and_training_says_which(tmp_path, capsys):
    """Issue 20 item 11: training says what it does with recovered (and interrupted) episodes."""
    rng = np.random.default_rng(4)
    for i in range(3):
        demo = make_demo("bread", rng, T=30)
        demo.task = "bread/push_east"
        bag = write_bag(tmp_path / "demos" / f"ep{i}", demo)
    meta = bag / "metadata.yaml"  # the last one: what `recover` leaves of a file cut short
    meta.write_text(meta.read_text().replace("episode.outcome: kept", "episode.outcome: recovered"))
    args = ["train", "--bags", str(tmp_path / "demos"), "--epochs", "1", "--hidden", "8", "--quiet"]
    assert main(args + ["--out", str(tmp_path / "m")]) == 0
    out = capsys.readouterr()
    assert "loaded 2 demos" in out.out and f"skipped {bag}: episode outcome is 'recovered'" in out.err
    assert "left out 1 incomplete episodes" in out.err and "--include-incomplete trains on them" in out.err
    assert main(args + ["--out", str(tmp_path / "all"), "--include-incomplete"]) == 0
    out = capsys.readouterr()
    assert "loaded 3 demos" in out.out and "training on 1 incomplete demos" in out.err


def test_the_cli_defaults_are_train_configs():
    """TrainConfig declares the recipe's defaults once; the CLI passes them through unchanged."""
    import argparse

    from vla_latent_training.config import TrainConfig
    from vla_latent_training.train_cli import add_arguments, train_config

    p = argparse.ArgumentParser()
    add_arguments(p)
    assert train_config(p.parse_args(["--bags", "b", "--out", "o"])) == TrainConfig()
    assert train_config(p.parse_args(["--bags", "b", "--out", "o", "--paper-exact"])) == TrainConfig.paper()
    assert train_config(p.parse_args(["--bags", "b", "--out", "o", "--hidden", "64"])).hidden == 64

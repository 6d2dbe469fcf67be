"""The controller node in-process: topics, services, parameters, zero on every problem."""

import dataclasses
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
import yaml
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from require import missing
from sensor_msgs.msg import Image, JointState, Joy
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger
from vla_common.ros.context import end_context
from vla_common.ros.node_main import ConfigError, StartupError
from vla_common.ros.testing import RosHarness
from vla_latent_controller.controller_node import PARAMETERS, ControllerNode, _core_value
from vla_latent_controller.teleop import TeleopParams
from vla_latent_controller.testing import CLASSES, READY, make_demos, make_pairs, write_random_model
from vla_launch.run import RunError, find_executable

from vla_interfaces.msg import ControllerStatus, Detection, DetectionArray
from vla_interfaces.srv import SetMode

pytestmark = pytest.mark.ros
NAMES = [f"panda_joint{i}" for i in range(1, 8)]


class Harness(RosHarness):
    """The node under test and an io node that plays joystick, robot and detector."""

    def __init__(self, model_dir, **params):
        super().__init__()
        overrides = [Parameter("model_path", value=str(model_dir) if model_dir else "")]
        overrides += [Parameter(k, value=v) for k, v in params.items()]
        try:
            self.node = self.add(ControllerNode(context=self.context, parameter_overrides=overrides))
        except Exception:
            self.shutdown()
            raise
        self.io = self.add(rclpy.create_node("controller_test_io", context=self.context))
        self.joy = self.io.create_publisher(Joy, "joy", 10)
        self.js = self.io.create_publisher(JointState, "joint_states", 10)
        self.det = self.io.create_publisher(DetectionArray, "detections", 10)
        self.cmds, self.status = [], []
        self.io.create_subscription(
            Float64MultiArray, "joint_velocity_cmd", lambda m: self.cmds.append(m.data), 10
        )
        self.io.create_subscription(ControllerStatus, "controller_node/status", self.status.append, 10)
        self.spin_until(lambda: all(p.get_subscription_count() > 0 for p in (self.joy, self.js, self.det)))
        self.spin_until(lambda: self.cmds)

    def send(self, axis=0.8, names=NAMES, q=READY, dets=(("bread", 320.0, 240.0),)):
        js = JointState(name=list(names), position=[float(v) for v in q])
        js.header.stamp = self.io.get_clock().now().to_msg()
        self.js.publish(js)
        if dets is not None:
            msg = DetectionArray(image_width=640, image_height=480)
            msg.detections = [Detection(class_id=c, score=0.9, center_x=x, center_y=y) for c, x, y in dets]
            self.det.publish(msg)
        if axis is not None:
            self.joy.publish(Joy(axes=[float(axis), 0.0], buttons=[0, 0]))

    def settle(self, code, **send):
        """Keep inputs fresh until the status reports `code`; the command of that same tick (the one the
        status names, published just before it: a later one may already be a joy timeout's zero on a
        loaded machine). Like an operator, it returns the stick to neutral when the controller asks for
        it (AWAITING_NEUTRAL). 60 s of wall time only against a hang."""
        end = time.monotonic() + 60.0
        while time.monotonic() < end:
            asked = self.status and self.status[-1].code == ControllerStatus.AWAITING_NEUTRAL
            release = asked and code != ControllerStatus.AWAITING_NEUTRAL
            self.send(**{**send, "axis": 0.0} if release else send)
            self.status.clear()
            self.spin_until(lambda: self.status, timeout=0.05)
            if self.status and self.status[-1].code == code:
                st = self.status[-1]
                assert self.spin_until(lambda st=st: self._sent_with(st) is not None, timeout=60.0), st
                return st, self._sent_with(st)

        raise AssertionError(f"status never {code}: {self.status[-1:] if self.status else 'none'}")

    def _sent_with(self, st: ControllerStatus) -> np.ndarray | None:
        """The last command published with the values `st` names (its tick's), or None."""
        want = np.asarray(st.command, float)
        return next((np.array(c) for c in reversed(self.cmds) if np.array_equal(np.array(c), want)), None)

    def call_service(self, srv_type, name, req):
        return self.call(self.io.create_client(srv_type, name), req)

    def close(self):
        self.shutdown()


@pytest.fixture
def harness(random_model_dir):
    h = Harness(random_model_dir)
    yield h
    h.close()


def test_latent_command_deadband_and_status(harness):
    st, cmd = harness.settle(ControllerStatus.ACTIVE)
    assert np.linalg.norm(cmd) > 0 and st.latched_class == "bread" and st.mode == "latent"
    assert st.latched_x == pytest.approx(0.5) and st.header.frame_id
    st, cmd = harness.settle(ControllerStatus.ZERO_DEADBAND, axis=0.05)
    assert np.all(cmd == 0.0)


@pytest.mark.parametrize("centre", [(1e6, -1e6), (-50.0, 240.0)])
def test_a_detection_outside_the_image_gives_zero_and_bad_input(harness, centre):
    """Issue 20 item 8: a detection at (1e6, -1e6) or -50 px in a 640x480 image drove the arm at
    0.28-0.33 rad/s; now the command stays zero with BAD_INPUT until a detection in the image comes."""
    st, cmd = harness.settle(ControllerStatus.BAD_INPUT, axis=1.0, dets=(("bread", *centre),))
    assert np.all(cmd == 0.0) and "outside the 640x480 image" in st.reason and st.latched_class == ""
    assert all(not any(c) for c in harness.cmds)
    st, cmd = harness.settle(ControllerStatus.ACTIVE, axis=1.0)
    assert np.linalg.norm(cmd) > 0 and st.latched_x == pytest.approx(0.5)


def test_bad_inputs_give_zero_and_status(harness):
    st, cmd = harness.settle(ControllerStatus.MODEL_ERROR, names=NAMES[:6], q=READY[:6])
    assert "lack panda_joint7" in st.reason and np.all(cmd == 0.0)
    st, cmd = harness.settle(ControllerStatus.BAD_INPUT, axis=float("nan"))
    assert "not a finite" in st.reason and np.all(cmd == 0.0)
    st, cmd = harness.settle(ControllerStatus.ACTIVE)
    st, cmd = harness.settle(ControllerStatus.JOY_TIMEOUT, axis=None)
    assert np.all(cmd == 0.0)


def test_services_and_parameters(harness):
    harness.settle(ControllerStatus.ACTIVE)
    r = harness.call_service(Trigger, "controller_node/redetect", Trigger.Request())
    assert r.success
    st, cmd = harness.settle(ControllerStatus.WAITING_FOR_DETECTION, dets=None)
    assert np.all(cmd == 0.0) and st.latched_class == ""
    st, _ = harness.settle(ControllerStatus.ACTIVE, dets=[("milk_carton", 100.0, 100.0)])
    assert st.latched_class == "milk_carton"
    r = harness.call_service(SetMode, "controller_node/set_mode", SetMode.Request(mode="joint"))
    assert not r.success and "unknown mode" in r.message
    r = harness.call_service(SetMode, "controller_node/set_mode", SetMode.Request(mode="end_effector"))
    assert r.success
    st, cmd = harness.settle(ControllerStatus.ACTIVE)
    assert st.mode == "end_effector" and st.ee_axis == "x" and np.linalg.norm(cmd) > 0
    res = harness.node.set_parameters([Parameter("ee_linear_speed", value=0.05)])
    assert res[0].successful and harness.node.core.ee.linear_speed == 0.05
    res = harness.node.set_parameters([Parameter("deadband", value=0.9)])
    assert res[0].successful
    harness.settle(ControllerStatus.ZERO_DEADBAND)
    res = harness.node.set_parameters([Parameter("deadband", value=2.0)])
    assert not res[0].successful  # outside the descriptor's range
    res = harness.node.set_parameters([Parameter("rate", value=10.0)])
    assert not res[0].successful


def test_services_and_parameters_agree(harness):
    r = harness.call_service(SetMode, "controller_node/set_mode", SetMode.Request(mode="end_effector"))
    assert r.success and harness.node.get_parameter("mode").value == "end_effector"
    r = harness.call_service(SetMode, "controller_node/set_mode", SetMode.Request(mode="joint"))
    assert not r.success and harness.node.get_parameter("mode").value == "end_effector"
    res = harness.node.set_parameters([Parameter("mode", value="latent")])
    assert res[0].successful and harness.node.core.mode == "latent"


def test_an_unknown_goal_selection_is_refused_with_the_valid_ones(harness, random_model_dir):
    res = harness.node.set_parameters([Parameter("goal_selection", value="teapot")])
    assert not res[0].successful
    assert "highest_score" in res[0].reason and "milk_carton" in res[0].reason
    assert harness.node.get_parameter("goal_selection").value == "highest_score"
    for ok in ("milk_carton", "nearest_to_ee", "highest_score"):
        assert harness.node.set_parameters([Parameter("goal_selection", value=ok)])[0].successful
    with pytest.raises(ConfigError, match="goal_selection"):
        Harness(random_model_dir, goal_selection="teapot")


def test_a_model_without_the_goal_class_is_refused(harness, tmp_path):
    assert harness.node.set_parameters([Parameter("goal_selection", value="bread")])[0].successful
    other = write_random_model(tmp_path / "fruit", classes=("apple", "pear"))
    res = harness.node.set_parameters([Parameter("model_path", value=str(other))])
    assert not res[0].successful and "bread" in res[0].reason


FR3 = [f"fr3_joint{i}" for i in range(1, 8)]


def test_a_panda_model_on_an_fr3_needs_a_joint_map(random_model_dir):
    h = Harness(random_model_dir)
    try:
        _, ref = h.settle(ControllerStatus.ACTIVE)
    finally:
        h.close()
    h = Harness(random_model_dir)
    try:
        st, cmd = h.settle(ControllerStatus.MODEL_ERROR, names=FR3)
        assert "lack panda_joint1" in st.reason and "joint_map" in st.reason and np.all(cmd == 0.0)
        res = h.node.set_parameters([Parameter("joint_map", value=["fr3_joint1"])])
        assert not res[0].successful and "robot_joint:model_joint" in res[0].reason
        mapping = [f"fr3_joint{i}:panda_joint{i}" for i in range(1, 8)]
        assert h.node.set_parameters([Parameter("joint_map", value=mapping)])[0].successful
        order = [6, 5, 4, 3, 2, 1, 0]  # an FR3 driver that lists its joints backwards
        st, cmd = h.settle(ControllerStatus.ACTIVE, names=[FR3[i] for i in order], q=READY[order])
        np.testing.assert_allclose(cmd, ref[order], rtol=1e-12)
    finally:
        h.close()
    h = Harness(random_model_dir, joint_map=mapping)  # also from the start (a parameter file)
    try:
        st, cmd = h.settle(ControllerStatus.ACTIVE, names=FR3)
        np.testing.assert_allclose(cmd, ref, rtol=1e-12)
    finally:
        h.close()


CONTROLLER_YAML = Path(__file__).resolve().parents[2] / "vla_bringup" / "config" / "controller.yaml"


def test_the_shipped_parameter_file_names_declared_parameters_and_loads():
    values = yaml.safe_load(CONTROLLER_YAML.read_text())["/**"]["ros__parameters"]
    assert set(values) <= set(PARAMETERS.params), set(values) - set(PARAMETERS.params)
    h = RosHarness()
    try:
        node = h.add(ControllerNode(context=h.context, cli_args=["--ros-args", "--params-file",
                                                                    str(CONTROLLER_YAML)]))
        for name, value in values.items():
            if value == []:  # an empty array parameter is declared by type only: it reads as unset
                continue
            assert node.get_parameter(name).value == value, name
        assert node.core.joint_map == {}
    finally:
        h.shutdown()


def test_every_parameter_has_a_readme_row():
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    missing = [p.name for p in PARAMETERS if f"| `{p.name}` |" not in readme]
    assert not missing, f"README lacks parameter rows for {missing}"


def test_the_core_parameters_are_declared_with_the_cores_defaults():
    """One declaration of each default: TeleopParams's; the table reads it (issue 21 item 10)."""
    core = TeleopParams()
    fields = [f for f in dataclasses.fields(TeleopParams) if f.name != "dq_max"]  # from the robot
    assert {f.name for f in fields} <= set(PARAMETERS.params)
    for f in fields:
        assert _core_value(f.name, PARAMETERS.params[f.name].default) == getattr(core, f.name), f.name


def test_a_model_that_does_not_load_stops_the_node_at_startup(tmp_path):
    (tmp_path / "config.json").write_text("{broken")
    with pytest.raises(StartupError, match="corrupt JSON"):
        Harness(tmp_path)


def test_a_failed_reload_keeps_the_model_and_refuses_the_parameter(harness, tmp_path):
    before = harness.node.core.model
    (tmp_path / "config.json").write_text("{broken")
    res = harness.node.set_parameters([Parameter("model_path", value=str(tmp_path))])
    assert not res[0].successful and "corrupt JSON" in res[0].reason
    assert harness.node.core.model is before
    assert harness.node.get_parameter("model_path").value != str(tmp_path)
    harness.settle(ControllerStatus.ACTIVE)
    other = write_random_model(tmp_path / "other", seed=3)
    res = harness.node.set_parameters([Parameter("model_path", value=str(other))])
    assert res[0].successful and harness.node.core.model.artifacts.path == other


def _installed(exe: str) -> str:
    try:
        return find_executable("vla_latent_controller", exe)
    except RunError as err:
        missing("SETUP", f"{exe}: {err} (run make setup)")


@pytest.mark.slow
def test_process_publishes_zero_on_shutdown(random_model_dir):
    exe = _installed("controller_node")
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("shutdown_probe", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    cmds = []
    node.create_subscription(Float64MultiArray, "joint_velocity_cmd", lambda m: cmds.append(list(m.data)), 10)
    joy = node.create_publisher(Joy, "joy", 10)
    js = node.create_publisher(JointState, "joint_states", 10)
    det = node.create_publisher(DetectionArray, "detections", 10)
    codes = []
    node.create_subscription(ControllerStatus, "controller_node/status", lambda m: codes.append(m.code), 10)
    proc = subprocess.Popen(
        [str(exe), "--ros-args", "-p", f"model_path:={random_model_dir}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env=os.environ.copy(),
    )
    try:
        end = time.monotonic() + 30
        active = False
        while time.monotonic() < end and not active:
            js.publish(JointState(name=NAMES, position=list(READY)))
            msg = DetectionArray(image_width=640, image_height=480)
            msg.detections = [Detection(class_id="bread", score=0.9, center_x=320.0, center_y=240.0)]
            det.publish(msg)
            at_neutral = ControllerStatus.ZERO_DEADBAND in codes     # armed: the operator was at neutral
            joy.publish(Joy(axes=[0.9 if at_neutral else 0.0], buttons=[]))
            ex.spin_once(timeout_sec=0.02)
            active = bool(cmds) and any(v != 0.0 for v in cmds[-1])
        assert active, "controller never commanded motion"
        proc.send_signal(signal.SIGINT)
        t = time.monotonic()
        while time.monotonic() - t < 5:  # keep the stick pushed: the last command must still be zero
            joy.publish(Joy(axes=[0.9], buttons=[]))
            ex.spin_once(timeout_sec=0.02)
            if proc.poll() is not None:
                break
        for _ in range(20):
            ex.spin_once(timeout_sec=0.02)
        assert proc.wait(timeout=10) == 0
        assert cmds[-1] == [0.0] * 7
    finally:
        if proc.poll() is None:
            proc.kill()
        ex.shutdown()
        node.destroy_node()
        end_context(ctx)


@pytest.mark.slow
def test_image_encoder_latches_a_camera_frame(tmp_path):
    pytest.importorskip("vla_latent_training", reason="the image-encoder model is trained here (torch)")
    from vla_latent_training.train import TrainConfig, train_model

    demos = make_demos(per_class=1, with_image=True, T=20)
    res = train_model(
        demos,
        TrainConfig(encoder="end_to_end", epochs=3),
        classes=CLASSES,
        pairs_fn=make_pairs,
        progress=False,
        threads=1,
        log=lambda s: None,
    )
    h = Harness(res.save(tmp_path / "e2e"))
    try:
        st, cmd = h.settle(ControllerStatus.WAITING_FOR_DETECTION, dets=None)
        assert "camera image" in st.reason and np.all(cmd == 0.0)
        pub = h.io.create_publisher(Image, "camera/image_raw", 10)
        img = demos[0].first_image
        msg = Image(
            height=img.shape[0],
            width=img.shape[1],
            encoding="rgb8",
            step=img.shape[1] * 3,
            data=img.tobytes(),
        )
        h.spin_until(lambda: pub.get_subscription_count() > 0)
        for _ in range(5):
            pub.publish(msg)
            h.spin_until(lambda: False, timeout=0.02)
        st, cmd = h.settle(ControllerStatus.ACTIVE, dets=None)
        assert np.linalg.norm(cmd) > 0 and st.latched_class == ""
    finally:
        h.close()


@pytest.mark.slow
def test_process_exits_non_zero_when_its_model_does_not_load(tmp_path):
    exe = _installed("controller_node")
    (tmp_path / "config.json").write_text("{broken")
    r = subprocess.run([str(exe), "--ros-args", "-p", f"model_path:={tmp_path}"], capture_output=True,
                       text=True, timeout=30, env=os.environ.copy())
    assert r.returncode == 1 and "corrupt JSON" in r.stderr and "Traceback" not in r.stderr


def _start_and_wait(exe: str, model_dir, *args: str):
    """Start the node process and a probe that subscribes to its command; return when it is up."""
    probe = RosHarness(other_processes=True)
    node = probe.add(rclpy.create_node("signal_probe", context=probe.context))
    cmds = []
    node.create_subscription(Float64MultiArray, "joint_velocity_cmd", lambda m: cmds.append(list(m.data)), 10)
    proc = subprocess.Popen(
        [str(exe), "--ros-args", "-p", f"model_path:={model_dir}", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=os.environ.copy(),
    )
    up = probe.spin_until(lambda: node.count_publishers("joint_velocity_cmd") > 0, timeout=30)
    # discovery both ways, so the zero command on shutdown reaches the probe: an answer of the node's
    # parameter service (its executor answers even without /clock) proves it has discovered us
    up = up and probe.discovered_by(node, "/controller_node")
    return proc, probe, cmds, up


@pytest.mark.slow
@pytest.mark.parametrize(
    "sig, twice", [(signal.SIGINT, False), (signal.SIGTERM, False), (signal.SIGINT, True)]
)
def test_process_stops_on_a_signal_with_sim_time_and_no_clock(random_model_dir, sig, twice):
    """With use_sim_time and no /clock no timer ever fires; the node must still stop on the first signal,
    send the zero command, exit 0, and a second signal during cleanup prints no traceback."""
    exe = _installed("controller_node")
    proc, probe, cmds, up = _start_and_wait(exe, random_model_dir, "-p", "use_sim_time:=true")
    try:
        assert up, "controller_node never came up"
        t0 = time.monotonic()
        proc.send_signal(sig)
        if twice:  # once its on_shutdown sent the zero: during cleanup (a no-op if it has already exited)
            probe.spin_until(lambda: cmds and cmds[-1] == [0.0] * 7, timeout=5.0)
            proc.send_signal(sig)
        try:
            code = proc.wait(timeout=10)  # a hang detector; the node itself takes about 0.1 s
        except subprocess.TimeoutExpired:
            pytest.fail("controller_node ignored the signal with use_sim_time and no /clock")
        elapsed = time.monotonic() - t0
        probe.spin_until(lambda: cmds, timeout=2.0)
        stderr = proc.stderr.read()
        assert code == 0, stderr
        assert "Traceback" not in stderr, stderr
        assert cmds and cmds[-1] == [0.0] * 7, f"no zero command on shutdown ({elapsed:.2f} s)"
    finally:
        if proc.poll() is None:
            proc.kill()
        probe.shutdown()


def test_under_sim_time_inputs_before_the_first_clock_are_not_aged_from_zero(random_model_dir):
    """Joint states that arrive before /clock were stored at t = 0, and the first status said they were
    1796169897 s old once the clock started at an epoch time: they are not stored until the clock runs."""
    from rosgraph_msgs.msg import Clock

    h = Harness.__new__(Harness)
    RosHarness.__init__(h)
    try:
        node = h.add(ControllerNode(context=h.context, parameter_overrides=[
            Parameter("model_path", value=str(random_model_dir)), Parameter("use_sim_time", value=True)]))
        io = h.add(rclpy.create_node("sim_clock_io", context=h.context))
        js = io.create_publisher(JointState, "joint_states", 10)
        clock = io.create_publisher(Clock, "/clock", 10)
        status = []
        io.create_subscription(ControllerStatus, "controller_node/status", status.append, 10)
        assert h.spin_until(lambda: js.get_subscription_count() and clock.get_subscription_count())
        heard = []
        io.create_subscription(JointState, "joint_states", heard.append, 10)
        js.publish(JointState(name=NAMES, position=[float(v) for v in READY]))
        assert h.spin_until(lambda: heard)  # delivered to io, and so to the node's subscription too
        for _ in range(5):
            h.executor.spin_once(timeout_sec=0.01)
        assert node.core._js.t == -np.inf  # before /clock: not stored at t = 0
        t = Clock()
        t.clock.sec = 1_796_169_897
        clock.publish(t)
        assert h.spin_until(lambda: status)
        assert "1796169897" not in status[0].reason and status[0].header.frame_id == "panda_link0"
    finally:
        h.shutdown()


# -- a parameter dump loads back (issue 32 item 10) ----------------------------------------------------

def dump_as_ros2_param_does(node) -> str:
    """What `ros2 param dump` writes for `node` (ros2cli 0.32: every listed parameter's value through
    rclpy's parameter_value_to_python, dotted names nested, `yaml.dump(..., default_flow_style=False)`)."""
    from rclpy.parameter import parameter_value_to_python
    params: dict = {}
    for name in sorted(node.list_parameters([], 0).names):
        *parents, last = name.split(".")
        where = params
        for part in parents:
            where = where.setdefault(part, {})
        where[last] = parameter_value_to_python(node.get_parameter(name).get_parameter_value())
    return yaml.dump({node.get_fully_qualified_name(): {"ros__parameters": params}}, default_flow_style=False)


def test_a_parameter_dump_loads_back_with_the_same_values(harness, tmp_path):
    """`ros2 param dump /controller_node > f.yaml`, then `--params-file f.yaml`: rcl must read it and the
    node start with the same values. ee_axes was a string list, dumped `- x - y`, and rcl reads a bare y
    as true: the dump did not load. A list set at run time (the study sets one) is stored as the text."""
    res = harness.node.set_parameters([Parameter("ee_axes", value=["x", "y", "z"])])
    assert res[0].successful and harness.node.get_parameter("ee_axes").value == "x,y,z"
    assert harness.node.core.params.ee_axes == ["x", "y", "z"]
    dumped = tmp_path / "dump.yaml"
    dumped.write_text(dump_as_ros2_param_does(harness.node))
    h = RosHarness()
    try:
        node = h.add(ControllerNode(context=h.context, cli_args=["--ros-args", "--params-file", str(dumped)]))
        for name in harness.node.list_parameters([], 0).names:
            assert node.get_parameter(name).value == harness.node.get_parameter(name).value, name
        assert node.core.params.ee_axes == ["x", "y", "z"]
    finally:
        h.shutdown()


@pytest.mark.parametrize("given", [
    ["-p", "ee_axes:=x,y,z"], ["-p", "ee_axes:=x, y, z"],  # the README's forms
    ["--params-file", "OLD"],                              # a file of the older form: a quoted list
])
def test_ee_axes_from_the_command_line_and_an_older_file(random_model_dir, tmp_path, given):
    old = tmp_path / "old.yaml"
    old.write_text('/**:\n  ros__parameters:\n    ee_axes: ["x", "y", "z"]\n')
    h = RosHarness()
    try:
        args = ["--ros-args", "-p", f"model_path:={random_model_dir}", *[str(old) if a == "OLD" else a
                                                                          for a in given]]
        node = h.add(ControllerNode(context=h.context, cli_args=args))
        assert node.get_parameter("ee_axes").value in ("x,y,z", "x, y, z")
        assert node.core.params.ee_axes == ["x", "y", "z"]
        for bad in ("x,x", "x,up", "", ["x", "x"]):
            res = node.set_parameters([Parameter("ee_axes", value=bad)])[0]
            assert not res.successful and "needs distinct axes" in res.reason, bad
    finally:
        h.shutdown()


def test_the_assistance_is_set_at_run_time_and_the_status_names_its_goal_at_once():
    """Issue 34: the caregiver's level reaches the core at once; the status carries the inferred goal,
    published when it changes (the status rate here is one per 10 s)."""
    from sensor_msgs.msg import CameraInfo
    from vla_common.camera_model import SIM_WEBCAM

    h = Harness(Path(__file__).resolve().parents[1] / "models" / "default", status_rate=0.1)
    try:
        said = []   # every status from here on
        h.io.create_subscription(ControllerStatus, "controller_node/status", said.append, 100)
        info = h.io.create_publisher(CameraInfo, "camera/camera_info", 10)
        fx, fy, cx, cy = SIM_WEBCAM.intrinsics(640, 480)
        u, v = SIM_WEBCAM.projector(640, 480)([0.5, 0.05, 0.04])   # a loaf on the table
        bad = h.node.set_parameters([Parameter("assistance", value="max")])
        assert not bad[0].successful and h.node.core.params.assistance == "off"
        st, _ = h.settle(ControllerStatus.ACTIVE, dets=(("bread", u, v),))
        assert st.assistance == "off" and st.goal_task == ""
        assert h.node.set_parameters([Parameter("assistance", value="high")])[0].successful
        assert h.node.core.params.assistance == "high"
        info.publish(CameraInfo(width=640, height=480, k=[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]))
        h.spin_until(lambda: h.node._intrinsics is not None)
        st, cmd = h.settle(ControllerStatus.ACTIVE, axis=1.0, dets=(("bread", u, v),))
        for _ in range(20):   # a few ticks until the detections and the camera are both in
            if st.goal_task:
                break
            st, cmd = h.settle(ControllerStatus.ACTIVE, axis=1.0, dets=(("bread", u, v),))
        assert st.assistance == "high" and st.goal_task == "bread/push_east" and st.goal_stage == "hover"
        # published when the goal appeared: less than the 10 s period after the status before it (the
        # level's change), which only a change gives
        assert h.spin_until(lambda: any(m.goal_task for m in said), timeout=60.0)
        first = next(i for i, m in enumerate(said) if m.goal_task)
        t = [m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for m in said[max(first - 1, 0):first + 1]]
        assert first > 0 and t[1] - t[0] < 10.0, t
        assert st.goal_x == pytest.approx(0.5, abs=1e-3) and st.goal_y == pytest.approx(0.05, abs=1e-3)
        assert 0.5 < st.goal_confidence <= 1.0 and st.goal_share > 0.0
        st, cmd = h.settle(ControllerStatus.ZERO_DEADBAND, axis=0.0, dets=(("bread", u, v),))
        assert np.all(cmd == 0.0) and st.goal_share == 0.0 and st.goal_task == "bread/push_east"
    finally:
        h.close()


def test_a_routine_stop_is_said_once_at_info_then_at_debug(random_model_dir, capfd):
    """Each time the input and the arm's states stop (a key let go, a lagging simulation) the code goes
    through routine stops (JOY_TIMEOUT or AWAITING_NEUTRAL, WAITING_FOR_JOINT_STATES): each is said at
    INFO the first time only. Before, every time (at most every 2 s: 358 lines in 20 minutes of the
    operator station). The status topic still has every change."""
    from vla_latent_controller.status_log import ROUTINE

    h = Harness(random_model_dir)
    entered = []
    try:
        for _ in range(3):
            h.settle(ControllerStatus.ACTIVE)
            h.status.clear()
            assert h.spin_until(lambda: any(s.code == ControllerStatus.WAITING_FOR_JOINT_STATES
                                            for s in h.status), 10.0)
            entered += [s.code for s in h.status]
            h.spin_for(2.1)   # past the INFO lines' 2 s throttle, which alone let the old code repeat them
    finally:
        h.close()
    stops = [c for c in entered if c != ControllerStatus.WAITING_FOR_JOINT_STATES]
    assert len(stops) >= 3, entered                   # three stops of the input, on the status topic
    err = capfd.readouterr().err
    for code in ROUTINE:
        assert err.count(f"zero command: {code.name}:") <= 1, err

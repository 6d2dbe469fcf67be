"""The simulated teleoperator's core: candidate grid, waypoint schedule, greedy choice, closed loop."""
import numpy as np
import pytest
from vla_evaluation.sim_teleoperator import (
    SimTeleoperator,
    WaypointSchedule,
    axis_candidates,
    best_candidate,
)

Q0 = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])


def deadband_linear(direction, deadband=0.1, speed=0.5):
    """A fake controller: |axis| <= deadband -> zero, else axis * speed * direction (rad/s)."""
    d = np.asarray(direction, dtype=float) / np.linalg.norm(direction)

    def command(axes, q):
        axes = np.asarray(axes, dtype=float)
        z = np.where(np.abs(axes) <= deadband, 0.0, axes)
        return z[:, None] * speed * d[None, :]

    return command


def test_axis_candidates_odd_grid_with_zero_first():
    a = axis_candidates(41)
    assert a.shape == (41,)
    assert a[0] == 0.0
    assert np.isclose(a.min(), -1) and np.isclose(a.max(), 1)
    assert np.all(np.diff(np.abs(a)) >= -1e-12)  # ordered by magnitude: ties pick the gentlest
    with pytest.raises(ValueError):
        axis_candidates(40)
    with pytest.raises(ValueError):
        axis_candidates(1)


def test_best_candidate_batched_and_skips_nonfinite():
    cmds = np.array([[[0.0] * 7, [1.0] * 7, [np.nan] * 7]])  # (1, 3, 7)
    q = np.zeros((1, 7))
    w = np.full((1, 7), 1.0)
    idx, dist = best_candidate(cmds, q, w, horizon=1.0)
    assert idx.tolist() == [1] and np.isclose(dist[0], 0.0)
    cmds_bad = np.array([[[np.nan] * 7, [0.0] * 7]])
    idx, _ = best_candidate(cmds_bad, q, w)
    assert idx.tolist() == [1]


def test_schedule_push_switches_at_k_and_circle_spreads_rest():
    w1, w2 = Q0, Q0 + 0.1
    s = WaypointSchedule([w1, w2], switch_time=15.0, time_limit=30.0)
    assert s.index_at(0.0) == 0 and s.index_at(14.99) == 0 and s.index_at(15.0) == 1
    assert s.index_at(29.0) == 1 and s.done(30.0) and not s.done(29.9)
    assert np.allclose(s.final, w2)
    circle = WaypointSchedule([Q0 + 0.01 * i for i in range(6)], switch_time=15.0, time_limit=30.0)
    assert circle.switch_times == pytest.approx([15.0, 18.0, 21.0, 24.0, 27.0])
    assert circle.index_at(16.0) == 1 and circle.index_at(29.0) == 5
    with pytest.raises(ValueError):
        WaypointSchedule([np.zeros(6)])
    with pytest.raises(ValueError):
        WaypointSchedule([Q0], switch_time=40.0, time_limit=30.0)
    with pytest.raises(ValueError):
        WaypointSchedule([Q0, Q0], switch_times=[3.0, 4.0])


def test_picks_sign_towards_waypoint_and_zero_at_goal():
    d = np.array([1.0, 0.5, 0, 0, 0, 0, 0])
    sched = WaypointSchedule([Q0 + 0.3 * d / np.linalg.norm(d)])
    tele = SimTeleoperator(deadband_linear(d), sched, horizon=1.0)
    assert tele.act(0.0, Q0).axis > 0.1
    behind = WaypointSchedule([Q0 - 0.3 * d / np.linalg.norm(d)])
    assert SimTeleoperator(deadband_linear(d), behind).act(0.0, Q0).axis < -0.1
    at_goal = SimTeleoperator(deadband_linear(d), WaypointSchedule([Q0]))
    assert at_goal.act(0.0, Q0).axis == 0.0


def test_zero_model_means_hands_off_and_bad_inputs_never_raise():
    def zero(axes, q):
        return np.zeros((len(axes), 7))

    def broken(axes, q):
        raise RuntimeError("boom")

    sched = WaypointSchedule([Q0 + 0.2])
    assert SimTeleoperator(zero, sched).act(0.0, Q0).axis == 0.0
    step = SimTeleoperator(broken, sched).act(0.0, Q0)
    assert step.axis == 0.0 and "boom" in step.reason
    step = SimTeleoperator(zero, sched).act(0.0, np.full(7, np.nan))
    assert step.axis == 0.0 and "bad joint state" in step.reason
    step = SimTeleoperator(lambda a, q: np.zeros((3, 7)), sched).act(0.0, Q0)
    assert step.axis == 0.0 and "shape" in step.reason
    done = SimTeleoperator(zero, sched).act(30.0, Q0)
    assert done.done and done.axis == 0.0
    with pytest.raises(ValueError):
        SimTeleoperator(zero, sched, horizon=0.0)


def test_closed_loop_reaches_pre_then_post_push_waypoint():
    """A decoder whose direction depends on the state (two phases) lets the greedy user reach both."""
    d1 = np.array([0.4, 0.2, 0.0, 0.1, 0.0, 0.0, 0.0])
    d2 = np.array([0.0, 0.0, 0.3, 0.0, 0.2, 0.0, 0.0])
    pre, post = Q0 + d1, Q0 + d1 + d2

    def two_phase(axes, q):
        # before the pre-push point move along d1, after it along d2 (like a learned push)
        along = float(np.dot(q - Q0, d1) / np.dot(d1, d1))
        direction = d1 if along < 0.9 else d2
        return deadband_linear(direction)(axes, q)

    sched = WaypointSchedule([pre, post], switch_time=15.0, time_limit=30.0)
    tele = SimTeleoperator(two_phase, sched, horizon=1.0)
    q, dt = Q0.copy(), 0.05
    t = 0.0
    while True:
        step = tele.act(t, q)
        if step.done:
            break
        q = q + two_phase(np.array([step.axis]), q)[0] * dt
        if abs(t - 14.0) < dt / 2:
            assert np.linalg.norm(q - pre) < 0.05  # deadband: stops within half a grid step
        t += dt
    assert np.linalg.norm(q - post) < 0.1 * np.linalg.norm(Q0 - post) + 0.05


def random_model(path, seed=0):
    """A small valid detector-encoder model with random weights (no training needed)."""
    from vla_latent_controller.artifacts import decoder_tensor_shapes, save_model
    from vla_latent_controller.model import LatentModel

    classes = ["bread", "soda_can", "milk_carton", "glass_bottle", "cereal_box"]
    cfg = {"encoder": "detector", "classes": classes, "joint_names": [f"panda_joint{i}" for i in range(1, 8)],
           "dims": {"context": 7, "joints": 7, "latent": 1, "hidden": 30, "cnn_feature": 0},
           "normalisation": {"q_mean": Q0.tolist(), "q_std": [0.2] * 7, "a_scale": [0.3] * 7},
           "latent": {"gain": {"bread": 0.8, "soda_can": -0.6}, "default_gain": 0.7}}
    rng = np.random.default_rng(seed)
    tensors = {k: rng.normal(0, 0.5, s) for k, s in decoder_tensor_shapes(cfg).items()}
    return LatentModel.load(save_model(path, cfg, tensors))


def test_stick_to_command_matches_the_controller_core(tmp_path):
    """The teleoperator must predict exactly what the controller will command for each stick value."""
    from vla_common.detection import Detection
    from vla_evaluation.sim_teleoperator import StickToCommand
    from vla_latent_controller.teleop import TeleopCore, TeleopParams

    model = random_model(tmp_path / "m")
    det = Detection("soda_can", 0.9, 320.0, 200.0)
    params = TeleopParams(deadband=0.1, axis_scale=1.3, action_scale=2.0, max_joint_speed=1.5)
    core = TeleopCore(params, model)
    core.arming.offer(True)                 # the operator has been at neutral (the arming rule aside)
    core.on_joint_states([f"panda_joint{i}" for i in range(1, 8)], Q0.tolist(), 0.0)
    core.on_detections([det], (640, 480), 0.0)
    ctx = model.context(det=det, image_size=(640, 480))
    stick = StickToCommand(model, ctx, "soda_can", deadband=0.1, axis_scale=1.3, action_scale=2.0,
                           max_joint_speed=1.5)
    axes = np.array([-1.0, -0.6, -0.1, 0.0, 0.05, 0.1, 0.11, 0.3, 0.9, 1.0, 1.7])
    predicted = stick(axes, Q0)
    for a, p in zip(axes, predicted):
        core.on_joy([a, 0.0], [0, 0, 0, 0], 0.0)
        cmd, status = core.step(0.01)
        assert np.allclose(cmd, p, atol=1e-9), (a, cmd, p, status.reason)
    assert np.all(predicted[2:6] == 0.0)
    assert np.all(np.linalg.norm(predicted, axis=1) <= 1.5 + 1e-9)


# ---------------------------------------------------------------- the ROS node, in-process
@pytest.fixture
def ros():
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from vla_common.ros.context import end_context

    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    nodes = []
    yield ctx, ex, nodes
    for n in nodes:
        ex.remove_node(n)
        n.destroy_node()
    ex.shutdown()
    end_context(ctx)


def _spin_until(ex, cond, timeout):
    import time

    end = time.monotonic() + timeout
    while time.monotonic() < end and not cond():
        ex.spin_once(timeout_sec=0.02)
    return cond()


@pytest.mark.slow
@pytest.mark.ros
def test_node_drives_joy_through_an_episode(ros, tmp_path):
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import JointState, Joy
    from vla_common.tasks import task_layout
    from vla_evaluation.sim_teleoperator_node import SimTeleoperatorNode

    from vla_interfaces.msg import ControllerStatus, SceneObject, SceneObjectArray, TeleopStatus
    from vla_interfaces.srv import StartEpisode

    ctx, ex, nodes = ros
    random_model(tmp_path / "m")
    P = Parameter
    tele = SimTeleoperatorNode(context=ctx, parameter_overrides=[
        P("model_path", value=str(tmp_path / "m")), P("rate", value=50.0), P("time_limit", value=1.5),
        P("switch_time", value=0.7), P("start_timeout", value=1.0)])
    peer = Node("peer", context=ctx)
    nodes += [tele, peer]
    ex.add_node(tele)
    ex.add_node(peer)
    joys, statuses = [], []
    peer.create_subscription(Joy, "joy", joys.append, 10)
    peer.create_subscription(TeleopStatus, "sim_teleoperator/status", statuses.append, 10)
    js_pub = peer.create_publisher(JointState, "joint_states", qos_profile_sensor_data)
    obj_pub = peer.create_publisher(SceneObjectArray, "scene/objects", 10)
    ctrl_pub = peer.create_publisher(ControllerStatus, "controller_node/status", 10)
    start = peer.create_client(StartEpisode, "sim_teleoperator/start_episode")
    goal = task_layout("bread/push_east", np.random.default_rng(3), n_objects=1)[0]

    flags = {"ctrl": True}

    def feed():
        js = JointState(name=[f"panda_joint{i}" for i in range(1, 8)], position=Q0.tolist())
        js_pub.publish(js)
        objs = SceneObjectArray(objects=[SceneObject(class_id="bread", x=goal.x, y=goal.y, yaw=goal.yaw)])
        obj_pub.publish(objs)
        if flags["ctrl"]:
            ctrl_pub.publish(ControllerStatus(latched_class="bread", latched_x=0.5, latched_y=0.6))

    peer.create_timer(0.02, feed)
    assert start.wait_for_service(timeout_sec=5.0)

    def call(task):
        fut = start.call_async(StartEpisode.Request(task=task))
        assert _spin_until(ex, fut.done, 5.0)
        return fut.result()

    bad = call("bread/juggle")
    assert not bad.success and "juggle" in bad.message
    ok = call("bread/push_east")
    assert ok.success
    assert _spin_until(ex, lambda: any(s.state == TeleopStatus.DONE for s in statuses), 10.0)
    running = [s for s in statuses if s.state == TeleopStatus.RUNNING]
    assert running and running[-1].waypoint_count == 2 and len(running[-1].final_waypoint) == 7
    assert running[-1].task == "bread/push_east"
    # A stream through the whole 1.5 s episode. Not a count from the 50 Hz rate: a loaded machine
    # runs the timer late (17-21 messages at load ~20), which is not what this test is about.
    stamps = [j.header.stamp.sec + j.header.stamp.nanosec * 1e-9 for j in joys]
    assert len(joys) >= 10 and stamps[-1] - stamps[0] >= 1.2
    assert all(len(j.axes) >= 1 and -1.0 <= j.axes[0] <= 1.0 for j in joys)
    assert joys[-1].axes[0] == 0.0  # stick released at the time limit
    assert joys[-1].header.stamp.sec > 0 or joys[-1].header.stamp.nanosec > 0

    # stopped before its time limit: every status from then on says how long it ran (an orchestrator
    # that missed the first DONE, on a loaded machine, still knows when it ended)
    from std_srvs.srv import Trigger
    stop = peer.create_client(Trigger, "sim_teleoperator/stop")
    statuses.clear()
    assert call("bread/push_east").success
    assert _spin_until(ex, lambda: any(s.state == TeleopStatus.RUNNING for s in statuses), 10.0)
    _spin_until(ex, lambda: False, 0.3)
    fut = stop.call_async(Trigger.Request())
    assert _spin_until(ex, fut.done, 5.0) and fut.result().success
    assert _spin_until(ex, lambda: sum(s.state == TeleopStatus.DONE for s in statuses) >= 4, 10.0)
    ended = [s.elapsed for s in statuses if s.state == TeleopStatus.DONE]
    assert len(set(ended)) == 1 and 0.0 < ended[0] < 1.5, ended

    # without the controller's latched context it gives up after start_timeout, stick released
    flags["ctrl"] = False
    _spin_until(ex, lambda: False, 0.3)
    statuses.clear()
    assert call("bread/push_east").success
    assert _spin_until(ex, lambda: any(s.state == TeleopStatus.FAILED for s in statuses), 10.0)
    failed = next(s for s in statuses if s.state == TeleopStatus.FAILED)
    # it names the topic it listens on and what to set (a renamed controller is heard nowhere else)
    assert "/controller_node/status" in failed.reason and "controller_status_topic" in failed.reason
    assert joys[-1].axes[0] == 0.0


def test_stick_rate_limit_moves_the_stick_gradually():
    d = np.array([1.0, 0, 0, 0, 0, 0, 0])
    sched = WaypointSchedule([Q0 + 5.0 * d], switch_time=1.0, time_limit=30.0)
    free = SimTeleoperator(deadband_linear(d), sched)
    assert free.act(0.0, Q0).axis == 1.0 and free.act(0.01, Q0).axis == 1.0
    limited = SimTeleoperator(deadband_linear(d), sched, max_stick_rate=5.0)
    first = limited.act(0.0, Q0).axis  # nothing to limit against yet
    assert first == 1.0
    behind = WaypointSchedule([Q0 - 5.0 * d], switch_time=1.0, time_limit=30.0)
    limited.schedule = behind  # the goal flips: the hand needs 0.4 s to go from +1 to -1
    axes = [limited.act(0.02 * k, Q0).axis for k in range(1, 25)]
    steps = np.abs(np.diff([first, *axes]))
    assert np.all(steps <= 5.0 * 0.02 + 1e-9)
    assert axes[-1] == pytest.approx(-1.0) and axes[3] > 0.5
    with pytest.raises(ValueError):
        SimTeleoperator(deadband_linear(d), sched, max_stick_rate=-1.0)


def _set(ex, node, client, **values):
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    params = [Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
    req = SetParameters.Request(parameters=params)
    assert client.wait_for_service(timeout_sec=5.0)
    fut = client.call_async(req)
    assert _spin_until(ex, fut.done, 5.0)
    return fut.result().results


@pytest.mark.ros
def test_node_applies_or_refuses_every_run_time_parameter(ros, tmp_path):
    """Episode settings apply from the next episode; an even n_candidates and a model change during
    an episode are refused with a reason; the read-only rate is refused."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from vla_evaluation.sim_teleoperator_node import SimTeleoperatorNode

    from vla_interfaces.msg import TeleopStatus

    ctx, ex, nodes = ros
    random_model(tmp_path / "m")
    random_model(tmp_path / "m2", seed=1)
    tele = SimTeleoperatorNode(context=ctx,
                               parameter_overrides=[Parameter("model_path", value=str(tmp_path / "m"))])
    peer = Node("peer", context=ctx)
    nodes += [tele, peer]
    ex.add_node(tele)
    ex.add_node(peer)
    cli = peer.create_client(SetParameters, "sim_teleoperator/set_parameters")
    ok = _set(ex, peer, cli, horizon=2.0, n_candidates=81, time_limit=5.0)
    assert all(r.successful for r in ok) and tele.p["horizon"] == 2.0 and tele.p["n_candidates"] == 81
    (even,) = _set(ex, peer, cli, n_candidates=40)
    assert not even.successful and "odd" in even.reason and tele.p["n_candidates"] == 81
    (rate,) = _set(ex, peer, cli, rate=50.0)
    assert not rate.successful
    (bad,) = _set(ex, peer, cli, model_path=str(tmp_path / "missing"))
    assert not bad.successful and "cannot load model" in bad.reason
    (model,) = _set(ex, peer, cli, model_path=str(tmp_path / "m2"))
    assert model.successful and str(tele.model.artifacts.path).endswith("m2")
    tele._request("bread/push_east")  # an episode is waiting for its inputs
    assert tele.state == TeleopStatus.WAITING
    (busy,) = _set(ex, peer, cli, model_path=str(tmp_path / "m"))
    assert not busy.successful and "running" in busy.reason


@pytest.mark.ros
def test_a_task_given_before_the_first_clock_waits_from_the_first_clock(ros, tmp_path):
    """use_sim_time and `task` at startup: the request is stamped 0 until /clock arrives. The wait for
    inputs must count from the first simulated time, not give up at once (simulated time then is the
    bridge's wall-clock start, ~1.8e9 s after 0)."""
    from builtin_interfaces.msg import Time
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rosgraph_msgs.msg import Clock
    from vla_evaluation.sim_teleoperator_node import SimTeleoperatorNode

    from vla_interfaces.msg import TeleopStatus

    ctx, ex, nodes = ros
    random_model(tmp_path / "m")
    P = Parameter
    tele = SimTeleoperatorNode(context=ctx, parameter_overrides=[
        P("model_path", value=str(tmp_path / "m")), P("task", value="bread/push_east"),
        P("use_sim_time", value=True), P("start_timeout", value=5.0)])
    peer = Node("clock", context=ctx)
    nodes += [tele, peer]
    ex.add_node(tele)
    ex.add_node(peer)
    clock = peer.create_publisher(Clock, "/clock", 10)
    ticks = [0]

    def tick():  # simulated time from 1.8e9 s on, 10 ms a tick
        ticks[0] += 1
        sec, centis = divmod(ticks[0], 100)
        clock.publish(Clock(clock=Time(sec=1_800_000_000 + sec, nanosec=10_000_000 * centis)))

    peer.create_timer(0.01, tick)
    _spin_until(ex, lambda: False, 1.0)
    assert tele.state == TeleopStatus.WAITING, tele.reason  # still waiting for its inputs, not FAILED


@pytest.mark.ros
def test_trigger_joint_states_answers_each_joint_state_at_its_stamp(ros, tmp_path):
    """For a simulation stepped in lockstep: one stick value per joint state, stamped with that state's
    time, and none in between (no timer)."""
    from builtin_interfaces.msg import Time
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import JointState, Joy
    from vla_common.tasks import task_layout
    from vla_evaluation.sim_teleoperator_node import SimTeleoperatorNode

    from vla_interfaces.msg import ControllerStatus, SceneObject, SceneObjectArray, TeleopStatus

    ctx, ex, nodes = ros
    random_model(tmp_path / "m")
    P = Parameter
    tele = SimTeleoperatorNode(context=ctx, parameter_overrides=[
        P("model_path", value=str(tmp_path / "m")), P("trigger", value="joint_states"),
        P("task", value="bread/push_east")])
    peer = Node("peer", context=ctx)
    nodes += [tele, peer]
    ex.add_node(tele)
    ex.add_node(peer)
    joys = []
    peer.create_subscription(Joy, "joy", joys.append, 100)
    js_pub = peer.create_publisher(JointState, "joint_states", qos_profile_sensor_data)
    goal = task_layout("bread/push_east", np.random.default_rng(3), n_objects=1)[0]
    peer.create_publisher(SceneObjectArray, "scene/objects", 10).publish(
        SceneObjectArray(objects=[SceneObject(class_id="bread", x=goal.x, y=goal.y, yaw=goal.yaw)]))
    ctrl = peer.create_publisher(ControllerStatus, "controller_node/status", 10)
    names = [f"panda_joint{i}" for i in range(1, 8)]
    sent = []
    for k in range(40):
        stamp = Time(sec=100, nanosec=10_000_000 * k)
        if k < 10:  # the context and the scene until the episode runs
            ctrl.publish(ControllerStatus(latched_class="bread", latched_x=0.5, latched_y=0.6))
            peer.create_publisher(SceneObjectArray, "scene/objects", 10)
        js = JointState(name=names, position=Q0.tolist())
        js.header.stamp = stamp
        js_pub.publish(js)
        sent.append((stamp.sec, stamp.nanosec))
        _spin_until(ex, lambda: False, 0.03)
    assert tele.state == TeleopStatus.RUNNING, tele.reason
    stamps = [(j.header.stamp.sec, j.header.stamp.nanosec) for j in joys]
    assert stamps and set(stamps) <= set(sent)  # every stick value at a joint state's time
    assert len(stamps) == len(set(stamps))  # one per joint state


@pytest.mark.slow
@pytest.mark.ros
def test_image_subscription_is_on_the_image_qos(ros, tmp_path):
    """An image-encoder model makes the node subscribe to camera/image_raw on IMAGE_QOS (reliable,
    keep-last 30) like every image publisher; a SensorDataQoS (best-effort) subscriber lost frames."""
    from rclpy.parameter import Parameter
    from rclpy.qos import ReliabilityPolicy
    from vla_common.ros.qos import IMAGE_DEPTH
    from vla_evaluation.sim_teleoperator_node import SimTeleoperatorNode
    from vla_latent_controller.testing import CLASSES as FAKE_CLASSES
    from vla_latent_controller.testing import make_demos, make_pairs
    from vla_latent_training.train import TrainConfig, train_model

    demos = make_demos(per_class=1, with_image=True, T=20)
    res = train_model(demos, TrainConfig(encoder="end_to_end", epochs=1), classes=FAKE_CLASSES,
                      pairs_fn=make_pairs, progress=False, threads=1, log=lambda s: None)
    ctx, ex, nodes = ros
    model_path = str(res.save(tmp_path / "e2e"))
    tele = SimTeleoperatorNode(context=ctx, parameter_overrides=[Parameter("model_path", value=model_path)])
    nodes.append(tele)
    (info,) = tele.get_subscriptions_info_by_topic("/camera/image_raw")  # as the graph sees it
    assert info.qos_profile.reliability == ReliabilityPolicy.RELIABLE
    (sub,) = [s for s in tele.subscriptions if s.topic_name == "/camera/image_raw"]
    assert sub.qos_profile.depth == IMAGE_DEPTH  # discovery does not carry the depth


def test_hold_keeps_the_stick_at_one_value_until_the_time_limit():
    """Issue 20 item 5: a person who just holds the stick, whatever the waypoints say."""
    schedule = WaypointSchedule([Q0, Q0 + 0.5], 1.0, 3.0)
    tele = SimTeleoperator(deadband_linear(np.ones(7)), schedule, hold=1.0)
    assert [tele.act(t, Q0 + 0.5).axis for t in (0.0, 1.5, 2.9)] == [1.0, 1.0, 1.0]
    assert tele.act(3.0, Q0).done and tele.act(3.0, Q0).axis == 0.0
    assert tele.act(0.5, np.full(7, np.nan)).axis == 0.0        # bad joint state: hands off
    with pytest.raises(ValueError):
        SimTeleoperator(deadband_linear(np.ones(7)), schedule, hold=1.5)


@pytest.mark.ros
def test_where_the_latent_stops_short_the_node_aligns_in_end_effector_mode_then_goes_back(ros, tmp_path):
    """A pick-and-place whose arm stops 3 cm beside the grasp point: after a second without progress
    the user asks the controller for end-effector mode (~/set_mode), presses the axis button until
    the controller's status shows the axis it wants (up first: the hand is beside the bottle), pushes
    the stick that way, and at the end of the episode puts the controller back in latent mode.

    In simulated time (trigger joint_states): each step the fake controller's status is in before the
    joint state, and the node's Joy for it is in before the next step. With the status on a 50 Hz wall
    timer, at load 35 the node saw stale axes and pressed 8 times (x -> ... -> y, twice round)."""
    from builtin_interfaces.msg import Time
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState, Joy
    from vla_common.catalogue import default_catalogue
    from vla_common.kinematics import PandaKinematics
    from vla_common.tasks import task_layout
    from vla_evaluation.sim_grasp import hand_phases
    from vla_evaluation.sim_teleoperator_node import SimTeleoperatorNode
    from vla_sim.planner import plan_task

    from vla_interfaces.msg import (
        ControllerStatus,
        GripperStatus,
        SceneObject,
        SceneObjectArray,
        TeleopStatus,
    )
    from vla_interfaces.srv import SetMode, StartEpisode

    ctx, ex, nodes = ros
    random_model(tmp_path / "m")
    task = "glass_bottle/pick_place_west"
    goal = task_layout(task, np.random.default_rng(3), n_objects=1)[0]
    kin = PandaKinematics()
    plan = plan_task(kin, default_catalogue().task(task), goal, Q0, np.random.default_rng(0))
    grasp = hand_phases(plan)[0].waypoint_indices[-1]
    q_near = np.array(plan.waypoints[grasp], float)
    q_near[0] += 0.06                                   # the base turned: ~3 cm beside the grasp point
    assert 0.02 < np.linalg.norm(kin.fk(q_near)[0] - kin.fk(plan.waypoints[grasp])[0]) < 0.05

    P = Parameter
    tele = SimTeleoperatorNode(context=ctx, parameter_overrides=[
        P("model_path", value=str(tmp_path / "m")), P("rate", value=50.0), P("time_limit", value=6.0),
        P("start_timeout", value=2.0), P("trigger", value="joint_states")])
    peer = Node("peer", context=ctx)
    nodes += [tele, peer]
    ex.add_node(tele)
    ex.add_node(peer)
    ctrl = {"mode": "latent", "axis": 0, "requests": [], "prev": 0}
    cycle = ("x", "y", "z", "roll", "pitch", "yaw")

    def set_mode(req, res):
        ctrl["requests"].append(req.mode)
        ctrl["mode"], res.success = req.mode, True
        return res

    joys = []

    def on_joy(msg):
        joys.append((ctrl["mode"], cycle[ctrl["axis"]], msg))
        pressed = len(msg.buttons) > 0 and msg.buttons[0] == 1
        if pressed and not ctrl["prev"] and ctrl["mode"] == "end_effector":
            ctrl["axis"] = (ctrl["axis"] + 1) % len(cycle)
        ctrl["prev"] = pressed

    peer.create_service(SetMode, "controller_node/set_mode", set_mode)
    peer.create_subscription(Joy, "joy", on_joy, 50)
    js_pub = peer.create_publisher(JointState, "joint_states", 10)
    obj_pub = peer.create_publisher(SceneObjectArray, "scene/objects", 10)
    ctrl_pub = peer.create_publisher(ControllerStatus, "controller_node/status", 10)
    hand_pub = peer.create_publisher(GripperStatus, "gripper/status", 10)
    start = peer.create_client(StartEpisode, "sim_teleoperator/start_episode")
    assert start.wait_for_service(timeout_sec=10.0)
    fut = start.call_async(StartEpisode.Request(task=task))
    assert _spin_until(ex, fut.done, 10.0) and fut.result().success

    def step(k: int) -> None:
        """Simulated time 1000 + 0.02 k s: the scene and the controller's status as the Joys left them,
        then the joint state; returns once the node's Joy for it is in (wall bounds only against a hang)."""
        stamp = Time(sec=1000 + k // 50, nanosec=20_000_000 * (k % 50))
        obj_pub.publish(SceneObjectArray(objects=[SceneObject(class_id="glass_bottle", x=goal.x, y=goal.y,
                                                              yaw=goal.yaw)]))
        hand_pub.publish(GripperStatus(state=GripperStatus.IDLE, width=0.08))   # open, as the phase wants
        status = ControllerStatus(latched_class="glass_bottle", latched_x=0.5, latched_y=0.6,
                                  mode=ctrl["mode"], ee_axis=cycle[ctrl["axis"]])
        status.header.stamp = stamp
        ctrl_pub.publish(status)
        assert _spin_until(ex, lambda: tele.ctrl is not None and tele.ctrl.header.stamp == stamp
                           and "glass_bottle" in tele.objects and tele.hand is not None, 30.0)
        js = JointState(name=[f"panda_joint{i}" for i in range(1, 8)], position=q_near.tolist())
        js.header.stamp = stamp
        n = len(joys)
        js_pub.publish(js)
        assert _spin_until(ex, lambda: len(joys) > n, 30.0), k

    for k in range(400):                                 # 6 s of episode and its start: 300 steps
        step(k)
        if tele.state == TeleopStatus.DONE:
            break
    assert tele.state == TeleopStatus.DONE, tele.reason
    assert _spin_until(ex, lambda: ctrl["mode"] == "latent", 10.0)    # as the episode found it

    assert ctrl["requests"][0] == "end_effector" and ctrl["requests"][-1] == "latent"
    ee = [(axis, j) for mode, axis, j in joys if mode == "end_effector"]
    presses = [j for _, j in ee if j.buttons[0] == 1]
    assert 1 <= len(presses) <= 3                        # x -> y -> z: two presses (one more at most)
    up = [j.axes[0] for axis, j in ee if axis == "z"]
    assert up and max(up) > 0.1                          # past the deadband, up over the bottle first
    assert all(j.axes[0] == 0.0 for axis, j in ee if axis != "z")   # the stick rests on the wrong axis
    assert joys[-1][2].axes[0] == 0.0


@pytest.mark.ros
def test_in_lockstep_every_joint_state_gets_exactly_one_joy_between_episodes_too(ros, tmp_path):
    """The controller waits for the joy of each joint state (lockstep): the teleoperator answers every
    one, at its stamp, with the stick at rest and no button while no episode runs."""
    from builtin_interfaces.msg import Time
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState, Joy
    from vla_evaluation.sim_teleoperator_node import SimTeleoperatorNode

    ctx, ex, nodes = ros
    random_model(tmp_path / "m")
    tele = SimTeleoperatorNode(context=ctx, parameter_overrides=[
        Parameter("model_path", value=str(tmp_path / "m")), Parameter("lockstep", value=True),
        Parameter("enable_button", value=1)])
    peer = Node("peer", context=ctx)
    nodes += [tele, peer]
    ex.add_node(tele)
    ex.add_node(peer)
    joys = []
    peer.create_subscription(Joy, "joy", joys.append, 100)
    js_pub = peer.create_publisher(JointState, "joint_states", 100)
    _spin_until(ex, lambda: js_pub.get_subscription_count() > 0, 10.0)
    names = [f"panda_joint{i}" for i in range(1, 8)]
    sent = []
    for k in range(5):
        js = JointState(name=names, position=Q0.tolist())
        js.header.stamp = Time(sec=1, nanosec=10_000_000 * k)
        js_pub.publish(js)
        sent.append((1, 10_000_000 * k))
        _spin_until(ex, lambda k=k: len(joys) > k, 10.0)
    _spin_until(ex, lambda: False, 0.2)
    assert [(j.header.stamp.sec, j.header.stamp.nanosec) for j in joys] == sent
    assert all(j.axes[0] == 0.0 and j.buttons[1] == 0 for j in joys)

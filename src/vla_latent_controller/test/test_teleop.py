import json
import math
from pathlib import Path

import numpy as np
import pytest
from vla_common.detection import Detection
from vla_latent_controller.artifacts import load_model, save_model
from vla_latent_controller.joints import parse_joint_map
from vla_latent_controller.model import LatentModel
from vla_latent_controller.teleop import Code, TeleopCore, TeleopParams, stick_to_unit, unit_to_stick
from vla_latent_controller.testing import READY, write_random_model

from vla_interfaces.msg import ControllerStatus

NAMES = [f"panda_joint{i}" for i in range(1, 8)]
SIZE = (640, 480)


class FakeKin:
    """A fixed full-rank Jacobian: enough to check the end-effector mapping."""

    def __init__(self):
        self.J = np.random.default_rng(0).normal(size=(6, 7))

    def jacobian(self, q):
        return self.J


def make_core(model_dir=None, armed=True, **kw):
    """A core whose operator has been at neutral (armed), unless `armed=False`: the arming rule
    has its own tests (test_arming_core below and test/test_arming.py)."""
    model = LatentModel.load(model_dir) if model_dir is not None else None
    core = TeleopCore(TeleopParams(**kw), model=model, kinematics=FakeKin())
    if armed:
        core.arming.offer(True)
    return core


BREAD = (Detection("bread", 0.9, 320, 240),)


def feed(core, now, axis=0.8, buttons=(0, 0, 0), dets=BREAD, q=READY):
    core.on_joint_states(NAMES, list(q), now)
    if axis is not None:
        core.on_joy([axis, 0.0], list(buttons), now)
    if dets is not None:
        core.on_detections(list(dets), SIZE, now)


def neutral(core, now):
    """The operator lets the stick go back to neutral for one tick (re-arms the controller)."""
    axes = list(core._axes or [0.0])
    core.on_joy([0.0] + axes[1:], list(core._buttons), now)
    assert core.step(now)[1].code == Code.ZERO_DEADBAND


def test_active_command_then_deadband_is_exactly_zero(random_model_dir):
    core = make_core(random_model_dir)
    feed(core, 0.0, axis=0.8)
    cmd, st = core.step(0.01)
    assert st.code == Code.ACTIVE and np.linalg.norm(cmd) > 0
    assert st.latched_class == "bread" and st.latched_x == pytest.approx(0.5)
    for v in (0.0, 0.1, -0.1, 0.05):
        core.on_joy([v], [0, 0, 0], 0.02)
        cmd, st = core.step(0.03)
        assert st.code == Code.ZERO_DEADBAND
        assert np.all(cmd == 0.0)


def test_stick_maps_continuously_beyond_deadband(random_model_dir):
    core = make_core(random_model_dir)
    feed(core, 0.0, axis=0.1001)
    _, st = core.step(0.0)
    assert st.code == Code.ACTIVE and 0 < st.z < 1e-3
    feed(core, 0.0, axis=1.0)
    _, st = core.step(0.0)
    assert st.z == pytest.approx(0.8)  # full stick = the model's gain


@pytest.mark.parametrize(
    "axes, code, text",
    [
        ([float("nan"), 0.0], Code.BAD_INPUT, "not a finite"),
        ([], Code.BAD_INPUT, "out of range"),
        (["x"], Code.BAD_INPUT, "not a finite"),
    ],
)
def test_bad_axes_give_zero_and_status(random_model_dir, axes, code, text):
    core = make_core(random_model_dir)
    feed(core, 0.0)
    core.on_joy(axes, [], 0.0)
    cmd, st = core.step(0.01)
    assert st.code == code and text in st.reason and np.all(cmd == 0)


def test_axis_index_out_of_range(random_model_dir):
    core = make_core(random_model_dir, axis=5)
    feed(core, 0.0)
    cmd, st = core.step(0.0)
    assert st.code == Code.BAD_INPUT and "axis 5 out of range" in st.reason and np.all(cmd == 0)


def test_joint_states_by_name_in_any_order(random_model_dir):
    """Extra joints are ignored; the command follows the order of joint_states' names."""
    a = make_core(random_model_dir)
    feed(a, 0.0)
    ref = a.step(0.0)[0].copy()
    b = make_core(random_model_dir)
    feed(b, 0.0)
    order = [3, 0, 6, 2, 5, 1, 4]
    b.on_joint_states(
        ["panda_finger_joint1"] + [NAMES[i] for i in order], [0.04] + [READY[i] for i in order], 0.0
    )
    np.testing.assert_array_equal(b.step(0.0)[0], ref[order])


@pytest.mark.parametrize(
    "names, pos, text",
    [
        (NAMES, [*READY[:6], float("nan")], "non-finite positions for panda_joint7"),
        (NAMES, list(READY[:5]), "7 names but 5 positions"),
    ],
)
def test_bad_joint_states(random_model_dir, names, pos, text):
    core = make_core(random_model_dir)
    feed(core, 0.0)
    core.on_joint_states(names, pos, 0.0)
    cmd, st = core.step(0.0)
    assert st.code == Code.BAD_INPUT and text in st.reason and np.all(cmd == 0)


def test_waiting_and_timeouts(random_model_dir):
    core = make_core(random_model_dir, joy_timeout=0.1, joint_states_timeout=0.5)
    assert core.step(0.0)[1].code == Code.WAITING_FOR_JOINT_STATES
    core.on_joint_states(NAMES, list(READY), 0.0)
    core.on_detections([Detection("bread", 0.9, 1, 1)], SIZE, 0.0)
    assert core.step(0.0)[1].code == Code.WAITING_FOR_JOY
    core.on_joy([0.9], [], 0.0)
    cmd, st = core.step(0.01)                    # waiting was a stop: the held stick does nothing
    assert st.code == Code.AWAITING_NEUTRAL and np.all(cmd == 0) and "neutral" in st.reason
    neutral(core, 0.02)
    core.on_joy([0.9], [], 0.03)
    assert core.step(0.05)[1].code == Code.ACTIVE
    cmd, st = core.step(0.2)
    assert st.code == Code.JOY_TIMEOUT and np.all(cmd == 0)
    core.on_joy([0.9], [], 1.0)
    cmd, st = core.step(1.0)
    assert st.code == Code.WAITING_FOR_JOINT_STATES and "timeout" in st.reason and np.all(cmd == 0)


def test_deadman(random_model_dir):
    core = make_core(random_model_dir, enable_button=1)
    feed(core, 0.0, buttons=(0, 0))
    cmd, st = core.step(0.0)
    assert st.code == Code.DEADMAN_RELEASED and np.all(cmd == 0)
    feed(core, 0.0, buttons=(0, 1))
    assert core.step(0.0)[1].code == Code.ACTIVE
    feed(core, 0.0, buttons=())
    assert core.step(0.0)[1].code == Code.BAD_INPUT


def test_no_detection_waits_then_latches_once(random_model_dir):
    core = make_core(random_model_dir)
    feed(core, 0.0, dets=None)
    cmd, st = core.step(0.0)
    assert st.code == Code.WAITING_FOR_DETECTION and np.all(cmd == 0)
    core.on_detections([], SIZE, 0.0)
    assert core.step(0.0)[1].code == Code.WAITING_FOR_DETECTION
    core.on_detections([Detection("bread", 0.5, 64, 48), Detection("soda_can", 0.9, 320, 240)], SIZE, 0.1)
    _, st = core.step(0.1)
    assert st.code == Code.AWAITING_NEUTRAL and st.latched_class == "soda_can"   # latched, not moving
    neutral(core, 0.1)
    feed(core, 0.1, dets=None)
    _, st = core.step(0.1)
    assert st.code == Code.ACTIVE and st.latched_class == "soda_can"
    core.on_detections([Detection("bread", 0.99, 64, 48)], SIZE, 0.2)  # latched: later detections are ignored
    assert core.step(0.2)[1].latched_class == "soda_can"


def test_redetect_and_max_age(random_model_dir):
    core = make_core(random_model_dir, redetect_button=2, detection_max_age=1.0)
    feed(core, 0.0)
    assert core.step(0.0)[1].latched_class == "bread"
    core.on_joy([0.8, 0.0], [0, 0, 1], 0.5)  # button press: re-detect
    _, st = core.step(0.5)
    assert st.code == Code.WAITING_FOR_DETECTION and st.latched_class == ""
    core.on_detections([Detection("milk_carton", 0.9, 100, 100)], SIZE, 0.6)
    core.on_joy([0.8, 0.0], [0, 0, 1], 0.6)  # held, not a new press
    core.on_joint_states(NAMES, list(READY), 0.6)
    assert core.step(0.6)[1].latched_class == "milk_carton"
    core.on_joint_states(NAMES, list(READY), 1.7)
    core.on_joy([0.8, 0.0], [0, 0, 0], 1.7)
    _, st = core.step(1.7)  # latched 1.1 s ago, no newer detection
    assert st.code == Code.WAITING_FOR_DETECTION
    core.on_detections([Detection("glass_bottle", 0.9, 100, 100)], SIZE, 1.7)
    assert core.step(1.7)[1].latched_class == "glass_bottle"


def test_fixed_goal_class(random_model_dir):
    core = make_core(random_model_dir, goal_selection="milk_carton")
    feed(core, 0.0, dets=[Detection("bread", 0.9, 1, 1)])
    assert core.step(0.0)[1].code == Code.WAITING_FOR_DETECTION
    core.on_detections([Detection("bread", 0.9, 1, 1), Detection("milk_carton", 0.2, 5, 5)], SIZE, 0.0)
    assert core.step(0.0)[1].latched_class == "milk_carton"
    core.params.goal_selection = "teapot"
    cmd, st = core.step(0.0)
    assert st.code == Code.MODEL_ERROR and "goal_selection" in st.reason and np.all(cmd == 0)


def test_classes_unknown_to_the_model(tmp_path):
    d = write_random_model(tmp_path / "m", classes=("apple", "pear"))
    core = make_core(d)
    feed(core, 0.0, dets=[Detection("bread", 0.9, 1, 1)])
    cmd, st = core.step(0.0)
    assert st.code == Code.MODEL_ERROR and "not in the model's classes" in st.reason and np.all(cmd == 0)


def test_no_model(tmp_path):
    core = TeleopCore(TeleopParams(), model=None, model_error="model.safetensors: corrupt")
    feed(core, 0.0)
    cmd, st = core.step(0.0)
    assert st.code == Code.MODEL_ERROR and "corrupt" in st.reason and np.all(cmd == 0)


def test_speed_clamp_keeps_direction(random_model_dir):
    core = make_core(random_model_dir, action_scale=1.0)
    feed(core, 0.0, axis=1.0)
    raw = core.step(0.0)[0].copy()
    core.params.action_scale = 1000.0
    cmd = core.step(0.0)[0]
    assert np.linalg.norm(cmd) == pytest.approx(1.5)
    np.testing.assert_allclose(cmd / np.linalg.norm(cmd), raw / np.linalg.norm(raw), atol=1e-9)
    core.params.dq_max = dict.fromkeys(NAMES, 0.1)
    assert np.max(np.abs(core.step(0.0)[0])) == pytest.approx(0.1)


def test_loop_never_raises(random_model_dir):
    core = make_core(random_model_dir)
    feed(core, 0.0)

    def boom(q, z):
        raise RuntimeError("decoder exploded")

    core.model.decoder.decode = boom
    cmd, st = core.step(0.0)
    assert st.code == Code.MODEL_ERROR and "decoder exploded" in st.reason and np.all(cmd == 0)
    core.model.decoder.decode = lambda q, z: np.full(7, np.nan)
    cmd, st = core.step(0.0)
    assert st.code == Code.MODEL_ERROR and "not finite" in st.reason and np.all(cmd == 0)


def test_end_effector_mode_follows_selected_axis():
    core = make_core(None, mode="end_effector", ee_mode_button=0, max_joint_speed=100.0)
    kin = core.kinematics
    for k, axis in enumerate(("x", "y", "z", "roll", "pitch", "yaw")):
        feed(core, 10.0 * k, axis=0.55, dets=None)
        cmd, st = core.step(10.0 * k)
        assert st.code == Code.ACTIVE and st.ee_axis == axis
        twist = kin.J @ cmd
        assert np.argmax(np.abs(twist)) == k and twist[k] > 0
        assert np.linalg.norm(np.delete(twist, k)) < 1e-2 * abs(twist[k])  # damping: tiny cross-talk
        core.on_joy([0.55, 0.0], [1, 0, 0], 10.0 * k + 0.01)  # press: next axis
        core.on_joy([0.55, 0.0], [0, 0, 0], 10.0 * k + 0.05)
        core.on_joy([0.55, 0.0], [1, 0, 0], 10.0 * k + 0.1)  # within 0.25 s: debounced
        core.on_joy([0.55, 0.0], [0, 0, 0], 10.0 * k + 0.15)
    assert core.ee.axis == "x"  # cycled once per step, wrapped around


def test_end_effector_mode_cycles_only_the_given_axes():
    """ee_axes [x, y, z] (a task with the hand pointing down): the button goes z -> x in one press,
    not through roll, pitch and yaw; a change at run time keeps the selected axis where it can."""
    core = make_core(None, mode="end_effector", ee_mode_button=0, max_joint_speed=100.0,
                     ee_axes=["x", "y", "z"])
    kin = core.kinematics
    seen = []
    for k in range(4):
        feed(core, 10.0 * k, axis=0.55, dets=None)
        cmd, st = core.step(10.0 * k)
        seen.append(st.ee_axis)
        twist = kin.J @ cmd
        assert np.argmax(np.abs(twist)) == "xyz".index(st.ee_axis)
        core.on_joy([0.55, 0.0], [1, 0, 0], 10.0 * k + 0.01)  # press: next axis
        core.on_joy([0.55, 0.0], [0, 0, 0], 10.0 * k + 0.05)
    assert seen == ["x", "y", "z", "x"] and core.ee.axis == "y"
    core.params.ee_axes = ["z", "x"]
    core.sync_params()
    assert core.ee.axes == ("z", "x") and core.ee.axis == "z"  # y is gone: the first of the new cycle
    with pytest.raises(ValueError, match="distinct axes"):
        core.ee.set_axes(["x", "x"])


def test_a_mode_set_starts_the_end_effector_baseline_at_its_first_axis():
    """Issue 33/35: a study trial sets the mode; the axis the last trial left must not carry over (a
    sweep's worker runs whichever trials it gets, so the trial's row would depend on them)."""
    core = make_core(None, mode="end_effector", ee_mode_button=0, max_joint_speed=100.0)
    core.on_joy([0.55, 0.0], [1, 0, 0], 0.01)  # press: y
    core.on_joy([0.55, 0.0], [0, 0, 0], 0.05)
    assert core.ee.axis == "y"
    assert core.set_mode("end_effector")[0] and core.ee.axis == "x"
    core.on_joy([0.55, 0.0], [1, 0, 0], 0.06)  # at once: no debounce left from the last trial
    assert core.ee.axis == "y"


def test_status_codes_match_message_constants():
    for c in Code:
        assert getattr(ControllerStatus, c.name) == c.value


def test_mode_switch_rejects_unknown():
    core = make_core(None)
    assert core.set_mode("end_effector")[0] and core.mode == "end_effector"
    ok, msg = core.set_mode("joint")
    assert not ok and "unknown mode" in msg and core.mode == "end_effector"
    assert math.isnan(core.status.latched_x)


def test_stick_to_unit_vectorised_matches_scalar():
    s = np.array([-2.0, -1.0, -0.5, -0.1, 0.0, 0.05, 0.1, 0.55, 1.0, 3.0])
    u = stick_to_unit(s, 0.1, 1.0)
    np.testing.assert_allclose(u, [-1, -1, -0.4 / 0.9, 0, 0, 0, 0, 0.5, 1, 1])
    assert all(
        stick_to_unit(float(v), 0.1, 2.0) == pytest.approx(min(1, max(-1, 2 * x))) for v, x in zip(s, u)
    )


def test_unit_to_stick_inverts_the_stick_mapping_and_stays_past_the_deadband():
    for db in (0.0, 0.1, 0.3):
        for u in (-1.0, -0.4, -0.01, 0.01, 0.25, 1.0):
            s = unit_to_stick(u, db)
            assert abs(s) > db and stick_to_unit(s, db) == pytest.approx(u)
        assert unit_to_stick(0.0, db) == 0.0 and unit_to_stick(3.0, db) == 1.0


def test_malformed_detection_and_joy(random_model_dir):
    core = make_core(random_model_dir)
    feed(core, 0.0, dets=None)
    core.on_detections([Detection("bread", 0.9, 320, 240)], (0, 0), 0.0)
    cmd, st = core.step(0.0)
    assert st.code == Code.BAD_INPUT and "image size" in st.reason and np.all(cmd == 0)
    core.on_joy(None, None, 0.0)
    core.on_detections([Detection("bread", 0.9, 320, 240)], SIZE, 0.0)
    cmd, st = core.step(0.0)
    assert st.code == Code.BAD_INPUT and np.all(cmd == 0)


@pytest.mark.parametrize("cx, cy", [(1e6, -1e6), (-50.0, 240.0), (float("nan"), 240.0)])
def test_a_detection_outside_the_image_is_bad_input_and_never_latched(random_model_dir, cx, cy):
    """Issue 20 item 8: outside the image (plus a small margin) is BAD_INPUT, like NaN; a valid
    detection that arrives later is latched."""
    core = make_core(random_model_dir)
    feed(core, 0.0, axis=1.0, dets=(Detection("bread", 0.9, cx, cy),))
    cmd, st = core.step(0.01)
    assert st.code == Code.BAD_INPUT and np.all(cmd == 0) and core.latched is None
    assert "bread detection" in st.reason
    feed(core, 0.02, axis=1.0)
    cmd, st = core.step(0.03)
    assert st.code == Code.AWAITING_NEUTRAL and np.all(cmd == 0) and st.latched_x == pytest.approx(0.5)
    neutral(core, 0.04)
    feed(core, 0.05, axis=1.0)
    cmd, st = core.step(0.05)
    assert st.code == Code.ACTIVE and np.linalg.norm(cmd) > 0


def _permuted_model(src: Path, dst: Path, order: list[int]) -> Path:
    """The same network as `src` with its joints listed in `order`: by joint name, the same function."""
    art = load_model(src)
    cfg = json.loads(json.dumps(art.config))
    cfg["joint_names"] = [cfg["joint_names"][i] for i in order]
    for key in ("q_mean", "q_std", "a_scale"):
        cfg["normalisation"][key] = [cfg["normalisation"][key][i] for i in order]
    t = {k: v.copy() for k, v in art.tensors.items()}
    k = cfg["dims"]["context"]
    t["decoder.0.weight"][:, k : k + 7] = art.tensors["decoder.0.weight"][:, k : k + 7][:, order]
    t["decoder.4.weight"] = art.tensors["decoder.4.weight"][order]
    t["decoder.4.bias"] = art.tensors["decoder.4.bias"][order]
    cfg.pop("files")
    return save_model(dst, cfg, t)


def test_command_is_in_the_robots_joint_order(random_model_dir, tmp_path):
    """A model that lists its joints in another order drives the same joints by name; the command is
    in the order of the names in joint_states (the robot's)."""
    ref = make_core(random_model_dir)
    feed(ref, 0.0)
    want = dict(zip(NAMES, ref.step(0.0)[0].copy()))
    assert np.linalg.norm(list(want.values())) > 0
    order = [6, 5, 4, 3, 2, 1, 0]
    core = make_core(_permuted_model(random_model_dir, tmp_path / "reversed", order))
    feed(core, 0.0)
    np.testing.assert_allclose(core.step(0.0)[0], [want[n] for n in NAMES], rtol=1e-12, atol=1e-15)
    robot = [NAMES[i] for i in (3, 0, 6, 2, 5, 1, 4)]  # a robot that publishes its joints in this order
    positions = [0.04] + [READY[NAMES.index(n)] for n in robot]
    core.on_joint_states(["panda_finger_joint1", *robot], positions, 0.0)
    cmd, st = core.step(0.0)
    assert st.code == Code.ACTIVE
    np.testing.assert_allclose(cmd, [want[n] for n in robot], rtol=1e-12, atol=1e-15)
    assert core.command_joints == tuple(robot)


def test_a_model_whose_joints_the_robot_lacks_is_refused(random_model_dir):
    core = make_core(random_model_dir)
    feed(core, 0.0)
    core.on_joint_states(NAMES[:6], list(READY[:6]), 0.0)
    cmd, st = core.step(0.0)
    assert st.code == Code.MODEL_ERROR and "lack panda_joint7" in st.reason and np.all(cmd == 0)


@pytest.mark.parametrize("value", [-1, 2, 255])
def test_only_a_pressed_button_holds_the_deadman(random_model_dir, value):
    """Joy buttons are 0 or 1; any other value (a driver's -1, garbage) is not a held deadman."""
    core = make_core(random_model_dir, enable_button=1)
    feed(core, 0.0, buttons=(0, value))
    cmd, st = core.step(0.0)
    assert st.code == Code.DEADMAN_RELEASED and np.all(cmd == 0)


FR3_NAMES = [f"fr3_joint{i}" for i in range(1, 8)]
FR3_MAP = {f"panda_joint{i}": f"fr3_joint{i}" for i in range(1, 8)}


def test_a_panda_model_is_refused_on_an_fr3_unless_mapped(random_model_dir):
    ref = make_core(random_model_dir)
    feed(ref, 0.0)
    want = dict(zip(NAMES, ref.step(0.0)[0].copy()))
    core = make_core(random_model_dir)
    core.on_joy([0.8, 0.0], [0, 0, 0], 0.0)
    core.on_detections(list(BREAD), SIZE, 0.0)
    core.on_joint_states(FR3_NAMES, list(READY), 0.0)  # the FR3 publishes only its own joints
    cmd, st = core.step(0.0)
    assert st.code == Code.MODEL_ERROR and np.all(cmd == 0)
    assert "lack panda_joint1" in st.reason and "fr3_joint1" in st.reason and "joint_map" in st.reason
    core.set_joint_map(FR3_MAP)
    robot = [FR3_NAMES[i] for i in (6, 0, 1, 2, 3, 4, 5)]  # in whatever order the FR3 lists them
    core.on_joint_states(robot, [READY[FR3_NAMES.index(n)] for n in robot], 0.0)
    assert core.step(0.0)[1].code == Code.AWAITING_NEUTRAL            # the refusal was a stop
    neutral(core, 0.0)
    core.on_joy([0.8, 0.0], [0, 0, 0], 0.0)
    cmd, st = core.step(0.0)
    assert st.code == Code.ACTIVE and core.command_joints == tuple(robot)
    np.testing.assert_array_equal(cmd, [want[n.replace("fr3", "panda")] for n in robot])


def test_the_fr3_limits_apply_to_its_joints(random_model_dir):
    core = make_core(random_model_dir, action_scale=1000.0, max_joint_speed=0.0,
                     dq_max={"fr3_joint1": 0.1, "panda_joint1": 9.0})
    core.set_joint_map(FR3_MAP)
    core.on_joy([0.8, 0.0], [0, 0, 0], 0.0)
    core.on_detections(list(BREAD), SIZE, 0.0)
    core.on_joint_states(FR3_NAMES, list(READY), 0.0)
    cmd, st = core.step(0.0)
    assert st.code == Code.ACTIVE and abs(cmd[0]) == pytest.approx(0.1)


@pytest.mark.parametrize(
    "entries, match",
    [
        (["fr3_joint1"], "not 'robot_joint:model_joint'"),
        (["fr3_joint1:panda_joint1", "fr3_joint2:panda_joint1"], "twice"),
        (["fr3_joint1:panda_joint1", "fr3_joint1:panda_joint2"], "twice"),
        ([":panda_joint1"], "not 'robot_joint:model_joint'"),
    ],
)
def test_bad_joint_maps_are_refused(entries, match):
    with pytest.raises(ValueError, match=match):
        parse_joint_map(entries)


def test_joint_map_parses_robot_to_model_pairs():
    assert parse_joint_map([" fr3_joint1 : panda_joint1", "b:a"]) == {"panda_joint1": "fr3_joint1", "a": "b"}
    assert parse_joint_map([]) == {}


def test_the_grasp_button_counts_presses_not_holds(random_model_dir):
    core = make_core(random_model_dir, grasp_button=1)
    core.on_joy([0.0, 0.0], [0, 0, 0, 0], 0.0)
    for k in range(10):                       # held down: one press
        core.on_joy([0.0, 0.0], [0, 1, 0, 0], 0.1 + 0.01 * k)
    assert core.grasp_presses == 1
    core.on_joy([0.0, 0.0], [0, 0, 0, 0], 0.3)
    core.on_joy([0.0, 0.0], [0, 1, 0, 0], 0.4)
    assert core.grasp_presses == 2
    core.on_joy([0.0], [], 0.5)               # a joy without that button: no press, no error
    assert core.grasp_presses == 2


STOPS = {
    # name: (what happens at t = 1.0 while the stick is held, the code it gives)
    "joy timeout": (lambda core: None, Code.JOY_TIMEOUT),
    "joint states late": (lambda core: setattr(core._js, "t", 0.0), Code.WAITING_FOR_JOINT_STATES),
    "bad joy input": (lambda core: core.on_joy([float("nan")], [], 1.0), Code.BAD_INPUT),
    "re-detect": (lambda core: core.request_redetect(1.0), Code.WAITING_FOR_DETECTION),
}


@pytest.mark.parametrize("stop", sorted(STOPS))
@pytest.mark.parametrize("gap", [0.15, 0.3, 0.5])
def test_a_stop_the_operator_did_not_choose_holds_until_neutral(random_model_dir, stop, gap):
    """Issue 20 item 1: after any zero the operator did not choose, a held stick with input gaps of
    0.15-0.5 s gives zero (AWAITING_NEUTRAL) until the stick returns to neutral; then it moves."""
    core = make_core(random_model_dir, joy_timeout=0.1, joint_states_timeout=0.5)
    feed(core, 0.0, axis=1.0)
    assert core.step(0.0)[1].code == Code.ACTIVE
    cause, code = STOPS[stop]
    if stop == "joy timeout":
        core.on_joint_states(NAMES, list(READY), 1.0)
    else:
        feed(core, {"joint states late": 0.4, "re-detect": 0.99}.get(stop, 1.0), axis=1.0)
    cause(core)
    assert core.step(1.0)[1].code == code
    t, seen = 1.0, set()
    for _ in range(12):                       # the stick stays held; its messages come with gaps
        t += gap
        feed(core, t, axis=1.0)
        cmd, st = core.step(t + 0.01)
        seen.add(st.code)
        assert np.all(cmd == 0.0), (stop, st.code, st.reason)
        cmd, st = core.step(t + gap * 0.9)    # and between them
        assert np.all(cmd == 0.0), (stop, st.code, st.reason)
    assert Code.AWAITING_NEUTRAL in seen
    feed(core, t + 1.0, axis=0.0)
    assert core.step(t + 1.0)[1].code == Code.ZERO_DEADBAND
    feed(core, t + 1.05, axis=1.0)
    cmd, st = core.step(t + 1.05)
    assert st.code == Code.ACTIVE and np.linalg.norm(cmd) > 0


def test_the_controller_starts_disarmed_and_a_deadman_release_is_a_neutral(random_model_dir):
    core = make_core(random_model_dir, armed=False, enable_button=1)
    feed(core, 0.0, axis=1.0, buttons=(0, 1))
    cmd, st = core.step(0.0)
    assert st.code == Code.AWAITING_NEUTRAL and np.all(cmd == 0.0) and "starting" in st.reason
    feed(core, 0.01, axis=1.0, buttons=(0, 0))     # the operator lets go of the deadman
    assert core.step(0.01)[1].code == Code.DEADMAN_RELEASED
    feed(core, 0.02, axis=1.0, buttons=(0, 1))
    cmd, st = core.step(0.02)
    assert st.code == Code.ACTIVE and np.linalg.norm(cmd) > 0


def test_select_target_by_class_index_pixel_and_back_to_policy(random_model_dir):
    core = make_core(random_model_dir)
    two = [Detection("bread", 0.9, 100, 100, 40, 40), Detection("soda_can", 0.5, 400, 300, 60, 80)]
    feed(core, 0.0, dets=two)
    st = core.step(0.0)[1]
    assert st.latched_class == "bread" and st.latched_by == "goal_selection: highest_score"
    ok, msg = core.select_target("pixel", "", -1, 410.0, 330.0, 0.1)
    assert ok, msg
    assert core.step(0.1)[1].code == Code.WAITING_FOR_DETECTION  # latched from the next detection only
    feed(core, 0.2, dets=two)
    st = core.step(0.2)[1]
    assert st.latched_class == "soda_can" and st.latched_by == "operator: pixel (410, 330)"
    assert core.select_target("index", "", 0, 0, 0, 0.3)[0]
    feed(core, 0.4, dets=two)
    st = core.step(0.4)[1]
    assert st.latched_class == "bread" and st.latched_by == "operator: index 0"
    assert core.select_target("class", "soda_can", -1, 0, 0, 0.5)[0]
    feed(core, 0.6, dets=two)
    assert core.step(0.6)[1].latched_by == "operator: class soda_can"
    assert core.select_target("policy", "", -1, 0, 0, 0.7)[0]
    feed(core, 0.8, dets=two)
    st = core.step(0.8)[1]
    assert st.latched_class == "bread" and st.latched_by == "goal_selection: highest_score"


@pytest.mark.parametrize("by, cls, idx, x, y, text", [
    ("class", "unicorn", -1, 0, 0, "not one of the model's classes"),
    ("index", "", 5, 0, 0, "not in the latest"),
    ("pixel", "", -1, math.nan, 0, "finite"),
    ("nearest", "", -1, 0, 0, "unknown selection"),
])
def test_select_target_refusals_keep_the_latch(random_model_dir, by, cls, idx, x, y, text):
    core = make_core(random_model_dir)
    feed(core, 0.0)
    assert core.step(0.0)[1].latched_class == "bread"
    ok, msg = core.select_target(by, cls, idx, x, y, 0.1)
    assert not ok and text in msg
    assert core.step(0.1)[1].latched_class == "bread"


def test_a_pick_not_in_view_waits_with_a_reason(random_model_dir):
    core = make_core(random_model_dir)
    feed(core, 0.0)
    assert core.select_target("pixel", "", -1, 5.0, 5.0, 0.1)[0]
    feed(core, 0.2)
    st = core.step(0.2)[1]
    assert st.code == Code.WAITING_FOR_DETECTION and "operator: pixel (5, 5)" in st.reason


def test_the_command_has_the_chords_speed_and_the_paths_direction(random_model_dir):
    """path_fraction (issue 20): the speed of the chord at z, the direction of the chord at
    path_fraction x z; batch and single agree; 1 is the raw action, 0 (the default) the model's
    calibrated one, 1 for a model without one."""
    core = make_core(random_model_dir, action_scale=1.0, max_joint_speed=0.0)
    feed(core, 0.0, axis=1.0)
    assert core.params.path_fraction == 0.0 and core.model.path_fraction() == 1.0
    raw = core.step(0.0)[0].copy()
    PATH_FRACTION = core.params.path_fraction = 0.65
    cmd = core.step(0.0)[0].copy()
    dec, z = core.model.decoder, core.status.z
    q = np.asarray(core._js.positions, dtype=float)
    chord, path = dec.decode(q, z).copy(), dec.decode(q, PATH_FRACTION * z).copy()
    assert 0.0 < PATH_FRACTION < 1.0 and not np.allclose(chord / np.linalg.norm(chord),
                                                         path / np.linalg.norm(path))
    np.testing.assert_array_equal(raw, chord)
    assert np.linalg.norm(cmd) == pytest.approx(np.linalg.norm(chord))
    np.testing.assert_allclose(cmd / np.linalg.norm(cmd), path / np.linalg.norm(path), atol=1e-12)
    zs = np.array([-z, 0.3 * z, z])
    batch = dec.velocity_batch(q, zs, PATH_FRACTION)
    for i, zi in enumerate(zs):
        np.testing.assert_allclose(batch[i], dec.velocity(q, zi, PATH_FRACTION), atol=1e-12)
    # 0: the model's calibrated fraction (its latent.path_fraction)
    core.params.path_fraction = 0.0
    core.model.config["latent"]["path_fraction"] = PATH_FRACTION
    np.testing.assert_allclose(core.step(0.0)[0], cmd, atol=1e-12)
    core.params.path_fraction = 1.5
    assert core.step(0.0)[1].code == Code.MODEL_ERROR  # refused: [0, 1]
    np.testing.assert_array_equal(dec.velocity(q, z, 1.0), chord)

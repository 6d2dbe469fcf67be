"""The station node's caregiver settings in process (no browser): a refused file at start, a save that
keeps it aside, refusals in words, and a deadband refused while the controller is unreachable."""
import json

import pytest
from rclpy.parameter import Parameter
from vla_common.ros.testing import RosHarness
from vla_operator.settings import defaults
from vla_operator.station_node import StationNode

pytestmark = pytest.mark.ros


@pytest.fixture
def station(tmp_path):
    h = RosHarness()

    def make(settings: bytes | None = None, **params):
        path = tmp_path / "settings.json"
        if settings is not None:
            path.write_bytes(settings)
        overrides = [Parameter("port", value=0), Parameter("settings_file", value=str(path)),
                     Parameter("token_file", value=str(tmp_path / "token")),
                     Parameter("controller", value="no_such_controller_for_this_test"),
                     *(Parameter(k, value=v) for k, v in params.items())]
        return h.add(StationNode(context=h.context, parameter_overrides=overrides)), path
    make.harness = h
    yield make
    h.shutdown()


def save(node, values: dict) -> dict:
    replies = []
    node._apply_settings(values, replies.append)
    assert len(replies) == 1
    return replies[0]


def test_a_refused_file_gives_the_defaults_says_so_and_is_kept_aside_on_save(station):
    node, path = station(b'{"speed_scale": 0.5, "x": "<secret>"', speed_scale=0.7)
    assert node.settings == {**defaults(), "speed_scale": 0.7}
    assert "is not valid JSON: using the defaults" in node.settings_problem
    assert node.state["settings_problem"] == node.settings_problem and "secret" not in node.settings_problem
    reply = save(node, {"action_mode": "toggle"})
    assert reply["ok"] and "kept as settings.json.refused" in reply["message"], reply
    assert path.with_name("settings.json.refused").read_bytes().startswith(b'{"speed_scale": 0.5')
    assert json.loads(path.read_text())["action_mode"] == "toggle"
    assert node.state["settings_problem"] == ""


def test_the_file_wins_over_the_parameter_and_a_save_sets_it(station):
    node, path = station(json.dumps({"speed_scale": 0.4}).encode())
    assert node.get_parameter("speed_scale").value == 0.4 and node.settings["speed_scale"] == 0.4
    assert save(node, {"speed_scale": 0.9})["ok"]
    assert node.get_parameter("speed_scale").value == 0.9
    assert json.loads(path.read_text())["speed_scale"] == 0.9


def test_refusals_change_nothing(station):
    node, path = station()
    for values, words in (({"speed_scale": 2}, "speed_scale must be from 0.05 to 1.0"),
                          ({"speedscale": 1}, "did you mean 'speed_scale'?"),
                          ({"deadband": 0.2, "action_mode": "step"}, "no_such_controller_for_this_test/"
                           "set_parameters_atomically is not available")):
        reply = save(node, values)
        assert not reply["ok"] and words in reply["message"], reply
    assert not path.exists() and node.settings == defaults()


def test_next_axis_presses_the_controllers_mode_button_in_the_joy(station):
    """The page's "next axis" is the controller's own ee_mode_button, held for MODE_PRESS_S as a finger
    would; refused in words while the controller's button is not known (no controller here)."""
    from sensor_msgs.msg import Joy

    node, _ = station()
    replies = []
    node._request({"type": "ee_next"}, replies.append)
    assert not replies[-1]["ok"] and "ee_mode_button" in replies[-1]["message"]
    seen = []
    node.create_subscription(Joy, "joy", seen.append, 50)
    assert station.harness.spin_until(lambda: node.joy_pub.get_subscription_count() > 0, 10.0)
    node._ee_button = 5                      # as read from the controller's parameter
    node._request({"type": "ee_next"}, replies.append)
    assert replies[-1]["ok"]
    assert station.harness.spin_until(lambda: bool(seen), 10.0)
    assert len(seen[0].buttons) >= 6 and list(seen[0].buttons).count(1) == 1 and seen[0].buttons[5] == 1
    assert seen[0].axes[0] == 0.0            # nobody drives: the stick stays at rest
    node._mode_until = 0.0                   # the press is over: the next Joy releases it
    node._publish_axis(0.0)
    assert station.harness.spin_until(lambda: len(seen) >= 2, 10.0) and not any(seen[-1].buttons)


def test_the_address_is_printed_once_with_a_line_that_says_to_wait(station, capfd):
    """Issue 32: the address was printed twice among the nodes' INFO lines, with nothing saying to wait
    while the graph starts."""
    node, _ = station()
    out = capfd.readouterr()
    lines = (out.out + out.err).splitlines()
    assert sum(node.address in line for line in lines) == 1, lines
    assert any("may take a minute to start" in line for line in lines), lines

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
                     Parameter("controller", value="no_such_controller_for_this_test"),
                     *(Parameter(k, value=v) for k, v in params.items())]
        return h.add(StationNode(context=h.context, parameter_overrides=overrides)), path
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
                           "set_parameters is not available")):
        reply = save(node, values)
        assert not reply["ok"] and words in reply["message"], reply
    assert not path.exists() and node.settings == defaults()

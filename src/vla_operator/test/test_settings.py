"""The caregiver's settings without ROS: validation of untrusted values, the file's atomic write and
its refusals that never quote the file."""
import json

import pytest
from vla_operator.settings import SettingError, defaults, keep_aside, load, save, validate

from vla_operator import settings as cfg


def test_defaults_are_valid_and_a_copy():
    d = defaults()
    assert validate(d) == d
    d["keys"]["forward"].append("x")
    assert "x" not in defaults()["keys"]["forward"]


@pytest.mark.parametrize("values, words", [
    ({"speed_scale": 0.0}, "speed_scale must be from 0.05 to 1.0"),
    ({"speed_scale": float("nan")}, "speed_scale must be a number"),
    ({"speed_scale": float("inf")}, "speed_scale must be a number"),
    ({"speed_scale": 10**400}, "speed_scale must be a number"),
    ({"step_seconds": -10**400}, "step_seconds must be a number"),
    ({"deadband": 1e400}, "deadband must be a number"),
    ({"stop_on_stale_view": 1}, "stop_on_stale_view must be true or false"),
    ({"speed_scale": True}, "speed_scale must be a number"),
    ({"speed_scale": "1"}, "speed_scale must be a number"),
    ({"deadband": 1.0}, "deadband must be from 0.0 to 1.0 (excluded)"),
    ({"deadband": -0.1}, "deadband must be from"),
    ({"action_mode": "run"}, "action_mode must be one of: hold, step, toggle"),
    ({"assistance": "medium"}, "assistance must be one of: off, low, high"),
    ({"assistance": 1}, "assistance must be one of: off, low, high"),
    ({"step_seconds": 0.05}, "step_seconds must be from 0.1 to 2.0"),
    ({"step_seconds": None}, "step_seconds must be a number"),
    ({"scan_period": 10}, "scan_period must be from 0.5 to 5.0"),
    ({"input_device": "mouse"}, "input_device must be one of"),
    ({"keys": []}, "keys must be an object"),
    ({"keys": {"forward": ["ArrowUp"], "back": ["k"]}}, "keys.stop is missing"),
    ({"keys": {"forward": [], "back": ["k"], "stop": ["Escape"]}}, "keys.forward must be a list of 1 to 3"),
    ({"keys": {"forward": ["a", "b", "c", "d"], "back": ["k"], "stop": ["Escape"]}}, "1 to 3"),
    ({"keys": {"forward": ["j"], "back": ["J"], "stop": ["Escape"]}}, "j is given twice (forward and back)"),
    ({"keys": {"forward": ["Escape"], "back": ["k"], "stop": ["s"]}}, "Escape may only stop"),
    ({"keys": {"forward": [" "], "back": ["k"], "stop": ["Escape"]}}, "keys.forward: a key is not allowed"),
    ({"keys": {"forward": ["Tab"], "back": ["k"], "stop": ["Escape"]}}, "not allowed"),
    ({"keys": {"forward": ["F5"], "back": ["k"], "stop": ["Escape"]}}, "not allowed"),
    ({"keys": {"forward": ["Arrowup"], "back": ["k"], "stop": ["Escape"]}}, "did you mean ArrowUp?"),
    ({"keys": {"forward": [1], "back": ["k"], "stop": ["Escape"]}}, "each key must be a key name"),
    ({"keys": {"forwrd": ["j"], "back": ["k"], "stop": ["Escape"]}}, "did you mean 'forward'?"),
    ({"deadbnd": 0.2}, "unknown setting 'deadbnd' (did you mean 'deadband'?)"),
    ([1, 2], "settings must be an object"),
])
def test_refusals_name_the_setting_and_what_is_allowed(values, words):
    with pytest.raises(SettingError) as e:
        validate(values)
    assert words in str(e.value)


def test_a_refusal_never_quotes_the_value():
    secret = "<script>alert(1)</script>"
    for values in ({"action_mode": secret}, {"keys": {"forward": [secret], "back": ["k"], "stop": ["s"]}},
                   {secret: 1}):
        with pytest.raises(SettingError) as e:
            validate(values, quote_names=False)
        assert "script" not in str(e.value)


def test_valid_values_are_cleaned():
    v = validate({"speed_scale": 1, "deadband": 0.3, "action_mode": "step", "input_device": "gamepad",
                  "keys": {"forward": ["W", "ArrowUp"], "back": ["s"], "stop": ["Escape", "0"]}})
    assert v["speed_scale"] == 1.0 and isinstance(v["speed_scale"], float)
    assert v["keys"] == {"forward": ["w", "ArrowUp"], "back": ["s"], "stop": ["Escape", "0"]}
    assert validate({"deadband": None}) == {"deadband": None}   # the controller's own
    assert validate({"assistance": None, "stop_on_stale_view": True}) == {"assistance": None,
                                                                          "stop_on_stale_view": True}
    assert validate({"assistance": "high"}) == {"assistance": "high"}


def test_save_then_load_round_trip(tmp_path):
    path = tmp_path / "sub" / "settings.json"
    assert load(path) == (defaults(), "")            # no file yet: defaults, no problem
    s = {**defaults(), "speed_scale": 0.4, "deadband": 0.2, "action_mode": "toggle"}
    save(path, s)
    assert load(path) == (s, "")
    assert [p.name for p in path.parent.iterdir()] == ["settings.json"]   # no temporary file left


def test_save_is_atomic_the_old_file_survives_a_failed_write(tmp_path, monkeypatch):
    path = tmp_path / "settings.json"
    save(path, defaults())
    before = path.read_bytes()

    def full_disk(fd):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(cfg.os, "fsync", full_disk)
    with pytest.raises(OSError):
        save(path, {**defaults(), "speed_scale": 0.5})
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["settings.json"]


def test_save_refuses_invalid_settings(tmp_path):
    with pytest.raises(SettingError):
        save(tmp_path / "s.json", {**defaults(), "action_mode": "run"})
    assert not (tmp_path / "s.json").exists()


@pytest.mark.parametrize("content, words", [
    (b"{not json <secret>", "is not valid JSON"),
    (b"\xff\xfe<secret>", "is not valid JSON"),
    (b'["<secret>"]', "was refused (settings must be an object"),
    (b'{"action_mode": "<secret>"}', "was refused (action_mode must be one of"),
    (b'{"<secret>": 1}', "was refused (unknown setting; the settings are"),
    (b'{"speed_scal": 1}', "(did you mean 'speed_scale'?)"),
])
def test_a_bad_file_keeps_the_defaults_says_so_and_never_quotes_it(tmp_path, content, words):
    path = tmp_path / "settings.json"
    path.write_bytes(content)
    s, problem = load(path, {**defaults(), "speed_scale": 0.7})
    assert s == {**defaults(), "speed_scale": 0.7}
    assert words in problem and "using the defaults" in problem and str(path) in problem
    assert "secret" not in problem


def test_an_oversized_file_is_not_read(tmp_path):
    path = tmp_path / "settings.json"
    path.write_text(json.dumps({"speed_scale": 0.5}) + " " * cfg.MAX_FILE_BYTES)
    s, problem = load(path)
    assert s == defaults() and f"larger than {cfg.MAX_FILE_BYTES} bytes" in problem


def test_an_unreadable_file_says_why(tmp_path):
    path = tmp_path / "settings.json"
    path.mkdir()
    s, problem = load(path)
    assert s == defaults() and "cannot be read" in problem


def test_a_refused_file_is_kept_aside_not_lost(tmp_path):
    path = tmp_path / "settings.json"
    path.write_bytes(b"{broken")
    aside = keep_aside(path)
    assert aside is not None and aside.read_bytes() == b"{broken" and not path.exists()
    assert keep_aside(path) is None

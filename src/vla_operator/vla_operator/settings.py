"""The caregiver's settings (no rclpy): their schema (a pydantic model) and defaults, the validation of
untrusted values (a page's, or the settings file's), and the file on the robot PC, written atomically
and read with a size bound.

Every value is checked here before anything applies it: the page is a network peer and the file may
be damaged. An error names the setting and what is allowed, and never quotes a value or a file's
content (a page's unknown setting name is quoted back to that page, with the closest known one). The
deadband and the assistance level are the controller's own parameters: the controller decides (its
refusal is shown with its reason).
"""
from __future__ import annotations

import difflib
import json
import os
import string
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, model_validator

from vla_operator.schema import number, refusal, refused

MAX_FILE_BYTES = 16384          # the settings file is a few hundred bytes; anything larger is not ours
MAX_KEYS_PER_ACTION = 3
KEY_ACTIONS = ("forward", "back", "stop")
# Keys a mapping may use. Space, Enter and Tab are not among them: they operate and reach the page's
# controls (Space is also the single switch), and function keys belong to the browser (F5 reloads).
NAMED_KEYS = ("ArrowUp", "ArrowDown", "ArrowLeft", "ArrowRight", "PageUp", "PageDown", "Home", "End",
              "Escape")
ALLOWED_KEYS = frozenset(NAMED_KEYS) | frozenset(string.ascii_lowercase) | frozenset(string.digits)
ALLOWED_KEYS_WORDS = ", ".join(NAMED_KEYS) + ", a letter a-z or a digit 0-9"


class SettingError(ValueError):
    """A refused value; the message is safe to show and to log (it never quotes the value)."""


def _key_name(k: Any) -> str:
    """One key of the mapping: an allowed key's name (J and j are the same key)."""
    if not isinstance(k, str):
        raise refused("each key must be a key name")
    if len(k) == 1:
        k = k.lower()
    if k not in ALLOWED_KEYS:
        close = difflib.get_close_matches(k, NAMED_KEYS, n=1, cutoff=0.6) if len(k) <= 20 else []
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise refused(f"a key is not allowed{hint}; allowed: {ALLOWED_KEYS_WORDS}")
    return k


KeyList = Annotated[list[Annotated[str, BeforeValidator(_key_name)]],
                    Field(min_length=1, max_length=MAX_KEYS_PER_ACTION)]


class Keys(BaseModel):
    """{forward, back, stop}: each 1 to 3 allowed keys, no key twice; Escape only stops."""

    model_config = ConfigDict(strict=True, extra="forbid")
    NOUN: ClassVar[str] = "action"
    forward: KeyList
    back: KeyList
    stop: KeyList

    @model_validator(mode="after")
    def _each_key_once(self) -> Keys:
        seen: dict[str, str] = {}
        for action in KEY_ACTIONS:
            for k in getattr(self, action):   # k is one of ALLOWED_KEYS: our own name, not the input's
                if k in seen:
                    raise refused(f"{k} is given twice ({seen[k]} and {action})")
                if k == "Escape" and action != "stop":
                    raise refused("Escape may only stop the arm")
                seen[k] = action
        return self


class Values(BaseModel):
    """The settings a page or the file may give, any of them (absent ones are left as they are). The
    deadband and the assistance level are the controller's own parameters (None: the controller's as
    it is): the deadband's range here is the widest it can be, the controller's own range decides (its
    refusal is shown with its reason)."""

    model_config = ConfigDict(strict=True, extra="forbid")
    NOUN: ClassVar[str] = "setting"
    speed_scale: number(0.05, 1.0) = None
    deadband: number(0.0, 1.0, hi_open=True) | None = None
    assistance: Literal["off", "low", "high"] | None = None
    action_mode: Literal["hold", "step", "toggle"] = None
    input_device: Literal["buttons", "switch1", "switch2", "gamepad"] = None
    step_seconds: number(0.1, 2.0) = None
    scan_period: number(0.5, 5.0) = None
    keys: Keys = None
    stop_on_stale_view: bool = None


@dataclass(frozen=True)
class Setting:
    name: str
    default: Any
    words: str


SETTINGS: dict[str, Setting] = {s.name: s for s in (
    Setting("speed_scale", 1.0,
            "the page's axis times this (0.05 to 1); the station's speed_scale parameter"),
    Setting("deadband", None,
            "the controller's deadband parameter (its range applies); none: the controller's own"),
    Setting("assistance", None,
            "the controller's assistance parameter: off, low (at most half the command) or high; goal "
            "inference and a pull toward the inferred goal; none: the controller's own"),
    Setting("action_mode", "hold",
            "hold: moves while held; step: a short move per press; toggle: press to start, press to stop"),
    Setting("input_device", "buttons",
            "buttons (on-screen and keys), switch1 (single switch, scanning with Space), switch2 (dual "
            "switch: its keys are the mapping's), gamepad (the first pad's left stick)"),
    Setting("step_seconds", 0.3, "step mode: how long one press drives, in seconds (0.1 to 2)"),
    Setting("scan_period", 1.5,
            "single switch: seconds the scanning highlight stays on each control (0.5 to 5)"),
    Setting("keys", {"forward": ["ArrowUp", "ArrowRight", "j"], "back": ["ArrowDown", "ArrowLeft", "k"],
                     "stop": ["Escape"]},
            f"keys for forward, back and stop: 1 to {MAX_KEYS_PER_ACTION} each, no key twice, Escape only "
            "stops"),
    Setting("stop_on_stale_view", False,
            "stop the arm while the live view has had no new frame for 1 s (motion then needs a neutral "
            "input once the view is live again); off: the page only says that the view is stale"),
)}
assert set(SETTINGS) == set(Values.model_fields), "one table of settings: the model and its defaults"
# The settings that are the controller's own parameters (set through its parameter service), in words
CONTROLLER_SETTINGS = {"deadband": "the deadband", "assistance": "the assistance level"}


def defaults() -> dict[str, Any]:
    return json.loads(json.dumps({n: s.default for n, s in SETTINGS.items()}))   # a deep copy


def validate(values: Any, quote_names: bool = True) -> dict[str, Any]:
    """The clean values of a (partial) settings object, or SettingError for the first refused one (it
    names the setting and what is allowed). An unknown name is refused with the closest known one; it
    is quoted only when ``quote_names`` (to the page that sent it, never from a file)."""
    if not isinstance(values, dict):
        raise SettingError("settings must be an object {name: value}")
    try:
        m = Values.model_validate(values)
    except ValidationError as e:
        raise SettingError(refusal(Values, e, quote_names=quote_names)) from None
    clean = {name: getattr(m, name) for name in values}
    return {n: v.model_dump() if isinstance(v, BaseModel) else v for n, v in clean.items()}


def load(path: Path, base: dict[str, Any] | None = None) -> tuple[dict[str, Any], str]:
    """(settings, problem): the file's settings over ``base`` (the defaults), or ``base`` and why the
    file was not used ("" when it was, or when there is none yet). The problem never quotes the file."""
    s = dict(base) if base is not None else defaults()
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            return s, f"settings file {path} is larger than {MAX_FILE_BYTES} bytes: using the defaults"
        with path.open("rb") as f:
            raw = f.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        return s, ""
    except OSError as e:
        return s, f"settings file {path} cannot be read ({e.strerror}): using the defaults"
    try:
        data = json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        return s, f"settings file {path} is not valid JSON: using the defaults"
    try:
        s.update(validate(data, quote_names=False))
    except SettingError as e:
        return s, f"settings file {path} was refused ({e}): using the defaults"
    return s, ""


def save(path: Path, settings: dict[str, Any]) -> None:
    """Write atomically (a temporary file in the same folder, flushed, then renamed over the old one):
    a crash or a full disk leaves the previous file whole. OSError when it cannot be written."""
    validate(settings)      # never write what would be refused when read back
    data = json.dumps(settings, indent=1, sort_keys=True).encode()
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def keep_aside(path: Path) -> Path | None:
    """Move a refused settings file aside (``<name>.refused``) before it is replaced: no data is lost.
    The path it went to, or None when there was none."""
    if not path.exists():
        return None
    aside = path.with_name(path.name + ".refused")
    os.replace(path, aside)
    return aside

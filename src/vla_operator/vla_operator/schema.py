"""What each message from a page, and the caregiver's settings, must be: one pydantic model each (no
rclpy). Strict: no type is coerced (JSON ``4.0``, ``true`` and ``"4"`` are not whole numbers), every
number is finite and within its range, every string bounded. A refusal names the field and what it
must be, never quoting the value: ``1e400`` (infinite), ``10**400`` (an integer too large for a float)
or an index of ``1e20`` in any numeric field is refused with the field's name, and the connection
survives (issue 32: such numbers raised in the node and closed the operator's link).

The JSON is read with pydantic's own parser: its nesting is bounded (``json.loads`` of 1000 nested
brackets, which fit in one 2 KiB message, raised RecursionError and closed the link) and its large
numbers are kept whole, so the schema refuses them by name.
"""
from __future__ import annotations

import difflib
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator
from pydantic.fields import FieldInfo
from pydantic_core import PydanticCustomError, from_json

INT32 = (-(2**31), 2**31 - 1)
MAX_SEQ = 2**53                 # a page's counters are JavaScript numbers: whole up to 2^53


def number(lo: float, hi: float, hi_open: bool = False) -> Any:
    """A finite number (an integer is one too) from lo to hi (hi excluded when hi_open)."""
    return Annotated[float, Field(ge=lo, allow_inf_nan=False, **({"lt": hi} if hi_open else {"le": hi}))]


def whole(lo: int, hi: int) -> Any:
    return Annotated[int, Field(ge=lo, le=hi)]


def text(max_length: int, min_length: int = 0) -> Any:
    return Annotated[str, Field(min_length=min_length, max_length=max_length)]


class Message(BaseModel):
    """A page's message. Unknown fields are ignored (never used: only the model's fields go on)."""

    model_config = ConfigDict(strict=True, extra="ignore", frozen=True)


class Input(Message):
    type: Literal["input"]
    seq: whole(0, MAX_SEQ)
    t: number(-1e13, 1e13)      # ms on the page's clock (performance.now())
    axis: number(-1.0, 1.0)


class Bare(Message):
    """A message that is its type only (heartbeat, hidden, estop, gripper, ee_next, redetect)."""

    type: str


class Claim(Message):
    type: Literal["claim"]
    confirm: bool = False


class ReleaseEstop(Message):
    type: Literal["release_estop"]
    confirm: bool = False

    @model_validator(mode="after")
    def _confirmed(self) -> ReleaseEstop:
        if not self.confirm:
            raise refused("releasing the e-stop needs confirm: true")
        return self


class Select(Message):
    type: Literal["select"]
    by: Literal["class", "index", "pixel", "policy"]
    class_id: text(64) | None = None
    index: whole(*INT32) | None = None
    x: number(-1e5, 1e5) | None = None   # detector image pixels
    y: number(-1e5, 1e5) | None = None

    @model_validator(mode="after")
    def _what_by_needs(self) -> Select:
        needs = {"class": ("class_id",), "index": ("index",), "pixel": ("x", "y")}.get(self.by, ())
        for name in needs:
            if getattr(self, name) is None:
                raise refused(f"by {self.by} needs {' and '.join(needs)}")
        return self


class Teaching(Message):
    type: Literal["teaching"]
    on: bool


class Episode(Message):
    type: Literal["episode"]
    action: Literal["start", "stop", "discard"]
    task: text(128, 1) | None = None

    @model_validator(mode="after")
    def _start_needs_a_task(self) -> Episode:
        if self.action == "start" and self.task is None:
            raise refused("starting an episode needs a task")
        return self


class SettingsMessage(Message):
    type: Literal["settings"]
    values: dict[str, Any]      # each setting is checked by Settings (the node's reply names it)


class Answers(Message):
    type: Literal["answers"]
    id: whole(0, MAX_SEQ)
    answers: dict[text(300), Any]   # each answer: checked against the questionnaire that waits (its scale)


MODELS: dict[str, type[Message]] = {
    "input": Input, "heartbeat": Bare, "hidden": Bare, "claim": Claim, "estop": Bare,
    "release_estop": ReleaseEstop, "select": Select, "gripper": Bare, "ee_next": Bare,
    "redetect": Bare, "teaching": Teaching, "episode": Episode, "settings": SettingsMessage,
    "answers": Answers,
}


def parse(raw: str | bytes) -> dict | str:
    """The message as a dict with a string ``type``, or why it is malformed."""
    try:
        msg = from_json(raw, allow_inf_nan=True, cache_strings="keys")
    except ValueError:
        return "not JSON"
    if not isinstance(msg, dict) or not isinstance(msg.get("type"), str):
        return "not an object with a string 'type'"
    return msg


def check(msg: dict) -> dict | str:
    """The checked message of a known ``type`` (only its model's fields, absent ones left out), or the
    refusal, which names the field."""
    model = MODELS[msg["type"]]
    try:
        return model.model_validate(msg).model_dump(exclude_none=True)
    except ValidationError as e:
        return refusal(model, e, prefix=msg["type"])


# ---------------------------------------------------------------------- refusals in words
def refused(words: str) -> PydanticCustomError:
    """A refusal in our own words (from a validator); they must name the field and never the value."""
    return PydanticCustomError("refused", words)


def refusal(model: type[BaseModel], e: ValidationError, prefix: str = "", quote_names: bool = True) -> str:
    """The first error of ``e`` in words: the field's name and what it must be, never the value. A name
    the model does not know is quoted (40 characters at most) only when ``quote_names``."""
    errors = e.errors(include_url=False, include_input=False)
    err = next((x for x in errors if x["type"] == "extra_forbidden"), errors[0])   # a misspelt name first
    loc = [str(x) for x in err["loc"] if not isinstance(x, int)]     # list positions: the list's name
    kind, field, owner = err["type"], *_field(model, loc)
    name = ".".join(([prefix] if prefix else []) + [_shown(x, quote_names) for x in loc])
    if kind == "extra_forbidden":
        parent = ".".join(([prefix] if prefix else []) + loc[:-1])
        noun = getattr(owner, "NOUN", "field")
        known = list(owner.model_fields)
        shown = f" {loc[-1][:40]!r}" if quote_names else ""
        close = difflib.get_close_matches(loc[-1][:40], known, n=1, cutoff=0.5)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        words = f"unknown {noun}{shown}{hint}; the {noun}s are {', '.join(known)}"
        return f"{parent}: {words}" if parent else words
    if kind == "refused" or not loc:  # our own words, or a rule of the whole message
        return f"{name}: {err['msg']}" if name else err["msg"]
    if kind == "missing":
        return f"{name} is missing"
    if kind == "literal_error":
        return f"{name} must be one of: {err['ctx']['expected'].replace(' or ', ', ').replace(chr(39), '')}"
    if kind == "bool_type":
        return f"{name} must be true or false"
    if kind in ("dict_type", "model_type", "model_attributes_type"):
        return f"{name} must be an object"
    lo, hi = _constraint(field, "min_length", 0), _constraint(field, "max_length", None)
    if kind in ("list_type", "too_short", "too_long"):
        return f"{name} must be a list" + (f" of {lo} to {hi}" if hi is not None else "")
    if kind.startswith("string"):
        return f"{name} must be text" + (f" of {lo} to {hi} characters" if hi is not None else "")
    return _number_words(name, kind, field)


def _number_words(name: str, kind: str, field: FieldInfo | None) -> str:
    """A numeric field's refusal: its range when out of it, its kind and range when not a number (or an
    infinite one, or an integer no float holds)."""
    lo, hi = _constraint(field, "ge", None), _constraint(field, "le", None)
    hi_open = hi is None and _constraint(field, "lt", None) is not None
    hi = _constraint(field, "lt", None) if hi_open else hi
    is_whole = kind.startswith("int") or (isinstance(lo, int) and isinstance(hi, int))
    what = "a whole number" if is_whole else "a number"
    if lo is None or hi is None:
        return f"{name} must be {what}"
    span = f"from {_num(lo)} to {_num(hi)}{' (excluded)' if hi_open else ''}"
    if kind.startswith(("greater_than", "less_than")):
        return f"{name} must be {'a whole number ' if is_whole else ''}{span}"
    return f"{name} must be {what} {span}"


def _num(v: float) -> str:
    return repr(v) if len(repr(v)) <= 12 else f"{v:g}"


def _shown(part: str, quote: bool) -> str:
    return part if part.isidentifier() else (repr(part[:40]) if quote else "[...]")


def _field(model: type[BaseModel], loc: list[str]) -> tuple[FieldInfo | None, type[BaseModel]]:
    """(the field at ``loc``, the model that holds it), through nested models; a dict's key stays with
    the dict's field."""
    field, owner = None, model
    for part in loc:
        fields = getattr(owner, "model_fields", {}) if owner is not None else {}
        if part not in fields:
            break
        field = fields[part]
        sub = _model_in(field.annotation)
        if sub is None:
            break
        owner = sub
    return field, owner


def _model_in(annotation) -> type[BaseModel] | None:
    for a in (annotation, *getattr(annotation, "__args__", ())):
        if isinstance(a, type) and issubclass(a, BaseModel):
            return a
    return None


def _constraint(field: FieldInfo | None, name: str, default):
    """A constraint (ge, le, lt, min_length, max_length) of a field, through ``X | None`` and a dict's
    or a list's items."""
    if field is None:
        return default
    found, todo = list(field.metadata), [field.annotation]
    while todo:
        a = todo.pop()
        for arg in tuple(getattr(a, "__args__", ())) + tuple(getattr(a, "__metadata__", ())):
            if isinstance(arg, FieldInfo):
                found += arg.metadata
            elif arg is not type(None):
                todo.append(arg)
    for m in found:
        if getattr(m, name, None) is not None:
            return getattr(m, name)
    return default

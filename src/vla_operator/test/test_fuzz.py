"""Fuzzers of everything a page sends (issue 32, item 9): random messages, seeded and bounded in count,
into the link's rules, the schema and the caregiver settings. What they found on the old hand
validation, kept here as cases: an integer too large for a float (``10**400``) in ``t``, ``axis`` or a
setting raised OverflowError; 1000 nested brackets (one 2 KiB message) raised RecursionError; both
closed the operator's link.

Every message must give a verdict (never an exception), be counted exactly once, never quote markup
back, and never move the arm unless it is a well-formed input after the driver's neutral."""
from __future__ import annotations

import json
import random

import pytest
from vla_operator.link import Link
from vla_operator.schema import MODELS
from vla_operator.settings import SettingError, Values, validate

MARK = "<b>pwn</b>"
NUMBERS = ["1e400", "-1e400", "1" + "0" * 400, "-1" + "0" * 400, "1e20", "100000000000000000000", "NaN",
           "Infinity", "-0.0", "0", "1", "-1", "0.5", "1.0000000001", "2147483648", "9007199254740993",
           "1e-400", "true", "null", '"1"', "[]", "{}"]
STRINGS = ['""', json.dumps(MARK), json.dumps("x" * 3000), json.dumps("\u0000\ud7ff\u202e"), '"class"',
           '"index"', '"pixel"', '"policy"', '"start"', '"bread/push_east"', '"ArrowUp"', '"Escape"']
FIELDS = sorted({f for m in MODELS.values() for f in m.model_fields} | set(Values.model_fields) |
                {"values", "confirm", "on", MARK})


# Well-formed messages of each kind: the fuzzer breaks one field at a time (a random message alone
# rarely gets past the first check of a kind).
GOOD = {
    "input": {"seq": 7, "t": 120.5, "axis": 0.5}, "claim": {"confirm": True},
    "release_estop": {"confirm": True}, "select": {"by": "pixel", "x": 10.0, "y": 20.0, "index": 1,
                                                  "class_id": "bread"},
    "teaching": {"on": True}, "episode": {"action": "start", "task": "bread/push_east"},
    "settings": {"values": {"speed_scale": 0.5, "step_seconds": 0.3}}, "answers": {"id": 1, "answers": {}},
}


def value(rng: random.Random, depth: int = 0) -> str:
    """A JSON value's text: nasty numbers, strings, and nested objects and arrays."""
    r = rng.random()
    if r < 0.45:
        return rng.choice(NUMBERS)
    if r < 0.7:
        return rng.choice(STRINGS)
    if r < 0.8 or depth > 3:
        return rng.choice(["[" * 990 + "]" * 990, "[" * 150 + "]" * 150, "{" * 30])
    if r < 0.9:
        return "[" + ",".join(value(rng, depth + 1) for _ in range(rng.randint(0, 3))) + "]"
    return obj(rng, depth + 1)


def obj(rng: random.Random, depth: int = 0, kind: str | None = None) -> str:
    fields = rng.sample(FIELDS, rng.randint(0, 4))
    parts = [f"{json.dumps(f)}: {value(rng, depth)}" for f in fields]
    if kind is not None:
        parts.insert(rng.randint(0, len(parts)), f'"type": {json.dumps(kind)}')
    return "{" + ", ".join(parts) + "}"


def broken(rng: random.Random) -> str:
    """A well-formed message of a kind with one field (or one setting) replaced by a nasty value."""
    kind = rng.choice(list(MODELS))
    fields = {"type": json.dumps(kind), **{k: json.dumps(v) for k, v in GOOD.get(kind, {}).items()}}
    if kind == "settings" and rng.random() < 0.7:
        name = rng.choice(list(Values.model_fields))
        fields["values"] = "{" + f"{json.dumps(name)}: {value(rng)}" + "}"
    else:
        fields[rng.choice([*fields, MARK])] = value(rng)
    return "{" + ", ".join(f"{json.dumps(k)}: {v}" for k, v in fields.items()) + "}"


def message(rng: random.Random) -> str | bytes:
    r = rng.random()
    if r < 0.5:
        return broken(rng)
    if r < 0.8:
        return obj(rng, kind=rng.choice([*MODELS, "launch", MARK]))
    if r < 0.9:
        return rng.randbytes(rng.randint(0, 64))
    return value(rng)


@pytest.mark.parametrize("seed", range(4))
def test_random_messages_never_raise_never_quote_markup_and_never_move_unarmed(seed):
    rng = random.Random(seed)
    link = Link()
    driver = link.connect(0.0).cid
    watcher = link.connect(0.0).cid
    for n in range(2500):
        now = 1.0 + n * 0.001
        cid = driver if rng.random() < 0.8 else watcher
        raw = message(rng)
        was = link.value(now)
        v = link.on_message(cid, raw, now)
        assert MARK not in v.error
        if link.value(now) != was and link.value(now) != 0.0:   # moved: only an armed driver's input
            assert cid == driver and link.clients[driver].armed and not v.error
            assert json.loads(raw)["type"] == "input"
    c = link.counters.as_dict()
    assert c.pop("received") == 10000 // 4 == sum(v for k, v in c.items() if k != "coalesced")


@pytest.mark.parametrize("seed", range(3))
def test_random_settings_are_refused_in_words_without_their_values(seed):
    rng = random.Random(100 + seed)
    for _ in range(1500):
        try:
            values = json.loads(obj(rng))
        except (ValueError, RecursionError):
            continue                      # not JSON to the standard library: the page's parser refuses it
        try:
            validate(values)
            validate(values, quote_names=False)
        except SettingError as e:
            assert MARK not in str(e) or f"{MARK!r}"[:40] in str(e)   # a name, quoted only to its page
        try:
            validate(values, quote_names=False)
        except SettingError as e:
            assert MARK not in str(e) and "pwn" not in str(e)


def test_what_the_fuzzers_found_on_the_hand_validation():
    link = Link()
    cid = link.connect(0.0).cid
    big = "1" + "0" * 400
    for raw in (f'{{"type": "input", "seq": 1, "t": {big}, "axis": 0}}',
                f'{{"type": "input", "seq": 1, "t": 0, "axis": {big}}}',
                f'{{"type": "select", "by": "pixel", "x": {big}, "y": 0}}',
                "[" * 1000 + "]" * 1000):
        v = link.on_message(cid, raw, 1.0)
        assert v.error and not v.publish
    with pytest.raises(SettingError, match="speed_scale must be a number"):
        validate({"speed_scale": 10**400})


def test_random_messages_through_the_socket_never_close_it(tmp_path, page_class):
    """The same fuzzer through the running server (no ROS): every message is handled or refused, the
    server never fails on one (errors 0) and the page's socket stays open."""
    from vla_operator.server import Limits, Station

    (tmp_path / "index.html").write_text("<!doctype html>")
    token = "a-token-for-the-socket-fuzzer"
    station = Station(tmp_path, "127.0.0.1", 0, token, lambda axis: None,
                      lambda msg, reply: reply({"what": msg["type"], "ok": True}),
                      limits=Limits(max_rate=1e6, refusal_rate=1e6, max_refusals=1e6))
    station.start()
    page = page_class(f"http://127.0.0.1:{station.access.port}/?token={token}")
    try:
        rng, sent = random.Random(7), 0
        limit = station.link.params.max_message_bytes * 4       # larger: the socket is closed (below)
        while sent < 1500:
            raw = message(rng)
            if len(raw) <= limit:
                page.ws.send_binary(raw) if isinstance(raw, bytes) else page.send(raw)
                sent += 1
        page.send({"type": "heartbeat"})
        assert page.wait(lambda p: station.link.counters.received == 1501)
        assert station.counters["errors"] == 0 and not page.closed
        assert all(MARK not in json.dumps(m) for m in page.got)
        page.send("x" * (limit + 1))                            # a page never sends 8 KiB at once
        assert page.wait(lambda p: p.closed)
    finally:
        page.close()
        station.stop()

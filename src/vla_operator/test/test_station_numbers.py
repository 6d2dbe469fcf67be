"""Numbers too large for a float (issue 32, item 9): 10^400, 1e400 and an index of 1e20 in every numeric
field of every message kind, and of every caregiver setting, through the node and a page's socket. Each
is refused with the field's name, and the socket survives (the old code raised in the link or in the
node, which closed the operator's link)."""
from __future__ import annotations

import json
import typing

import pytest
from vla_operator.schema import MODELS
from vla_operator.settings import Values

pytestmark = pytest.mark.ros

BAD = ["1" + "0" * 400, "-1" + "0" * 400, "1e400", "-1e400", "1e20", "100000000000000000000"]
BASE = {"input": {"seq": 1, "t": 10.0, "axis": 0.0}, "select": {"by": "pixel", "x": 1.0, "y": 1.0},
        "answers": {"id": 1, "answers": {}}}


def numeric(annotation) -> bool:
    if annotation in (int, float):
        return True
    return any(numeric(a) for a in typing.get_args(annotation) if a is not bool)


FIELDS = [(kind, name) for kind, m in MODELS.items() for name, f in m.model_fields.items()
          if name != "type" and numeric(f.annotation)]
SETTINGS = [name for name, f in Values.model_fields.items() if numeric(f.annotation)]


def test_the_sweep_covers_the_fields_of_the_issue():
    assert {("input", "t"), ("input", "axis"), ("input", "seq"), ("select", "index"), ("select", "x"),
            ("answers", "id")} <= set(FIELDS)
    assert {"speed_scale", "deadband", "step_seconds", "scan_period"} <= set(SETTINGS)


def test_every_numeric_field_refuses_huge_numbers_by_name_and_the_socket_survives(station_node, page_class):
    node = station_node()
    page = page_class(node.address)
    try:
        assert page.wait(lambda p: p.of("hello"))
        page.send({"type": "input", "seq": 0, "t": 0.0, "axis": 0.0})    # the driver, armed
        sent = 0
        for kind, name in FIELDS:
            for literal in BAD:
                msg = {"type": kind, **BASE.get(kind, {}), name: "@"}
                if kind == "select":
                    msg["by"] = "index" if name == "index" else "pixel"
                page.send(json.dumps(msg).replace('"@"', literal))
                sent += 1
                assert page.wait(lambda p, n=sent: len(p.of("refused")) >= n), (kind, name, literal)
                r = page.of("refused")[-1]
                assert r["what"] == kind and f"{kind}.{name} must be" in r["reason"], (literal, r)
        def saves(p) -> list[dict]:
            return [m for m in p.of("reply") if m["what"] == "settings"]
        for name in SETTINGS:
            for literal in BAD:
                n = len(saves(page)) + 1
                page.send(json.dumps({"type": "settings", "values": {name: "@"}}).replace('"@"', literal))
                assert page.wait(lambda p, n=n: len(saves(p)) >= n), (name, literal)
                r = saves(page)[-1]
                assert not r["ok"] and r["message"].startswith(f"{name} must be"), (literal, r)
        assert not page.closed
        page.send({"type": "input", "seq": 2, "t": 20.0, "axis": 0.0})    # still the driver's link
        page.send({"type": "select", "by": "policy"})
        assert page.wait(lambda p: any(m["what"] == "select" for m in p.of("reply")))
        assert not page.closed and node.settings["speed_scale"] == 1.0
    finally:
        page.close()

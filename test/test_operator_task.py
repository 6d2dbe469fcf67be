"""Must-show of issue 32 item 5: the whole base task, the bread pushed east, through the operator
station's page alone, by a scripted keyboard user, a scripted single-switch user and a scripted gamepad
user (test/page_persons.py) in headless Chromium.

The graph and the trial are test/page_task.py's: the study's graph for a real participant, the scene
reset to one fresh layout before each person, the bread latched, the evaluation's judge on the
simulation's ground truth. Each person must push the bread east; the time to success is printed
(simulated s, and wall s from the first press) with the load average: figures, not an assertion
(bench/bench_operator_task.py runs it several times).
"""
from __future__ import annotations

import time

import pytest
from page_persons import PERSONS
from page_task import push_bread_east, station_graph

pytestmark = [pytest.mark.slow, pytest.mark.ros]


@pytest.fixture(scope="module")
def graph_and_page():
    from test_operator_station import browser_needed

    browser_needed()
    with station_graph() as g:
        yield g


@pytest.mark.timeout(1500)
def test_the_bread_is_pushed_east_through_the_page_by_keyboard_switch_and_gamepad(graph_and_page):
    ev, b = graph_and_page
    results = []
    for person_cls in PERSONS:
        t0 = time.monotonic()
        r = push_bread_east(ev, b, person_cls)
        r["trial_wall_s"] = round(time.monotonic() - t0, 1)
        print(f"[task through the page] {r}", flush=True)
        results.append(r)
    assert [r["person"] for r in results if not r["done"]] == [], results

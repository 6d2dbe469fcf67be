"""The questionnaire after each strategy (issue 24): on the operator station when the study runs with
it, else on the terminal, the same row in likert.jsonl either way; when the station does not answer
the runner says why and asks on the terminal, so no answers are lost. The station's page in a real
browser is test/test_operator_station.py's."""
from __future__ import annotations

import json
import threading

import numpy as np
import pytest
from vla_study.protocol import load_protocol
from vla_study.questionnaire import StationQuestionnaire, check_answers, likert_row, station_for
from vla_study.runner import LIKERT, run_study

TWO_STRATEGIES = """study: questionnaire
participants: P01
strategies: [latent-YOLO, end-effector]
settings:
  Seen: cereal_box/push_south
trials: 1
practice: {trials: 0, reset_seed: 7}
time_limit: 5
rate: 20
"""


class FakeStation:
    """The station's asker: answers from a list, or None with a reason (it did not answer)."""

    def __init__(self, outcomes):
        self.outcomes, self.asked = list(outcomes), []

    def ask(self, title, statements):
        self.asked.append((title, list(statements)))
        return self.outcomes.pop(0)


class FakeBackend:
    """Trials without a graph; the station is its `questionnaire` (station_for takes it)."""

    def __init__(self, station=None):
        if station is not None:
            self.questionnaire = station

    def run(self, trial, params, operator_seed):
        return ({"success": True, "time_s": 1.0, "path_length_m": 0.1, "mode_switches": 0, "sparc": None},
                {"t": np.zeros(1, np.float32)})


def study(tmp_path, backend, answers=()):
    f = tmp_path / "q.yaml"
    f.write_text(TWO_STRATEGIES)
    out, logs, typed = tmp_path / "study", [], iter(answers)
    run_study(load_protocol(f), out, backend=backend, log=logs.append, ask=lambda q: next(typed))
    rows = [json.loads(x) for x in (out / "likert.jsonl").read_text().splitlines()]
    return rows, logs, out


def test_the_station_answers_and_the_row_is_the_terminals(tmp_path):
    station = FakeStation([([7, 6, 5, 4, 3, 2], ""), ([1, 2, 3, 4, 5, 6], "")])
    rows, logs, _ = study(tmp_path, FakeBackend(station))   # the terminal is never asked (no answers)
    assert [t for t, _ in station.asked] == ["About the strategy you just used: latent-YOLO",
                                             "About the strategy you just used: end-effector"]
    assert all(s == list(LIKERT) for _, s in station.asked)
    assert rows == [
        {"participant": "P01", "strategy": "latent-YOLO", "answers": dict(zip(LIKERT, [7, 6, 5, 4, 3, 2]))},
        {"participant": "P01", "strategy": "end-effector", "answers": dict(zip(LIKERT, [1, 2, 3, 4, 5, 6]))}]
    assert any("answered on the operator station" in x for x in logs)


def test_when_the_station_does_not_answer_it_says_so_and_the_terminal_asks(tmp_path):
    station = FakeStation([(None, "no page drives the operator station (open http://127.0.0.1:8080/)"),
                           ([4, 4, 4, 4, 4, 4], "")])
    rows, logs, out = study(tmp_path, FakeBackend(station), answers=["9", "5"] + ["3"] * (len(LIKERT) - 1))
    assert rows[0] == {"participant": "P01", "strategy": "latent-YOLO",
                       "answers": {q: (5 if i == 0 else 3) for i, q in enumerate(LIKERT)}}
    assert rows[1] == {"participant": "P01", "strategy": "end-effector", "answers": dict.fromkeys(LIKERT, 4)}
    said = [x for x in logs if "did not take the questionnaire" in x]
    assert len(said) == 1 and "no page drives the operator station" in said[0] and "terminal" in said[0]
    # resumed: what was asked is not asked again (every trial is recorded: nothing runs, nothing is asked)
    again = FakeStation([])
    run_study(load_protocol(tmp_path / "q.yaml"), out, backend=FakeBackend(again), log=logs.append,
              ask=lambda q: pytest.fail(q))
    assert again.asked == [] and len((out / "likert.jsonl").read_text().splitlines()) == 2


class Interrupted(FakeStation):
    """Answers the first `n` questionnaires, then Ctrl-C while the page waits."""

    def __init__(self, n=0):
        super().__init__([([1] * len(LIKERT), "")] * n)

    def ask(self, title, statements):
        if not self.outcomes:
            self.asked.append((title, list(statements)))
            raise KeyboardInterrupt
        return super().ask(title, statements)


@pytest.mark.parametrize("answered", [0, 1])
def test_a_questionnaire_a_stop_left_unanswered_is_asked_when_the_study_resumes(tmp_path, answered):
    """Stopped while the page waited (Ctrl-C) after the first strategy: the resumed study asks it
    first, on the station. Stopped in the last strategy's: no trial is left, nothing is launched, and
    the terminal asks it (backend None: as `vla_study` resumes)."""
    f = tmp_path / "q.yaml"
    f.write_text(TWO_STRATEGIES)
    out, logs = tmp_path / "study", []
    with pytest.raises(KeyboardInterrupt):
        run_study(load_protocol(f), out, backend=FakeBackend(Interrupted(answered)), log=logs.append,
                  ask=lambda q: pytest.fail(q))
    station, typed = FakeStation([([2] * len(LIKERT), "")] * 2), iter(["7"] * len(LIKERT))
    run_study(load_protocol(f), out, backend=None if answered else FakeBackend(station), log=logs.append,
              ask=lambda q: next(typed))
    rows = [json.loads(x) for x in (out / "likert.jsonl").read_text().splitlines()]
    first = "end-effector" if answered else "latent-YOLO"
    assert any(f"strategy {first} was not answered before the study stopped: asking it now" in x
               for x in logs), logs
    assert [(r["strategy"], r["answers"][LIKERT[0]]) for r in rows] == (
        [("latent-YOLO", 1), ("end-effector", 7)] if answered else [("latent-YOLO", 2), ("end-effector", 2)])


def test_without_a_station_the_terminal_asks(tmp_path):
    rows, _, _ = study(tmp_path, FakeBackend(), answers=["2"] * len(LIKERT) * 2)
    assert [r["strategy"] for r in rows] == ["latent-YOLO", "end-effector"]
    assert rows[0]["answers"] == dict.fromkeys(LIKERT, 2)


def test_a_station_result_that_is_not_an_answer_on_the_scale_is_refused():
    assert check_answers([1, 7, 3], 3) is None
    assert "2 answers to 3 statements" in check_answers([1, 7], 3)
    assert "whole number from 1 to 7" in check_answers([1, 8, 3], 3)
    assert "whole number from 1 to 7" in check_answers([0, 1, 3], 3)


def test_likert_row_falls_back_to_the_terminal_with_the_reason():
    logs = []
    row = likert_row("P02", "end-effector", LIKERT, lambda: {"from": "terminal"},
                     FakeStation([(None, "its action operator_station/questionnaire is not available")]),
                     logs.append)
    assert row == {"from": "terminal"}
    assert "is not available" in logs[-1] and "asking on the terminal" in logs[-1]


@pytest.mark.ros
def test_a_page_that_goes_away_gives_the_questionnaire_back_to_the_terminal(tmp_path):
    """The real action against the station node in process: a driving page (a link client) takes the
    questionnaire; it goes away and none comes back for page_gone_s: the client cancels (the station
    withdraws it from the pages) and says why."""
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from vla_common.ros.testing import RosHarness
    from vla_operator.station_node import StationNode

    h = RosHarness()
    try:
        station = h.add(StationNode(context=h.context, parameter_overrides=[
            Parameter("port", value=0), Parameter("settings_file", value=str(tmp_path / "s.json")),
            Parameter("controller", value="no_such_controller_for_this_test")]))
        client = h.add(Node("study_questionnaire_test", context=h.context))
        page = station.station.link.connect(0.0).cid
        asker = StationQuestionnaire(client, page_gone_s=0.5, log=lambda s: None)
        out = {}
        t = threading.Thread(target=lambda: out.update(r=asker.ask("About it", LIKERT)), daemon=True)
        t.start()
        assert h.spin_until(lambda: station.state["questionnaire"] is not None, 20.0)
        with station.station.lock:
            station.station.link.disconnect(page)             # the page closed
        assert h.spin_until(lambda: not t.is_alive(), 20.0)
        answers, why = out["r"]
        assert answers is None and "no page drives the station for 0.5 s" in why, why
        assert h.spin_until(lambda: station.state["questionnaire"] is None, 5.0)   # withdrawn
        assert station.station.link.questionnaire is None
        assert h.spin_until(lambda: not station._q_ready and not station._q_outcomes, 5.0)   # goal ended
    finally:
        h.shutdown()


@pytest.mark.ros
def test_a_graph_backend_gets_the_stations_client_on_its_observers_node_once():
    """The launched graph's backend (GraphBackend: ev.obs.node) and the robot's (RobotBackend, the same);
    a backend without a ROS node gets none: the terminal."""
    from types import SimpleNamespace

    from vla_common.ros.testing import RosHarness

    h = RosHarness()
    try:
        from rclpy.node import Node
        node = h.add(Node("station_for_test", context=h.context))
        class Backend:
            ev = SimpleNamespace(obs=SimpleNamespace(node=node))
        backend = Backend()
        asker = station_for(backend)
        assert isinstance(asker, StationQuestionnaire) and asker.action == "operator_station/questionnaire"
        assert station_for(backend) is asker
        assert station_for(SimpleNamespace()) is None
        own = FakeStation([])
        assert station_for(SimpleNamespace(questionnaire=own, ev=backend.ev)) is own
    finally:
        h.shutdown()


class PageOnTheStation:
    """The participant's page without a browser (websocket-client): it connects first (so it drives),
    and answers the questionnaire as soon as the station shows one; every message it got is kept."""

    def __init__(self, address: str, answers: list[int]):
        from urllib.parse import urlsplit

        import websocket  # websocket-client (a selenium dependency)

        u = urlsplit(address)
        self.ws = websocket.create_connection(f"ws://{u.netloc}/ws?{u.query}", origin=f"http://{u.netloc}",
                                              timeout=60)   # the query: the station's token
        self.answers, self.got, self.sent = answers, [], None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        import websocket

        while True:
            try:
                raw = self.ws.recv()
            except (websocket.WebSocketException, OSError):
                return
            if raw == "":
                return     # websocket-client's answer to the station's close frame
            if not isinstance(raw, str):
                continue   # a frame's JPEG
            m = json.loads(raw)
            if m["type"] == "frame":
                continue
            self.got.append(m)
            q = m.get("questionnaire") if m["type"] == "state" else None
            if q and self.sent != q["id"]:
                self.sent = q["id"]
                self.ws.send(json.dumps({"type": "answers", "id": q["id"],
                                         "answers": dict(zip(q["statements"], self.answers))}))

    def close(self) -> None:
        self.ws.close()


class SaysDoneAtOnce:
    """The experimenter: the participant is ready, and says done at once (nothing needs to move)."""

    def confirm(self, text: str) -> None:
        pass

    def wait_done(self, text: str, ended) -> bool:
        return True


@pytest.mark.slow
@pytest.mark.ros
@pytest.mark.timeout(900)
def test_through_the_launched_graph_the_participants_page_answers_and_the_terminal_is_not_asked(tmp_path):
    """The study's own graph (GraphBackend with a real participant: the station starts with it): after
    the strategy's trial the runner's questionnaire reaches the page through the station's action on
    the graph's EventsExecutor, the page's answers come back as the likert.jsonl row."""
    from vla_study.graph_backend import GraphBackend

    f = tmp_path / "one.yaml"
    f.write_text(TWO_STRATEGIES.replace("[latent-YOLO, end-effector]", "[end-effector]"))
    proto, out = load_protocol(f), tmp_path / "study"
    backend = GraphBackend(proto, out, experimenter=SaysDoneAtOnce(), operator_port=0)
    page, logs = None, []
    try:
        assert backend.station.startswith("http://127.0.0.1:")
        page = PageOnTheStation(backend.station, [3, 4, 5, 6, 7, 1])
        run_study(proto, out, backend=backend, log=logs.append, ask=lambda q: pytest.fail(f"terminal: {q}"))
    finally:
        if page is not None:
            page.close()
        backend.close()
    rows = [json.loads(x) for x in (out / "likert.jsonl").read_text().splitlines()]
    assert rows == [{"participant": "P01", "strategy": "end-effector",
                     "answers": dict(zip(LIKERT, [3, 4, 5, 6, 7, 1]))}], logs
    assert any("answered on the operator station" in x for x in logs)
    replies = [m for m in page.got if m["type"] == "reply" and m["what"] == "questionnaire"]
    assert replies and replies[0]["ok"]


def test_the_terminal_questionnaire_keeps_to_the_scale(capsys):
    from vla_study.runner import LIKERT, ask_likert

    replies = iter(["8", "x", "0"] + ["4"] * len(LIKERT))
    row = ask_likert("P01", "latent-YOLO", lambda _prompt: next(replies))
    assert row["answers"] == {q: 4 for q in LIKERT}
    out = capsys.readouterr().out
    assert "1 = strongly disagree, 7 = strongly agree" in out
    assert out.count("please answer with a whole number from 1 to 7") == 3


def test_the_studys_default_protocol_is_the_papers_three_strategies():
    import argparse

    from vla_study.cli import add_arguments
    from vla_study.protocol import PAPER, load_protocol

    ap = argparse.ArgumentParser()
    add_arguments(ap)
    args = ap.parse_args(["--participants", "sim:9"])
    assert args.protocol == PAPER
    strategies = set(load_protocol(args.protocol).strategies)
    assert strategies == {"latent-YOLO", "latent-localization", "end-effector"}

"""A real participant's study through the launched graph: the person drives (here a scripted stick on
`joy`, as a joystick's joy_node or the operator station publishes it), the experimenter confirms each
trial's start and ends it at the participant's "done", and the questionnaire follows the strategy."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from scripted_person import ScriptedPerson
from vla_study.person import InputTally, TerminalExperimenter

PERSON = """study: person
participants: P01
strategies: [latent-YOLO]
settings:
  Seen: cereal_box/push_south
trials: 1
practice: {trials: 0, reset_seed: 7}
time_limit: 20
rate: 20
"""


def test_a_persons_inputs_are_counted_as_the_simulated_participants_are():
    t = InputTally(axis=0, mode_button=0)
    for axes, buttons in [([0.0], [0]), ([0.8], [0]), ([0.9], [0]), ([0.0], [0]), ([-0.5], [0]),
                          ([0.6], [0]), ([0.0], [1]), ([0.0], [1]), ([0.0], [0]), ([0.05], [0])]:
        t.on_joy(axes, buttons)
    # deflections: +0.8 (from rest), -0.5 (from rest), +0.6 (the other way: a reversal); one press
    assert (t.n_inputs, t.reversals) == (4, 1)
    assert t.lapses is None and t.switch_s is None   # not seen in a person: left empty, not zero
    t.on_mode(True)
    t.on_mode(False)
    assert t.n_switches == 1


def test_the_terminal_experimenter_ends_a_trial_at_enter_or_the_limit(tmp_path):
    import os
    r, w = os.pipe()
    with os.fdopen(r) as stream, os.fdopen(w, "w") as writer:
        ex = TerminalExperimenter(stream, poll_s=0.01)
        assert ex.wait_done("done?", lambda: True) is False       # the limit, and no line was read
        writer.write("\n")
        writer.flush()
        assert ex.wait_done("done?", lambda: False) is True       # the participant said done
        writer.write("\n")
        writer.flush()
        ex.confirm("ready?")                                       # the next Enter is still there for this


class ScriptedSession(ScriptedPerson):
    """The experimenter and the person: the person pushes the stick from the confirmation until they
    have driven `drive_s` simulated seconds, then says done; the experimenter presses Enter."""

    def __init__(self, drive_s: float) -> None:
        super().__init__(drive_s)
        self.prompts: list[str] = []

    def confirm(self, text: str) -> None:
        self.prompts.append(text)
        self.start_driving()

    def wait_done(self, text: str, ended) -> bool:
        self.prompts.append(text)
        return self.drive_until_done(ended, 300.0)


def test_the_station_address_is_waited_for_not_read_once(tmp_path):
    """The operator station prints its address after the graph's other nodes answer: the study waits
    for the line (checking the launch is alive meanwhile) instead of reading the log once; a line that
    never comes gives '' after the graph's start-up time."""
    from types import SimpleNamespace

    from vla_study.graph_backend import GraphBackend

    log = tmp_path / "graph.log"
    log.write_text("[graph] up\n")
    checks = []

    def alive():                     # the station's line appears while the launch is being checked
        checks.append(1)
        if len(checks) == 2:
            log.write_text(log.read_text() + "[operator_station] the operator station is at "
                           "http://127.0.0.1:8123/\n")

    backend = GraphBackend.__new__(GraphBackend)
    backend.ev = SimpleNamespace(runner=SimpleNamespace(session=SimpleNamespace(log_path=log)),
                                 config=SimpleNamespace(startup_timeout=30.0), alive=alive)
    assert backend._station_address(poll_s=0.0) == "http://127.0.0.1:8123/" and len(checks) == 2
    log.write_text("[graph] up\n")
    backend.ev.config.startup_timeout = 0.0
    assert backend._station_address(poll_s=0.0) == ""


@pytest.mark.slow
@pytest.mark.ros
@pytest.mark.timeout(900)
def test_a_real_participant_drives_the_graph_and_answers_the_questionnaire(tmp_path):
    from vla_study.graph_backend import GraphBackend
    from vla_study.protocol import load_protocol
    from vla_study.runner import LIKERT, run_study

    f = tmp_path / "person.yaml"
    f.write_text(PERSON)
    proto, out = load_protocol(f), tmp_path / "study"
    session = ScriptedSession(drive_s=4.0)
    backend = GraphBackend(proto, out, experimenter=session, operator_port=0)
    session.backend = backend
    answers = iter(["9", "6"] + ["5"] * len(LIKERT))   # a wrong answer is asked again
    try:
        assert backend.station.startswith("http://127.0.0.1:")   # the person's screen
        run_study(proto, out, backend=backend, ask=lambda q: next(answers), experimenter=session)
    finally:
        backend.close()
    assert "is the participant ready?" in session.prompts[0] and "says done" in session.prompts[1]
    rows = [json.loads(x) for x in (out / "trials.jsonl").read_text().splitlines()]
    assert len(rows) == 1
    r = rows[0]
    assert r["participant"] == "P01" and not r["simulated"] and r["backend"] == "graph"
    assert r["participant_done"] and 3.9 <= r["duration_s"] < 20, r   # ended at "done", not the limit
    assert r["n_inputs"] >= 1 and r["lapses"] is None
    assert r["path_length_m"] > 0.02, r                          # the person's stick moved the arm
    from rosbags.highlevel import AnyReader
    with AnyReader([Path(out) / r["bag"]]) as reader:
        conns = [c for c in reader.connections if c.topic == "/joy"]
        sticks = [reader.deserialize(raw, c.msgtype).axes[0]
                  for c, _t, raw in reader.messages(connections=conns)]
    assert sticks.count(1.0) >= 20                              # the person's 50 Hz stick is in the bag
    likert = [json.loads(x) for x in (out / "likert.jsonl").read_text().splitlines()]
    assert likert == [{"participant": "P01", "strategy": "latent-YOLO",
                       "answers": {q: (6 if i == 0 else 5) for i, q in enumerate(LIKERT)}}]

"""The study on a real robot (issue 24, `robot: real`): the runner attaches to a graph it did not start,
the experimenter places the object before each trial (the arm stopped by the bridge's e-stop) and
scores it after, no `~/reset` is ever called, the runner measures what joint_states show, and a study
interrupted at the terminal resumes without losing or duplicating a trial. The graph here is the
shipped MuJoCo one (demo.launch.yaml, no oracle, no recorder), started apart from the runner as a lab
starts its robot's launch; the experimenter and the participant are scripted."""
from __future__ import annotations

import json
import os

import pytest
from scripted_person import ScriptedPerson
from vla_study.cli import add_arguments
from vla_study.cli import run as cli_run
from vla_study.person import TerminalExperimenter, TrialScore, parse_displacement_cm
from vla_study.protocol import load_protocol, robot_refusal

ROBOT = """study: robot
participants: P01
strategies: [end-effector]
settings:
  base: bread/push_east
trials: 2
practice: {trials: 1, reset_seed: 7}
time_limit: 12
rate: 20
end_effector_axes: ["x", "y", "z"]
robot: real
"""


def _cli(argv: list[str]) -> int:
    import argparse

    p = argparse.ArgumentParser()
    add_arguments(p)
    return cli_run(p.parse_args(argv))


def test_a_simulated_participant_on_the_real_robot_is_refused_at_its_line(tmp_path, capsys):
    f = tmp_path / "robot.yaml"
    f.write_text(ROBOT.replace("participants: P01", "participants: sim:3"))
    why = robot_refusal(load_protocol(f))
    assert why.startswith(f"{f}:2: simulated participants (sim:1, sim:2, sim:3) cannot run on the real robot "
                          f"({f}:11: robot: real)"), why
    assert _cli(["--protocol", str(f), "--check"]) == 2
    assert f"{f}:2: simulated participants" in capsys.readouterr().err
    from vla_study.runner import run_study

    with pytest.raises(SystemExit, match=r"robot.yaml:2: simulated participants"):
        run_study(load_protocol(f), tmp_path / "never")        # the API refuses it too, before anything
    assert not (tmp_path / "never").exists()
    # the flag says where it came from when the flag set it; real ids on the command line are accepted
    f.write_text(ROBOT.replace("robot: real\n", ""))
    assert robot_refusal(load_protocol(f)) is None
    assert _cli(["--protocol", str(f), "--participants", "sim:2", "--robot", "real", "--check"]) == 2
    err = capsys.readouterr().err
    assert ("--participants: simulated participants (sim:1, sim:2) cannot run on the real robot "
            "(--robot real)") in err
    f.write_text(ROBOT.replace("participants: P01", "participants: sim:3"))
    assert _cli(["--protocol", str(f), "--participants", "P07", "--check"]) == 0
    out = capsys.readouterr().out
    assert "P07:" in out and out.count("place at x ") == 3          # the experimenter's sheet: where
    f.write_text(ROBOT + "backend: physics\n")
    assert robot_refusal(load_protocol(f)).startswith(f"{f}:12: the physics backend has no robot")
    f.write_text(ROBOT.replace("robot: real", "robot: hardware"))
    with pytest.raises(Exception, match=r"robot.yaml:11: robot \('hardware'\): .*'sim' or 'real'"):
        load_protocol(f)


SHIPPED_THEN = """study: paper-section-7-shipped-models
participants: sim:9
population_seed: 2026
strategies: [latent-YOLO, end-effector]
settings:
  base: [bread/push_east, soda_can/push_south, milk_carton/push_south_west, glass_bottle/push_west]
  Seen: cereal_box/push_south
  Near: cereal_box/push_south_east
  Far: cereal_box/circle
trials: 2
practice: {trials: 1, reset_seed: 7}
counterbalance: latin_square
time_limit: 30
rate: 20
end_effector_axes: ["x", "y", "z"]
end_effector_debounce: 0.15
"""


def test_a_simulated_study_keeps_its_digest(tmp_path):
    """Folders made before `robot` (and `role`, `seeds`, `development`) existed resume: at their defaults
    they leave the digest as it was (the shipped protocol's digest as the runner computed it before the
    key, at 95a1f1a)."""
    import dataclasses


    f = tmp_path / "shipped_then.yaml"   # protocols/shipped.yaml as it was then
    f.write_text(SHIPPED_THEN)
    p = load_protocol(f)
    assert p.robot == "sim" and p.digest() == "b385362ff4d71028"
    assert dataclasses.replace(p, robot="real").digest() != p.digest()


def test_the_experimenter_scores_at_the_terminal_and_nonsense_is_asked_again(capsys):
    assert parse_displacement_cm("") == (True, None)
    assert parse_displacement_cm("12,5") == (True, 0.125)
    for bad in ("-1", "nan", "250", "ten"):
        assert parse_displacement_cm(bad) == (False, None), bad
    r, w = os.pipe()
    with os.fdopen(r) as stream, os.fdopen(w, "w") as writer:
        writer.write("maybe\ny\n-3\n14\nn\n\n")
        writer.flush()
        ex = TerminalExperimenter(stream)
        assert ex.score("Trial 1") == TrialScore(True, 0.14)
        assert ex.score("Trial 2") == TrialScore(False, None)
    out = capsys.readouterr().out
    assert "please answer y or n" in out and "please give a number of cm" in out


class ScriptedLab(ScriptedPerson):
    """The experimenter and the participant. On each placement prompt the experimenter checks that the
    arm is stopped (the bridge's e-stop latched), 'places' the object (a simulated scene cannot be
    touched: the test only records the prompt) and confirms, unless told to press Ctrl-C there; the
    participant then pushes the stick (back to neutral while told to) until `drive_s` simulated s,
    says done; the experimenter scores from `scores`."""

    def __init__(self, drive_s: float, scores: list[TrialScore], interrupt_at: int | None = None) -> None:
        super().__init__(drive_s)
        self.scores, self.interrupt_at = list(scores), interrupt_at
        self.placed: list[str] = []
        self.estop_at_placement: list[bool] = []
        self.scored: list[str] = []
        self.relatched = None

    def confirm(self, text: str) -> None:
        obs = self.backend.ev.obs
        with obs.cond:
            latched = obs.cond.wait_for(lambda: obs.safety is not None and obs.safety.estop_active, 10.0)
        self.estop_at_placement.append(bool(latched))
        if not self.placed and self.interrupt_at is not None:
            # the participant presses release on the station's page while the experimenter places
            from std_srvs.srv import SetBool

            before = obs.relatched
            assert obs.call(obs.estop_cli, SetBool.Request(data=False), 10.0, "release").success
            with obs.cond:   # the runner saw the release and latched the e-stop again
                self.relatched = obs.cond.wait_for(lambda: obs.relatched > before and obs.safety.estop_active,
                                                   10.0)
        self.placed.append(text)
        if self.interrupt_at is not None and len(self.placed) == self.interrupt_at:
            raise KeyboardInterrupt   # the experimenter's Ctrl-C at the prompt
        self.start_driving()

    def wait_done(self, text: str, ended) -> bool:
        return self.drive_until_done(ended, 120.0)

    def score(self, text: str) -> TrialScore:
        self.scored.append(text)
        return self.scores.pop(0)


def _study_on(graph, tmp_path, use_sim_time: bool, state_rate: float, protocol: str = ROBOT,
              robot_model: str = "panda") -> None:
    """The protocol's trials on the started `graph` (a LaunchSession), Ctrl-C at the second placement,
    resumed by a second runner; checks what the issue asks of a real-robot study."""
    from vla_study.analysis import analyse
    from vla_study.robot_backend import RobotBackend
    from vla_study.runner import run_study, trial_plan

    f = tmp_path / "robot.yaml"
    f.write_text(protocol)
    proto, out = load_protocol(f), tmp_path / "study"
    plan = trial_plan(proto)
    assert len(plan) >= 3 and plan[0].phase == "practice"    # practice at the reset point, then tests
    scores = [TrialScore(True, 0.15), TrialScore(False, None), TrialScore(True, 0.12),
              TrialScore(False, 0.0)][:len(plan)]
    first = ScriptedLab(2.0, scores[:1], interrupt_at=2)
    second = ScriptedLab(2.0, scores[1:])
    try:
        for lab in (first, second):
            backend = RobotBackend(proto, out, experimenter=lab, use_sim_time=use_sim_time,
                                   startup_timeout=180.0, state_rate=state_rate)
            lab.backend = backend
            try:
                run_study(proto, out, backend=backend, experimenter=lab, ask=lambda q: "5")
            except KeyboardInterrupt:
                assert lab is first
            finally:
                backend.close()
                lab.relatches = backend.ev.obs.relatched
            graph.check()                                     # the lab's graph is still up
    finally:
        graph.stop()
    rows = [json.loads(x) for x in (out / "trials.jsonl").read_text().splitlines()]
    assert [r["key"] for r in rows] == [t.key for t in plan]   # each trial once, in order: none lost
    # asked to place and confirm before every trial (twice for the interrupted one), the arm stopped
    assert len(first.placed) == 2 and len(second.placed) == len(plan) - 1
    assert all(first.estop_at_placement + second.estop_at_placement)
    assert first.relatched                                    # a release between trials is undone at once
    assert second.relatches == 0                              # and only a release: the trials' own are not
    for text in first.placed + second.placed:
        assert "Place the bread at x = " in text and "m in the robot's base frame" in text, text
        assert "cm in front of the robot's base" in text and "e-stop latched" in text, text
    def where(text: str) -> list[str]:                         # the trial and the point (not the arm's line)
        return [x for x in text.splitlines() if "The arm is stopped" not in x]

    assert where(first.placed[1]) == where(second.placed[0])  # the interrupted trial, asked again
    assert len(first.scored) + len(second.scored) == len(plan)
    # the experimenter's score, the runner's measurements
    assert [(r["success"], r["object_displacement_m"]) for r in rows] == [(x.success, x.displacement_m)
                                                                          for x in scores]
    for r in rows:
        assert r["robot"] == "real" and r["scored_by"] == "experimenter" and not r["simulated"], r
        assert r["robot_model"] == robot_model and r["limit_violations"] == 0, r   # its own limit table
        assert r["participant_done"] and 0.5 <= r["duration_s"] < 12, r   # at "done", not the limit
        assert r["path_length_m"] > 0.02 and r["n_inputs"] >= 1 and r["sparc"] is not None, r
        assert r["ldlj"] is not None and r["lapses"] is None, r
        assert r["note"] == "", r                             # latent actions: the context was latched
        assert (out / r["bag"] / "metadata.yaml").exists(), r["bag"]
    # no ~/reset: the bridge logs every reset it serves ("reset: <objects>") or refuses
    bridge_lines = [x for x in graph.log_path.read_text().splitlines() if "panda_bridge" in x]
    assert bridge_lines and not [x for x in bridge_lines if "reset:" in x or "reset refused" in x]
    assert sum("e-stop latched" in x for x in bridge_lines) >= len(plan)
    likert = [json.loads(x) for x in (out / "likert.jsonl").read_text().splitlines()]
    assert sorted(x["strategy"] for x in likert) == sorted(proto.strategies)
    table = "\n".join(analyse(out, out))
    assert "simulated participants" not in table and "the experimenter placed each object" in table, table


@pytest.mark.slow
@pytest.mark.ros
@pytest.mark.timeout(900)
def test_a_real_robot_study_attaches_to_the_launched_mujoco_graph(tmp_path):
    from vla_launch.session import LaunchSession

    # the lab's graph, started apart from the runner (here the simulated Panda; no oracle, no recorder)
    graph = LaunchSession("vla_evaluation", "demo.launch.yaml",
                          {"use_teleoperator": False, "camera_rate": 2.0, "state_rate": 100.0,
                           "real_time_factor": 1.0}, log_path=tmp_path / "graph.log")
    graph.start()
    # both kinds of strategy: latent actions latch the detection of the scene as it is (no reset)
    protocol = ROBOT.replace("strategies: [end-effector]", "strategies: [latent-YOLO, end-effector]")
    _study_on(graph, tmp_path, use_sim_time=True, state_rate=100.0,
              protocol=protocol.replace("trials: 2\n", "trials: 1\n"))


@pytest.mark.slow
@pytest.mark.ros
@pytest.mark.timeout(900)
def test_a_real_robot_study_on_the_libfranka_bridge_against_franka_sim(tmp_path):
    """The bridge with backend libfranka (pylibfranka) against franka-sim, a simulated FR3 speaking the
    FCI protocol (software we did not write), and the controller with the FR3 joint map, started apart
    from the runner as a lab's robot PC runs them; wall-clock time, as on the robot."""
    from franka_sim_server import running
    from vla_launch.launcher import ProcessSpec
    from vla_launch.run import find_executable
    from vla_launch.session import LaunchSession

    with running(priority=50) as sim:
        bridge = {"backend": "libfranka", "robot_ip": "127.0.0.1", "driver": "pylibfranka",
                  "realtime_config": "ignore", "loop_prefix": " ".join(sim.netns.prefix()),
                  "loop_priority": 50, "control_rate": 250, "robot_model": "fr3",
                  "acceleration_scale": 0.4999, "jerk_scale": 0.4999}
        jmap = "[" + ", ".join(f"'fr3_joint{i}:panda_joint{i}'" for i in range(1, 8)) + "]"

        def cmd(pkg: str, exe: str, params: dict) -> list[str]:
            out = [find_executable(pkg, exe), "--ros-args"]
            for k, v in params.items():
                out += ["-p", f"{k}:={v}"]
            return out

        graph = LaunchSession.of_processes(
            [ProcessSpec("panda_bridge", cmd("vla_panda_bridge", "panda_bridge", bridge)),
             ProcessSpec("controller_node", cmd("vla_latent_controller", "controller_node",
                                                {"joy_timeout": 0.5, "joint_map": jmap}))],
            log_path=tmp_path / "graph.log")
        graph.start()
        _study_on(graph, tmp_path, use_sim_time=False, state_rate=200.0, robot_model="fr3")

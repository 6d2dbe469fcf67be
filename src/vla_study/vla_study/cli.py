"""`vla_study`: run the user study's protocol (resumable), then its figures and tables.

    vla_study --participants sim:9                  # the paper's protocol, shipped models
    vla_study --protocol my.yaml --out out/study    # another protocol
    vla_study --analyse-only --out out/study        # figures and tables from what ran
    vla_study --protocol my.yaml --check            # validate, print the sessions, run nothing
    vla_study --protocol my.yaml --participants P01 --robot real   # attach to the robot's graph
Run it again with the same --out to resume; a different protocol in that --out is refused.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

from vla_common.catalogue import load_catalogue
from vla_common.kinematics import PandaKinematics
from vla_evaluation.resources import is_latent_model, latent_model_dir
from vla_evaluation.sweep import add_arguments as add_engine_arguments
from vla_evaluation.sweep import engine_from

from vla_study.person import start_point
from vla_study.protocol import (
    PAPER,
    SHIPPED,
    Protocol,
    ProtocolError,
    load_protocol,
    parse_participants,
    robot_refusal,
)
from vla_study.runner import reused_seeds, run_study, trial_plan


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--protocol", type=Path, default=PAPER,
                   help=f"protocol YAML (default: {PAPER.name}, the paper's procedure: latent-YOLO, "
                        f"latent-localization and the end-effector baseline; {SHIPPED.name}: the first and "
                        "the last)")
    p.add_argument("--participants", default=None, help="sim:N or comma-separated ids (overrides the file)")
    p.add_argument("--out", type=Path, default=Path("out/study"), help="study folder (resumed if it exists)")
    p.add_argument("--limit", type=int, default=None, help="stop after this many new trials")
    p.add_argument("--only", default="", metavar="STRATEGY[,STRATEGY]",
                   help="run only these of the protocol's conditions (the folder keeps the whole protocol: "
                        "a later run without --only runs the others)")
    p.add_argument("--trials", type=int, default=None, help="test trials per task (overrides the file)")
    p.add_argument("--time-limit", type=float, default=None, help="s per trial (overrides the file)")
    p.add_argument("--backend", choices=("graph", "physics"), default=None,
                   help="graph: the launched graph, the stick as Joy, a bag per trial, simulated "
                        "participants in lockstep (the file's default; the only one left: physics, the "
                        "graph's loop copied into one process, is gone and refused with why)")
    p.add_argument("--robot", choices=("sim", "real"), default=None,
                   help="sim: launch the simulated Panda, reset by ~/reset (the file's default); real: "
                        "attach to the robot's graph already running on this ROS_DOMAIN_ID, the experimenter "
                        "places the object before each trial and scores it after (persons only)")
    p.add_argument("--use-sim-time", action="store_true",
                   help="with --robot real: the attached graph is a simulated one (a rehearsal on the MuJoCo "
                        "bridge) whose nodes follow /clock")
    p.add_argument("--analyse-only", action="store_true", help="only the figures and tables")
    add_engine_arguments(p)  # simulated participants' trials as units on Ray (real ones: --serial always)
    p.add_argument("--check", action="store_true",
                   help="validate the protocol and print each participant's session; run and write nothing")
    p.add_argument("--figures", type=Path, default=None, help="where figures and tables go (default: --out)")
    p.add_argument("--paths", action="store_true",
                   help="rerun the trials of --out whose TCP paths (trials/*.npz) are missing, with their "
                        "rows' seeds, and write only the paths (the rows stay; paths.jsonl says whether each "
                        "outcome was the row's); then the figures")


def run(args) -> int:
    if why := out_refusal(args.out):
        print(why, file=sys.stderr)
        return 2
    try:
        proto = load_protocol(args.protocol,
                              model_exists=lambda m: is_latent_model(latent_model_dir(m)))
        proto = with_overrides(proto, args)
    except ProtocolError as e:
        return refused(e.errors)
    except ValueError as e:
        print(f"--participants: {e}", file=sys.stderr)
        return 2
    if why := robot_refusal(proto):
        return refused([why])
    only = tuple(s for s in args.only.split(",") if s)
    if unknown := [s for s in only if s not in proto.strategies]:
        return refused([f"--only: {', '.join(map(repr, unknown))} not among the protocol's strategies "
                        f"({', '.join(proto.strategies)})"])
    if why := reused_seeds(proto):
        return refused(why)
    if args.check:
        print_sessions(proto)
        return 0
    if args.paths:
        from vla_study.paths import regenerate_paths  # the tool's own module: only when asked

        regenerate_paths(proto, args.out, log=lambda s: print(s, flush=True), limit=args.limit)
    failed: list[str] = []
    if not args.paths and not args.analyse_only:
        failed = run_study(proto, args.out, log=lambda s: print(s, flush=True), limit=args.limit,
                           use_sim_time=args.use_sim_time, engine=engine_from(args), only=only).failed
    from vla_study.analysis import analyse  # matplotlib: only for the figures, not for --help or --check

    for line in analyse(args.out, args.figures or args.out, proto.time_limit, proto.strategies,
                        list(proto.settings)):
        print(line)
    if failed:  # the analysis above is of what was recorded; the study is not complete
        print(f"[study] incomplete: {len(failed)} units of trials failed (see above); run the same command "
              "again to run them", file=sys.stderr)
        return 1
    return 0


def out_refusal(out: Path) -> str | None:
    """Why `out` cannot be a study folder: it, or a folder above it, is not a directory."""
    for p in (out, *out.parents):
        if p.exists():
            return None if p.is_dir() else f"--out {out}: {p} is not a directory (a study folder is one)"
    return None


def refused(errors: list[str]) -> int:
    """The protocol's problems on stderr, one line each (one problem: one line); exit status 2."""
    print("protocol refused: " + errors[0] if len(errors) == 1 else "protocol refused:\n" + "\n".join(errors),
          file=sys.stderr)
    return 2


def with_overrides(proto: Protocol, args) -> Protocol:
    """The protocol with the command line's overrides; where each came from is kept for messages."""
    if args.participants:
        proto = dataclasses.replace(proto, participants=parse_participants(args.participants),
                                    origin={**proto.origin, "participants": "--participants"})
    if args.trials is not None:
        proto = dataclasses.replace(proto, trials=args.trials)
    if args.time_limit is not None:
        proto = dataclasses.replace(proto, time_limit=args.time_limit)
    if args.backend is not None:
        proto = dataclasses.replace(proto, backend=args.backend,
                                    origin={**proto.origin, "backend": "--backend"})
    if args.robot is not None:
        proto = dataclasses.replace(proto, robot=args.robot, origin={**proto.origin, "robot": "--robot"})
    return proto


def print_sessions(proto: Protocol) -> None:
    """Each participant's session in order; on the real robot with where the object goes (the
    experimenter's sheet)."""
    plan = trial_plan(proto)
    real = proto.robot == "real"
    cat, kin = (load_catalogue(""), PandaKinematics()) if real else (None, None)
    print(f"{proto.source}: valid; {len(proto.participants)} participants, {len(plan)} trials "
          f"({sum(t.phase == 'practice' for t in plan)} practice)")
    for who in proto.participants:
        print(f"\n{who}:")
        for t in (t for t in plan if t.participant == who):
            where = ""
            if real:
                goal, _seed = start_point(t, cat, kin)
                where = f", place at x {goal.x:.3f} m, y {goal.y:.3f} m, yaw {math.degrees(goal.yaw):.0f} deg"
            print(f"  {t.order + 1:3d}. {t.strategy:20s} {t.setting:6s} {t.task:30s} {t.phase:8s} "
                  f"trial {t.trial + 1}, placement seed {t.layout_seed}{where}")


def main(argv: list[str] | None = None) -> int:
    """The `vla_study` command; 130 on Ctrl-C (no traceback)."""
    parser = argparse.ArgumentParser(prog="vla_study", description=__doc__.splitlines()[0])
    add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return run(args)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

"""`vla_demo_recorder` command line: recover and inspect bags; start/stop/discard/status of a running
recorder node."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import rclpy
from rclpy.node import Node
from std_srvs.srv import Trigger
from vla_common.ros.discovery import discovered_by
from vla_common.ros.spin import spin_until

from vla_demo_recorder.bag_writer import BagError, EpisodeInfo, read_metadata_yaml
from vla_demo_recorder.recover import recover
from vla_interfaces.msg import RecorderStatus
from vla_interfaces.srv import StartEpisode

# Commands that moved to the packages they belong to.
MOVED = {"pairs": "vla_latent_training pairs", "generate": "vla_evaluation generate"}


def _cmd_recover(args: argparse.Namespace) -> int:
    status = 0
    for bag in args.bags:
        try:
            report = recover(bag, force=args.force)
        except BagError as err:
            print(f"error: {err}", file=sys.stderr)
            status = 1
            continue
        print(report.summary())
    return status


def _cmd_info(args: argparse.Namespace) -> int:
    status = 0
    for bag in args.bags:
        try:
            meta = read_metadata_yaml(Path(bag))
        except BagError as err:
            print(f"error: {err}", file=sys.stderr)
            status = 1
            continue
        episode = EpisodeInfo.from_custom_data(meta.get("custom_data"))
        print(f"{bag}: {meta['message_count']} messages, "
              f"{meta['duration']['nanoseconds'] / 1e9:.2f} s")
        if episode is not None:
            print(f"  episode {episode.index}: task {episode.task} ({episode.object_class}), "
                  f"outcome {episode.outcome}" + (f", note: {episode.note}" if episode.note else "")
                  + (f", error: {episode.error}" if episode.error else ""))
            for key, value in episode.extra.items():
                print(f"  {key}: {value}")
        for t in meta["topics_with_message_count"]:
            tm = t["topic_metadata"]
            print(f"  {tm['name']:<28} {tm['type']:<36} {t['message_count']:>8}")
    return status


def _cmd_episode(args: argparse.Namespace) -> int:
    """Call the recorder node's services (this workspace has no ros2cli)."""
    rclpy.init()
    node = Node("vla_demo_recorder_cli")
    try:
        base = args.node.rstrip("/")

        def spin_once(seconds: float) -> None:
            rclpy.spin_once(node, timeout_sec=seconds)

        if args.command == "status":
            got: list[RecorderStatus] = []
            node.create_subscription(RecorderStatus, f"{base}/status", got.append, 10)
            if not spin_until(spin_once, lambda: bool(got), args.timeout):
                print(f"error: no {base}/status within {args.timeout} s", file=sys.stderr)
                return 1
            st = got[-1]
            print(f"{'recording' if st.recording else 'idle'}: episode {st.episode_index} ({st.task}) "
                  f"{st.messages_written} messages, {st.bytes_written / 1e6:.1f} MB, "
                  f"{st.messages_dropped} dropped, {st.bag_path}"
                  + (f"; last error: {st.last_error}" if st.last_error else ""))
            return 0
        if args.command == "start":
            client = node.create_client(StartEpisode, f"{base}/start_episode")
            request = StartEpisode.Request(task=args.task, note=args.note)
        else:
            client = node.create_client(Trigger, f"{base}/{args.command}_episode")
            request = Trigger.Request()
        if not client.wait_for_service(timeout_sec=args.timeout):
            print(f"error: service {client.srv_name} not available", file=sys.stderr)
            return 1
        # This process is new: the recorder would drop its answer to a client it has not yet discovered
        if not discovered_by(node, base, spin_once, args.timeout):
            print(f"error: {base} did not answer within {args.timeout} s", file=sys.stderr)
            return 1
        future = client.call_async(request)
        rclpy.spin_until_future_complete(node, future, timeout_sec=args.timeout + 30)
        result = future.result()
        if result is None:
            print("error: no reply", file=sys.stderr)
            return 1
        print(result.message)
        return 0 if result.success else 1
    finally:
        node.destroy_node()
        rclpy.shutdown()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="vla_demo_recorder", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("recover", help="make a bag whose writer was killed readable again (the original "
                                       "is kept as .orig; exit 1 when nothing was recovered)")
    p.add_argument("bags", nargs="+", help="bag folders (or .mcap files)")
    p.add_argument("--keep-original", action="store_true", help=argparse.SUPPRESS)  # always, now
    p.add_argument("--force", action="store_true", help="rewrite even a complete bag")
    p.set_defaults(func=_cmd_recover)

    p = sub.add_parser("info", help="episode metadata and per-topic counts of bags")
    p.add_argument("bags", nargs="+")
    p.set_defaults(func=_cmd_info)

    for name, text in (("start", "start an episode on a running recorder"),
                       ("stop", "stop (keep) the running episode"),
                       ("discard", "stop and discard the running episode"),
                       ("status", "print the recorder's status")):
        p = sub.add_parser(name, help=text)
        if name == "start":
            p.add_argument("--task", required=True, help="e.g. bread/push_east")
            p.add_argument("--note", default="")
        p.add_argument("--node", default="/recorder", help="the recorder node's name")
        p.add_argument("--timeout", type=float, default=10.0)
        p.set_defaults(func=_cmd_episode)

    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in MOVED:
        print(f"error: `vla_demo_recorder {argv[0]}` is now `{MOVED[argv[0]]}`", file=sys.stderr)
        return 2
    args = build_parser().parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())

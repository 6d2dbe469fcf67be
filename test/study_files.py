"""What a study's tests read back from its folder: the rows and a trial bag's Joy messages."""
import json
from pathlib import Path


def study_rows(out: Path) -> list[dict]:
    """The rows of `out/trials.jsonl`, in the order written (none when it does not exist yet)."""
    p = out / "trials.jsonl"
    return [json.loads(x) for x in p.read_text().splitlines() if x.strip()] if p.exists() else []


def bag_joy(bag: Path) -> list:
    """The Joy messages of a trial's bag (rosbags: a reader we did not write)."""
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == "/joy"]
        return [reader.deserialize(raw, c.msgtype) for c, _t, raw in reader.messages(connections=conns)]


def bag_messages(bag: Path, topic: str) -> list:
    """The messages of one topic of a trial's bag, the project's own types (vla_interfaces) included."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    msgs = Path(__file__).resolve().parents[1] / "src" / "vla_interfaces" / "msg"
    types: dict = {}
    for f in sorted(msgs.glob("*.msg")):
        types.update(get_types_from_msg(f.read_text(), f"vla_interfaces/msg/{f.stem}"))
    store.register(types)
    with AnyReader([bag], default_typestore=store) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        return [reader.deserialize(raw, c.msgtype) for c, _t, raw in reader.messages(connections=conns)]

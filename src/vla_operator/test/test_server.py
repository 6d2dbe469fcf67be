"""The server's side of the link without a browser: what it publishes, and under which lock."""
import json

from vla_operator.server import Station


def test_inputs_are_published_in_order_under_the_link_lock(tmp_path):
    """The node's timer publishes from the same link under the same lock: a value read and published
    together can never land after a newer one (a held value after the release's zero)."""
    published = []

    def publish(axis: float) -> None:
        assert station.lock.locked(), "published outside the link's lock"
        published.append(axis)

    now = [10.0]
    station = Station(tmp_path, "127.0.0.1", 0, "", publish, lambda msg, reply: None, clock=lambda: now[0])
    cid = station.link.connect(now[0]).cid
    for seq, axis in enumerate((0.0, 0.6, 0.0)):
        now[0] += 0.05
        station._on_message(cid, json.dumps({"type": "input", "seq": seq, "t": seq * 50.0, "axis": axis}))
    assert published == [0.0, 0.0, 0.6, 0.0]   # the press after neutral: that neutral again first

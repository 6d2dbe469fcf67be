"""What one page may cost (outbox.py): the outgoing queue stays bounded whatever is sent to a page that
does not read, and the newest state and frame win; the budgets refill at their rate."""
import asyncio

from vla_operator.outbox import Budget, Outbox


def drain(box: Outbox) -> list:
    async def run():
        out = []
        while len(box):
            out.append(await box.next())
        return out
    return asyncio.run(run())


def test_a_page_that_never_reads_costs_a_bounded_queue_and_gets_the_newest():
    box = Outbox(max_messages=4, max_refusals=2)
    for i in range(10_000):
        box.put(f"reply {i}")
        box.refuse(f"refused {i}")
        box.latest("state", f"state {i}")
        box.latest("frame", ({"n": i}, b"jpeg"))
    assert len(box) == 4 + 2 + 2 and box.dropped == 4 * 10_000 - 8
    assert drain(box) == [("text", f"reply {i}") for i in range(9996, 10_000)] + [
        ("text", "refused 9998"), ("text", "refused 9999"), ("text", "state 9999"),
        ("frame", ({"n": 9999}, b"jpeg"))]


def test_a_closed_outbox_ends_its_sender():
    async def run():
        box = Outbox()
        waiting = asyncio.ensure_future(box.next())
        await asyncio.sleep(0)
        box.close()
        return await asyncio.wait_for(waiting, 5.0)
    assert asyncio.run(run()) is None


def test_a_budget_allows_its_burst_then_its_rate():
    b = Budget(rate=10.0, burst=5.0)
    assert all(b.take(0.0) for _ in range(5)) and not b.take(0.0)
    assert b.take(0.1) and not b.take(0.1)            # one more after 0.1 s at 10/s
    assert sum(b.take(10.0) for _ in range(100)) == 5   # never more than the burst

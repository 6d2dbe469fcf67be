"""Ending a private rclpy context so its DDS participant goes at once, not at some later garbage
collection.

`rclpy.shutdown(context=ctx)` leaves the participant alive while anything still holds one of its
nodes (an action server or client that `destroy_node` left, a reference cycle), until a later garbage
collection: a test run or a study worker that makes a context per test or trial then held up to 21
participants in one process, and Fast DDS can deadlock when a participant is torn down while
another of the same process removes its endpoints (docs/history.md, stop 30: eProsima/Fast-DDS
#6193). One owner for the teardown: `destroy_node` for each node, then `end_context`.
"""
from __future__ import annotations

import gc

from rclpy.context import Context
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node


def end_context(ctx: Context) -> None:
    """Shut `ctx` down (if it is still up) and delete its participant now; a second call does nothing.
    Destroy its nodes first: the participant goes once nothing holds the context (what still does is
    collected here). Afterwards `ctx.ok()` raises: the context is gone, not only shut down."""
    try:
        ctx.try_shutdown()
    except _rclpy.InvalidHandle:  # already ended
        return
    gc.collect()
    ctx.destroy()


def destroy_node(node: Node) -> None:
    """`node.destroy_node()`, then what it left: rclpy's destroy_node leaves the node's action servers
    and clients (its waitables), and each keeps the node, hence the context and its participant,
    alive. A node that destroys its own in destroy_node has none left here."""
    node.destroy_node()
    for waitable in list(node.waitables):
        destroy = getattr(waitable, "destroy", None)
        if destroy is not None:
            destroy()

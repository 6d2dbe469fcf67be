"""Whether a node in another process has discovered ours, in one place.

`wait_for_service` says only that this side sees a server. A server that has not yet matched the
client's reply reader drops its answer (rmw_fastrtps: the request is served, the reply is lost), which
hits a client made just before its call: a command-line tool, a test. An answer of the other node's
parameter service proves it knows this node's endpoints; they are announced in the order they are
made, so the clients made before the probe are known too.
"""
from __future__ import annotations

import time
from collections.abc import Callable

from vla_common.ros.spin import spin_until

# s between fresh requests: an unanswered one may have been dropped, not delayed
RETRY_S = 0.5


def discovered_by(node, remote: str, spin_once: Callable[[float], object], timeout: float) -> bool:
    """True once the node named `remote` (its full name, such as /recorder) answers a parameter
    request of `node` within `timeout`; `spin_once(seconds)` spins `node` meanwhile."""
    from rcl_interfaces.srv import GetParameters

    client = node.create_client(GetParameters, f"{remote.rstrip('/')}/get_parameters")
    deadline = time.monotonic() + timeout
    try:
        while (left := deadline - time.monotonic()) > 0:
            if not spin_until(spin_once, client.service_is_ready, left):
                return False
            future = client.call_async(GetParameters.Request())
            if spin_until(spin_once, future.done, min(RETRY_S, max(0.0, deadline - time.monotonic()))):
                return True
            client.remove_pending_request(future)
        return False
    finally:
        node.destroy_client(client)

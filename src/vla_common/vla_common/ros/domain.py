"""ROS-domain isolation, in one place: which ROS_DOMAIN_ID a run uses and how it keeps to itself.

Tests, evaluation, demonstration generation and the benchmarks all start graphs on a shared machine;
each takes a domain of its own from one range (so two of them pick at random from the same pool, and
a probe can refuse a busy one), discovers on localhost only and uses no static peers. Every child
process inherits what `isolate` puts into the environment.
"""
from __future__ import annotations

import fcntl
import os
import random
import tempfile
import time
from collections.abc import Callable, MutableMapping

# Fast DDS allows 0..232 (its port arithmetic); keep clear of 0 (the default) and the well-known low ids.
DOMAINS = range(30, 233)
DISCOVERY = "LOCALHOST"
DISCOVERY_VARIABLE = "ROS_AUTOMATIC_DISCOVERY_RANGE"   # rcl reads it when a context is initialised


class DomainError(RuntimeError):
    """No usable ROS domain: the one asked for is busy, or no free one was found."""


# s: a graph that just ended (killed, or still going down) stays in discovery until its participants'
# lease runs out (Fast DDS: 20 s), so a given domain is probed again for this long before it is refused.
STALE_GRAPH_S = 30.0


def pick_domain(preferred: int | None = None, *, busy: Callable[[int], bool] | None = None,
                tries: int = 8, stale_s: float = STALE_GRAPH_S,
                clock: Callable[[], float] = time.monotonic) -> int:
    """`preferred` if given (DomainError when `busy` still says another graph uses it after
    `stale_s`), else a random domain from DOMAINS that `busy` (when given) finds free."""
    if preferred is not None:
        if not 0 <= preferred <= DOMAINS.stop - 1:
            raise DomainError(f"ROS domain {preferred} is outside 0..{DOMAINS.stop - 1}")
        deadline = clock() + stale_s
        while busy is not None and busy(preferred):      # each probe listens for a while itself
            if clock() >= deadline:
                raise DomainError(f"ROS domain {preferred} already has another graph on it; "
                                  "choose a free ROS_DOMAIN_ID")
        return preferred
    for domain in random.SystemRandom().sample(DOMAINS, tries):
        if not _reserve(domain):
            continue  # another process on this machine picked it and holds it
        if busy is None or not busy(domain):
            return domain
        release_domain(domain)
    raise DomainError(f"no free ROS domain found in {tries} tries")


# Random picks on one machine are reserved with a lock file each, held by the picking process until
# `release_domain` or its exit (the kernel drops the lock), so that graphs started at the same moment
# (a sweep's workers, parallel test runs) never draw the same domain: a probe cannot see a graph that
# has not started yet.
_RESERVED: dict[int, int] = {}


def _lock_dir() -> str:
    path = os.path.join(tempfile.gettempdir(), f"vla-ros-domains-{os.getuid()}")
    os.makedirs(path, mode=0o700, exist_ok=True)
    return path


def _reserve(domain: int) -> bool:
    if domain in _RESERVED:
        return False  # this process holds it already (a graph of its own is on it)
    fd = os.open(os.path.join(_lock_dir(), f"{domain}.lock"), os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return False
    _RESERVED[domain] = fd
    return True


def release_domain(domain: int) -> None:
    """Give back a domain this process picked at random (no-op for one it did not reserve)."""
    fd = _RESERVED.pop(domain, None)
    if fd is not None:
        os.close(fd)  # closing the descriptor drops the lock


def isolate(env: MutableMapping[str, str] | None = None, domain: int | None = None, *,
            busy: Callable[[int], bool] | None = None) -> int:
    """Give `env` (default: this process's environment, before any rclpy context exists) a ROS
    domain of its own and localhost-only discovery; returns the domain. An explicit `domain` wins,
    then a ROS_DOMAIN_ID already set in `env` (a caller's choice), then a random one."""
    env = os.environ if env is None else env
    if domain is None and env.get("ROS_DOMAIN_ID"):
        domain = int(env["ROS_DOMAIN_ID"])
    domain = pick_domain(domain, busy=busy)
    env["ROS_DOMAIN_ID"] = str(domain)
    env[DISCOVERY_VARIABLE] = DISCOVERY
    env.pop("ROS_STATIC_PEERS", None)
    return domain


def isolated_env(domain: int | None = None, *, busy: Callable[[int], bool] | None = None,
                 base: dict[str, str] | None = None) -> dict[str, str]:
    """A copy of `base` (default: os.environ) for a graph's processes, isolated as `isolate` does."""
    env = dict(os.environ if base is None else base)
    isolate(env, domain, busy=busy)
    return env


def graph_on_domain(domain: int, names: set[str], topic: str, listen_s: float = 1.5) -> bool:
    """True when, within `listen_s`, a node named in `names` or a publisher of `topic` shows up on
    `domain`: another graph lives there. A probe for `pick_domain(busy=...)`."""
    import rclpy  # here: the rest of this module is read before any rclpy context exists
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions

    from vla_common.ros.context import end_context

    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = Node("vla_domain_probe", context=ctx)
        deadline = time.monotonic() + listen_s
        while time.monotonic() < deadline:
            if names & set(node.get_node_names()) or node.count_publishers(topic):
                return True
            time.sleep(0.1)  # discovery needs time; nothing here to wait on
        node.destroy_node()
        return False
    finally:
        end_context(ctx)

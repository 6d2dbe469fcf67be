"""vla_common.ros.domain: the one place a run picks its ROS domain."""
import pytest
from vla_common.ros.domain import DOMAINS, DomainError, isolate, isolated_env, pick_domain, release_domain


def test_a_given_domain_is_kept_unless_busy():
    assert pick_domain(42) == 42
    with pytest.raises(DomainError, match="42 already has another graph"):
        pick_domain(42, busy=lambda d: True, stale_s=0.0)


def test_a_given_domain_is_probed_again_while_a_graph_that_ended_leaves_discovery():
    """A killed graph's participants linger until their lease runs out: the probe waits them out
    (here on a fake clock: each probe takes 1.5 s), and refuses a graph that stays."""
    t = [0.0]

    def probe(answers):
        def busy(_d):
            t[0] += 1.5
            return next(answers)
        return busy
    assert pick_domain(42, busy=probe(iter([True, True, False])), clock=lambda: t[0]) == 42
    t[0] = 0.0
    with pytest.raises(DomainError, match="already has another graph"):
        pick_domain(42, busy=probe(iter([True] * 100)), stale_s=30.0, clock=lambda: t[0])
    assert 30.0 <= t[0] <= 33.0
    with pytest.raises(DomainError, match="outside"):
        pick_domain(300)


def test_a_random_domain_is_one_the_probe_finds_free():
    seen = []
    d = pick_domain(busy=lambda d: seen.append(d) or len(seen) < 3)
    assert d == seen[-1] and len(seen) == 3 and d in DOMAINS
    with pytest.raises(DomainError, match="no free ROS domain"):
        pick_domain(busy=lambda d: True, tries=2)


def test_isolate_keeps_a_callers_domain_and_forces_localhost_discovery():
    env = {"ROS_DOMAIN_ID": "77", "ROS_STATIC_PEERS": "10.0.0.2", "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}
    assert isolate(env) == 77
    assert env == {"ROS_DOMAIN_ID": "77", "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    assert isolate(env, 88) == 88 and env["ROS_DOMAIN_ID"] == "88"
    fresh = isolated_env(base={"PATH": "/bin"})
    assert int(fresh["ROS_DOMAIN_ID"]) in DOMAINS and fresh["PATH"] == "/bin"


def test_random_picks_at_the_same_moment_never_share_a_domain():
    """A probe cannot see a graph that has not started yet: two workers that pick at once drew the
    same domain (a sweep's two graphs then talked to each other). A pick is reserved machine-wide
    until released; another process cannot take it meanwhile."""
    import subprocess
    import sys

    picked = []
    while len(picked) <= len(DOMAINS):
        try:
            picked.append(pick_domain(tries=len(DOMAINS)))
        except DomainError:
            break
    # every domain at most once (this process, or another run on the machine, may hold a few already)
    assert len(set(picked)) == len(picked) >= len(DOMAINS) // 2
    code = ("from vla_common.ros.domain import pick_domain, DomainError\n"
            "try:\n    pick_domain(tries=8)\nexcept DomainError:\n    print('refused')")
    other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert other.stdout.strip() == "refused", other.stderr  # held here, so another process may not
    for d in picked:
        release_domain(d)
    assert pick_domain() in DOMAINS

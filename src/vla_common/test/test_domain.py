"""vla_common.ros.domain: the one place a run picks its ROS domain."""
import pytest
from vla_common.ros.domain import DOMAINS, DomainError, isolate, isolated_env, pick_domain


def test_a_given_domain_is_kept_unless_busy():
    assert pick_domain(42) == 42
    with pytest.raises(DomainError, match="42 already has another graph"):
        pick_domain(42, busy=lambda d: True)
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

"""Claimed ROS_DOMAIN_IDs (harness/domains.py): a domain with a DDS participant on this host is
never claimed, whoever started it; a claim held with EXCLUSIVE_ENV makes a domain exclusive."""
from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from tank_control.harness import domains

#: every test here claims real domains (lock files beside those of the test sessions; one
#: starts a participant)
pytestmark = pytest.mark.ros

@pytest.fixture
def two_domains() -> Iterator[tuple[int, int]]:
    """Two domains claimed (held) for the test: no other session starts a graph on them."""
    first, first_lock = domains.claim()
    second, second_lock = domains.claim()
    try:
        yield first, second
    finally:
        first_lock.close()
        second_lock.close()


def test_a_domain_with_a_participant_on_this_host_is_not_claimed(two_domains, monkeypatch,
                                                                  tmp_path):
    """A node started by hand on domain D (no lock file of ours): claim() takes the other
    domain every time instead of joining its graph."""
    import rclpy
    from rclpy.context import Context
    taken, free = two_domains
    context = Context()
    rclpy.init(context=context, domain_id=taken)
    node = rclpy.create_node('hand_started', context=context)
    try:
        deadline = time.monotonic() + 30
        while not domains.participants_on(taken) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert domains.participants_on(taken), f'no participant seen on domain {taken}'
        assert not domains.participants_on(free)
        # our claims of both are held: look at these two only, with lock files of their own
        monkeypatch.setattr(domains, 'LOCK_DIR', tmp_path)
        monkeypatch.setattr(domains, 'DOMAIN_IDS', (taken, free))
        for _ in range(12):                      # in random order: D first in about half
            domain_id, handle = domains.claim()
            handle.close()
            assert domain_id == free
        monkeypatch.setattr(domains, 'DOMAIN_IDS', (taken,))
        with pytest.raises(RuntimeError, match=f'with DDS participants on this host: {taken}'):
            domains.claim()
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_exclusive_only_with_the_variable_and_a_held_claim(monkeypatch, tmp_path):
    monkeypatch.setattr(domains, 'LOCK_DIR', tmp_path)
    monkeypatch.setattr(domains, 'participants_on', lambda domain_id: [])
    domain_id, handle = domains.claim()
    env = {'ROS_DOMAIN_ID': str(domain_id), domains.EXCLUSIVE_ENV: str(domain_id)}
    assert domains.exclusive_domain(env)
    assert not domains.exclusive_domain({**env, domains.EXCLUSIVE_ENV: str(domain_id + 1)})
    assert not domains.exclusive_domain({'ROS_DOMAIN_ID': str(domain_id)})
    handle.close()                               # a stale variable: the claim is gone
    assert not domains.exclusive_domain(env)


def test_the_start_profile_is_named_unless_the_caller_has_one():
    """The processes a run starts announce themselves often at first (a Fast DDS profile);
    a profile the caller names, or another middleware, is left alone."""
    env = domains.start_profile_env({'ROS_DOMAIN_ID': '7'})
    text = open(env[domains.PROFILES_ENV]).read()
    count, period = domains.START_ANNOUNCEMENTS
    assert f'<count>{count}</count>' in text and f'<nanosec>{int(period * 1e9)}</nanosec>' in text
    assert ('<leaseAnnouncement><sec>0</sec><nanosec>500000000</nanosec></leaseAnnouncement>'
            in text and domains.ANNOUNCEMENT_PERIOD == 0.5)
    own = {'FASTRTPS_DEFAULT_PROFILES_FILE': '/etc/mine.xml'}
    assert domains.start_profile_env(own) == own
    assert domains.start_profile_env({'FASTDDS_DEFAULT_PROFILES_FILE': 'x.xml'}).get(
        domains.PROFILES_ENV) is None
    assert domains.PROFILES_ENV not in domains.start_profile_env(
        {'RMW_IMPLEMENTATION': 'rmw_cyclonedds_cpp'})
    assert domains.PROFILES_ENV in domains.start_profile_env(
        {'RMW_IMPLEMENTATION': 'rmw_fastrtps_cpp'})

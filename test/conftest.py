"""Shared test set-up."""

import os

import pytest

# the reliability campaigns' generators and checks assert the properties the fuzz tests run: give
# their failures pytest's detailed assertion messages too
pytest.register_assert_rewrite('benchmarks.reliability')


def isolate_ros(monkeypatch, offset: int) -> int:
    """
    Give this test run a ROS domain of its own and return the domain.

    A ROS domain of this test run (1..100, from the pid and a per-file offset), localhost
    discovery only, unbuffered and uncoloured logs for the child processes. Returns the domain.
    """
    domain = 1 + (os.getpid() + offset) % 100
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('RCUTILS_LOGGING_BUFFERED_STREAM', '0')
    monkeypatch.setenv('RCUTILS_COLORIZED_OUTPUT', '0')
    monkeypatch.setenv('PYTHONUNBUFFERED', '1')
    return domain

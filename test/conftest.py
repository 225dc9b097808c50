"""Shared test set-up."""

from pulsejet_sim.ros.launching import isolation_variables, pick_domain_id
import pytest

# the reliability campaigns' generators and checks assert the properties the fuzz tests run: give
# their failures pytest's detailed assertion messages too
pytest.register_assert_rewrite('benchmarks.reliability')


def isolate_ros(monkeypatch, offset: int) -> int:
    """
    Give this test run a ROS domain of its own and return the domain.

    A ROS domain of this test run (1..100, from the pid and a per-file offset), localhost
    discovery only, unbuffered and uncoloured logs for the child processes
    (pulsejet_sim.ros.launching), set in this process's environment until the test ends.
    """
    domain = pick_domain_id(offset)
    for name, value in isolation_variables(domain).items():
        monkeypatch.setenv(name, value)
    return domain

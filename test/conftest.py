"""Shared fixtures: DDS stays on loopback for every test in this folder."""

import os

import pytest
import rosproc

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("HOME", "/tmp")


@pytest.fixture(autouse=True, scope="module")
def _test_domain_leases():
    """Domains leased by a module's tests are held until its last process has ended: this
    autouse fixture is set up first, so it is torn down after the module's own fixtures."""
    yield
    rosproc.release_test_domains()

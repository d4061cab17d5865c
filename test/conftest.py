"""Shared test fixtures: isolated ROS 2 discovery, repo paths."""
import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# Every test process discovers only on this host and gets its own DDS domain (../shared/NOTES.md).
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


@pytest.fixture
def repo() -> Path:
    return REPO


@pytest.fixture
def ros_env(tmp_path) -> dict:
    """Environment for a subprocess that uses ROS 2: localhost discovery, a fresh domain id."""
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["ROS_DOMAIN_ID"] = str(101 + (os.getpid() + hash(str(tmp_path))) % 100)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark every test that runs real ROS 2 (it asks for ``ros_env``) as ``ros``: ``-m "not ros"`` runs the
    ROS-free part of the suite."""
    for item in items:
        if "ros_env" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.ros)

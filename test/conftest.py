"""Shared test configuration: markers and one DDS domain per ROS test module.

Markers (``--strict-markers`` is on, see setup.cfg):

* ``ros`` -- the test starts ROS 2 nodes or participants (needs rclpy and DDS);
* ``slow`` -- the test takes more than a few seconds (``-m "not slow"`` for a quick run).

Every module marked ``ros`` runs in a DDS domain of its own, taken from
:func:`allocate_domain`: an exclusive file lock per domain ID, so two test modules, two
pytest processes or a test and a benchmark on the same machine never share a domain.
"""
from __future__ import annotations

import fcntl
import os
import tempfile
from pathlib import Path

import pytest

#: domain IDs the tests may use (0 is left to whatever a user runs by hand; ≤ 101 keeps the
#: default RTPS port mapping valid for many participants per domain)
DOMAIN_RANGE = range(30, 100)
LOCK_DIR = Path(tempfile.gettempdir()) / "fuel_valve_ros_domains"


def allocate_domain():
    """``(domain_id, lock_file)``: a domain ID no other holder uses; keep the file open while
    the domain is in use, close it to release."""
    LOCK_DIR.mkdir(exist_ok=True)
    start = os.getpid() % len(DOMAIN_RANGE)
    for i in range(len(DOMAIN_RANGE)):
        domain = DOMAIN_RANGE[(start + i) % len(DOMAIN_RANGE)]
        handle = open(LOCK_DIR / f"{domain}.lock", "w")
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        return domain, handle
    raise RuntimeError(f"no free ROS domain ID in {DOMAIN_RANGE}")


@pytest.fixture(scope="module", autouse=True)
def ros_domain(request):
    """For modules marked ``ros``: set ``ROS_DOMAIN_ID`` to a domain of their own (inherited by
    the node processes they start) for the module's lifetime."""
    if request.node.get_closest_marker("ros") is None:
        yield None
        return
    domain, handle = allocate_domain()
    old = os.environ.get("ROS_DOMAIN_ID")
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    try:
        yield domain
    finally:
        if old is None:
            os.environ.pop("ROS_DOMAIN_ID", None)
        else:
            os.environ["ROS_DOMAIN_ID"] = old
        handle.close()


def load_benchmark(name: str):
    """``benchmarks/<name>.py`` as a module (benchmarks are scripts, not a package)."""
    import importlib.util
    path = Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"{name}_bench", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="session")
def robustness_bench():
    """``benchmarks/robustness.py`` as a module (its case sampling and runner)."""
    return load_benchmark("robustness")


@pytest.fixture(scope="session")
def freezes_bench():
    """``benchmarks/vcpu_freezes.py`` as a module (the closed loop with controller freezes)."""
    return load_benchmark("vcpu_freezes")

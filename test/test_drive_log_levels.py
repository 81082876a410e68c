"""The controller's "drive off" log line says, by its severity, what the operator must do (h25r):
ERROR only for a latched fault (clear it, ~/reset); the drive-watchdog re-arm wait under load --
expected, recovered by itself -- at INFO (it was "drive DISABLED: state waiting" at ERROR, §40);
waiting for a demand / a resolver sample at WARN.  No ROS graph: the pure function the node calls."""
from __future__ import annotations

import re

import pytest

pytest.importorskip("rclpy")


def test_drive_off_severity_follows_what_the_operator_must_do():
    from fuel_valve_control.core.driver import DriverOutput
    from fuel_valve_control.ros.controller_node import drive_off_log

    rearm = DriverOutput(0.0, False, "waiting", 40.0, 39.2)            # demand and measurement in hand
    severity, text = drive_off_log(rearm)
    assert severity == "info" and "re-arms by itself" in text and "DISABLED" not in text
    severity, text = drive_off_log(DriverOutput(0.0, False, "waiting", None, 12.0))
    assert severity == "warn" and "waiting for a valid demand" in text
    severity, text = drive_off_log(DriverOutput(0.0, False, "waiting", 30.0, None))
    assert severity == "warn" and "a resolver sample" in text
    assert drive_off_log(DriverOutput(0.0, False, "inactive", 30.0, 30.0))[0] == "info"
    fault = DriverOutput(0.0, False, "fault", 30.0, 30.0, {"demand_stale": "no valid demand for 2.00 s"})
    severity, text = drive_off_log(fault)
    assert severity == "error" and "~/reset" in text
    # benchmarks/soak.py counts the faulted disablements from the log with this pattern
    line = f"[123.456] [controller]: {text}"
    found = re.findall(r"\[(\d+\.\d+)\] \[[^]]*\]: drive DISABLED: state \w+(?:, faults: (.*?)(?:: clear the cause.*)?)?$",
                       line, re.M)
    assert found == [("123.456", "no valid demand for 2.00 s")]

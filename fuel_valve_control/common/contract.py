"""The interface contract of SPEC §4 in one place, importable without rclpy.

Topic names (relative: they follow the node namespace) and message type names, joint names,
the ``drive`` telemetry labels, the stroke and pressure range, and the demand scalings
(percent of the 60° stroke, 4-20 mA with NAMUR NE43 limits).  The plant, the controller,
the tools and the tests all read these names from here; QoS profiles and message builders
live in :mod:`fuel_valve_control.ros.interface` (they need rclpy).

Sign conventions: angles in rad, 0 = closed, :data:`STROKE_RAD` = fully open; percent =
percent of the stroke; currents in A (q axis, positive opening); Δp in kPa.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

# --- topics (relative: they follow the node namespace) ---------------------------------------
DEMAND = "demand"
DEMAND_MA = "demand_ma"
POSITION = "position"
CURRENT_COMMAND = "current_command"
#: the currents (std_msgs/Float64MultiArray, A, latched, published on change) a drive applies over consecutive control
#: periods for which no new ``current_command`` arrived: ``data[0]`` in the first such period, ``data[1]`` in the
#: second, ..., the last element in every later one (:func:`current_without_command`).  Empty (the default, and what a
#: drive that never received this topic assumes): hold the last command, as a drive without this feature does.  The
#: controller sets it while its output is a timed open-loop sequence (the fine stage's doublet: the next period's
#: planned retreat, then the current holding the valve): a kick held over a late answer is a longer kick, and throws
#: the valve, and so does a retreat held over several (docs/control_results.md §113)
CURRENT_FALLBACK = "current_fallback"
DRIVE_ENABLE = "drive_enable"
RESOLVER = "resolver"
JOINT_STATES = "joint_states"
DRIVE = "drive"
#: the drive's state word (std_msgs/UInt8, latched, published on change): one of the
#: ``DRIVE_STATE_*`` codes below, like a CiA 402 status word or an ODrive axis state
DRIVE_STATUS = "drive_status"
ESTIMATE = "estimate"
PRESSURE_DIFFERENTIAL = "pressure_differential"
#: results of the controller's valve tests (signature, partial stroke): one JSON document per
#: finished run in a std_msgs/String (core/valve_tests.py documents the keys), latched
VALVE_TEST = "valve_test"
DIAGNOSTICS = "/diagnostics"
CLOCK = "/clock"

#: every topic of the suite with its message type name (the recorder's default list)
TOPIC_TYPES = {
    DEMAND: "std_msgs/msg/Float64",
    DEMAND_MA: "std_msgs/msg/Float64",
    POSITION: "std_msgs/msg/Float64",
    CURRENT_COMMAND: "std_msgs/msg/Float64",
    CURRENT_FALLBACK: "std_msgs/msg/Float64MultiArray",
    DRIVE_ENABLE: "std_msgs/msg/Bool",
    RESOLVER: "sensor_msgs/msg/JointState",
    JOINT_STATES: "sensor_msgs/msg/JointState",
    DRIVE: "std_msgs/msg/Float64MultiArray",
    DRIVE_STATUS: "std_msgs/msg/UInt8",
    ESTIMATE: "sensor_msgs/msg/JointState",
    PRESSURE_DIFFERENTIAL: "std_msgs/msg/Float64",
    VALVE_TEST: "std_msgs/msg/String",
    DIAGNOSTICS: "diagnostic_msgs/msg/DiagnosticArray",
}

#: topics of the control loop itself (keep-last-1: a loop wants the newest value, no backlog)
LOOP_TOPICS = (RESOLVER, CURRENT_COMMAND, DEMAND, DEMAND_MA)
#: topics that are latched (a late joiner still learns the state)
LATCHED_TOPICS = (DRIVE_ENABLE, VALVE_TEST, DRIVE_STATUS, CURRENT_FALLBACK)


def current_without_command(last_command_a: float, fallback_a: Sequence[float], missed: int) -> float:
    """The current (A) a drive applies in the ``missed``-th consecutive period (1 = the first) for which no new
    ``current_command`` arrived: that element of the :data:`CURRENT_FALLBACK` schedule (its last one beyond its end),
    or with an empty schedule the last command held.  A schedule with a non-finite element is refused by the drive
    (it holds): :func:`fallback_valid`."""
    if not fallback_a:
        return last_command_a
    return float(fallback_a[min(max(missed, 1), len(fallback_a)) - 1])


def fallback_valid(fallback_a: Sequence[float]) -> bool:
    """Whether a drive takes the :data:`CURRENT_FALLBACK` schedule ``fallback_a`` (every element finite)."""
    return all(math.isfinite(x) for x in fallback_a)


# --- the drive's state word (DRIVE_STATUS) ---------------------------------------------------
DRIVE_STATE_DISABLED = 0         # off because drive_enable is false (the controller's choice)
DRIVE_STATE_ENABLED = 1          # on: applying current_command
#: off by its own command watchdog (no current_command for the drive's timeout); it stays off
#: until the controller re-enables it (a drive_enable true received after the trip)
DRIVE_STATE_WATCHDOG = 2
#: off by an internal drive error; latched until drive_enable goes false, then true
DRIVE_STATE_FAULT = 3
DRIVE_STATE_NAMES = {DRIVE_STATE_DISABLED: "disabled", DRIVE_STATE_ENABLED: "enabled",
                     DRIVE_STATE_WATCHDOG: "watchdog", DRIVE_STATE_FAULT: "fault"}
#: default command watchdog of the drive, s (five 1 kHz periods): the plant's
#: ``command_timeout_s`` and the controller's ``faults.drive_command_timeout_s`` (what it
#: assumes of a drive that does not report its state) both default to it
DRIVE_COMMAND_TIMEOUT_S = 0.005
#: lockstep: longest wall time the demand node holds a tick's demand back for its subscribers
#: to match once the loop's controller has subscribed (then it goes out anyway: a graph entry
#: that never matches must not stall the run), s.  The plant's re-publication of an unanswered
#: tick waits longer than this (``plant_node.LOCKSTEP_RESEND_S``): a tick the demand node is
#: still allowed to hold back is not a lost one
LOCKSTEP_MATCH_WAIT_S = 2.0

MOTOR_JOINT = "motor_shaft"
VALVE_JOINT = "valve_shaft"
JOINT_NAMES = (MOTOR_JOINT, VALVE_JOINT)

#: labels of the ``drive`` telemetry array, in order (Float64MultiArray layout labels)
TELEMETRY_LABELS = (
    "i_d", "i_q", "v_d", "v_q", "i_a", "i_b", "i_c",
    "friction_motor_nm", "friction_valve_nm", "spring_nm", "flow_nm",
    "electromagnetic_torque_nm", "coupling_torque_nm",
)

# --- the valve -------------------------------------------------------------------------------
STROKE_RAD = 1.0472              # 60° stroke, open stop
PRESSURE_MAX_KPA = 6206.0        # maximum gas pressure differential across the valve
RESOLVER_COUNT_RAD = 2.0 * 3.141592653589793 / 65536   # one count of the 16-bit resolvers, rad

# --- demand scalings -------------------------------------------------------------------------
NE43_FAIL_LOW_MA = 3.6           # NAMUR NE43: at or below = signal failure
NE43_FAIL_HIGH_MA = 21.0         # at or above = signal failure
NE43_USABLE_LOW_MA = 3.8         # usable range (clamped to 0..100 %)
NE43_USABLE_HIGH_MA = 20.5
PERCENT_FAIL_MARGIN = 5.0        # percent demands beyond -5 % / 105 % are signal failures


def ma_to_percent(ma: float) -> float:
    """4-20 mA -> percent of stroke (4 mA = closed, 20 mA = open); not clamped."""
    return (ma - 4.0) / 16.0 * 100.0


def percent_to_ma(pct: float) -> float:
    """Percent of stroke -> 4-20 mA (inverse of :func:`ma_to_percent`)."""
    return 4.0 + 16.0 * pct / 100.0

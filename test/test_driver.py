"""Fault logic of the valve driver core (SPEC §4), without ROS and without a plant.

:class:`~fuel_valve_control.core.driver.ValveDriver` is driven directly with synthetic time
and synthetic resolver samples: a valve that stays where the test puts it is all the fault
logic needs (a stuck valve is exactly what the tracking and I²t faults are for).  For every
fault: it latches, the output is zero current with the drive disabled (the spring closes the
valve), it stays latched once the inputs are good again, a reset is refused while the cause
is still present, and a reset clears it and re-arms the loop once the inputs are healthy.
"""
import math

import pytest

from fuel_valve_control.common.contract import (PRESSURE_MAX_KPA, NE43_FAIL_HIGH_MA, NE43_FAIL_LOW_MA, NE43_USABLE_LOW_MA,
                                                PERCENT_FAIL_MARGIN, STROKE_RAD, percent_to_ma)
from fuel_valve_control.core import driver as D
from fuel_valve_control.core.driver import ValveDriver
from fuel_valve_control.core.params import CONTROLLER_SPEC

PS = CONTROLLER_SPEC.defaults()
N = PS["model.gear_ratio"]
T = 1.0 / PS["loop_rate_hz"]


RIGID_MARGIN = CONTROLLER_SPEC.params["faults.resolver_disagreement_margin_rad"].high


class Rig:
    """A driver, a clock and a valve that sits where the test puts it.

    Each period the rig delivers a resolver sample (``valve`` rad, motor at ``N x valve``)
    unless ``resolver`` is off, a demand every ``demand_every`` periods unless ``demand`` is
    None, and then calls :meth:`ValveDriver.step`.
    """

    def __init__(self, **params):
        # the rig's coupling is rigid (motor = N x valve whatever the current): the widest
        # twist margin keeps the motor/valve consistency check quiet (tested in test_safety.py)
        self.d = ValveDriver(PS.replace({"faults.resolver_disagreement_margin_rad": RIGID_MARGIN, **params}))
        self.t = 0.0
        self.k = 0
        self.valve = 0.4 * STROKE_RAD
        self.demand = 40.0               # % of stroke (or mA with demand_source ma)
        self.demand_every = 10
        self.resolver = True
        self.pressure = PRESSURE_MAX_KPA         # Δp reading delivered every period (None: silent)
        self.source = params.get("demand_source", "percent")

    def send_demand(self, value) -> None:
        if self.source == "ma":
            self.d.demand_ma(self.t, value)
        else:
            self.d.demand_percent(self.t, value)

    def run(self, seconds: float) -> D.DriverOutput:
        out = self.d.last
        for _ in range(max(int(round(seconds / T)), 1)):
            self.t += T
            self.k += 1
            if self.pressure is not None:              # the Δp transducer (kPa)
                self.d.pressure_differential(self.t, self.pressure)
            if self.resolver:
                self.d.resolver(self.t, N * self.valve, self.valve)
            if self.demand is not None and self.k % self.demand_every == 0:
                self.send_demand(self.demand)
            out = self.d.step(self.t)
        return out

    def healthy(self) -> D.DriverOutput:
        """Run until armed with good inputs; the drive must be on."""
        out = self.run(0.05)
        assert out.state == "running" and out.enable, (out.state, out.faults, out.warnings)
        return out


def _assert_failsafe(out: D.DriverOutput, code: str) -> None:
    assert code in out.faults, out.faults
    assert out.state == "fault"
    assert out.enable is False
    assert out.current_a == 0.0


def _assert_latched_then_reset(rig: Rig, code: str) -> None:
    """With good inputs restored the fault stays latched; a reset clears it and re-arms."""
    _assert_failsafe(rig.run(0.2), code)
    ok, msg = rig.d.reset()
    assert ok, msg
    assert code in msg
    out = rig.run(0.02)
    assert out.faults == {} and out.state == "running" and out.enable, (out.state, out.faults)
    assert rig.d.health().level == 0


def test_healthy_driver_runs_and_drives_current():
    rig = Rig()
    rig.valve = 0.3 * STROKE_RAD          # 10 % short of the demand: the loop must push open
    out = rig.healthy()
    assert out.current_a > 0.0
    assert out.demand_pct == pytest.approx(40.0)
    assert out.position_pct == pytest.approx(30.0)
    assert rig.d.health().level == 0


def test_waiting_until_both_inputs_arrive():
    rig = Rig()
    rig.demand = None
    out = rig.run(0.01)
    assert out.state == "waiting" and not out.enable and out.current_a == 0.0
    assert rig.d.health().level == 1 and "valid demand" in rig.d.health().message
    rig.demand = 40.0
    rig.healthy()


# ----------------------------------------------------------------------------- demand signal
@pytest.mark.parametrize("source, bad", [
    ("percent", math.nan), ("percent", math.inf), ("percent", -math.inf),
    ("percent", -PERCENT_FAIL_MARGIN - 1.0), ("percent", 100.0 + PERCENT_FAIL_MARGIN + 1.0),
    ("ma", NE43_FAIL_LOW_MA), ("ma", 2.0), ("ma", NE43_FAIL_HIGH_MA), ("ma", 22.5), ("ma", math.nan),
], ids=lambda v: str(v))
def test_demand_signal_failure_latches_until_reset(source, bad):
    rig = Rig(demand_source=source)
    good = percent_to_ma(40.0) if source == "ma" else 40.0
    rig.demand = good
    rig.healthy()
    rig.send_demand(bad)
    _assert_failsafe(rig.d.step(rig.t + T / 2), D.DEMAND_SIGNAL)
    # the bad value is the latest one: the cause persists, so no reset
    ok, msg = rig.d.reset()
    assert not ok and "cannot reset" in msg
    _assert_failsafe(rig.d.step(rig.t + T / 2), D.DEMAND_SIGNAL)
    assert rig.d.health().level == 2
    _assert_latched_then_reset(rig, D.DEMAND_SIGNAL)


def test_demand_signal_failure_on_the_unselected_source_is_ignored():
    rig = Rig()                            # percent selected
    rig.healthy()
    rig.d.demand_ma(rig.t, 2.0)           # a broken 4-20 mA loop nobody listens to
    out = rig.run(0.05)
    assert out.state == "running" and out.faults == {}


@pytest.mark.parametrize("source, value, clamped", [
    ("percent", 102.0, 100.0), ("percent", -2.0, 0.0),
    ("ma", 0.5 * (NE43_FAIL_LOW_MA + NE43_USABLE_LOW_MA), 0.0),
    ("ma", 20.8, 100.0),
])
def test_demand_slightly_out_of_range_is_clamped_with_a_warning(source, value, clamped):
    rig = Rig(demand_source=source)
    rig.demand = percent_to_ma(40.0) if source == "ma" else 40.0
    rig.healthy()
    rig.demand = value
    out = rig.run(0.05)
    assert out.state == "running" and out.enable and out.faults == {}
    assert out.demand_pct == pytest.approx(clamped)
    assert "demand_range" in out.warnings
    assert rig.d.health().level == 1
    # a demand inside the range again clears the warning (it describes the present input)
    rig.demand = percent_to_ma(50.0) if source == "ma" else 50.0
    out = rig.run(0.05)
    assert "demand_range" not in out.warnings


# ----------------------------------------------------------------------------- demand stale
def test_stale_demand_trips_and_reset_waits_for_a_fresh_demand():
    rig = Rig(demand_timeout_action="trip")
    rig.healthy()
    rig.demand = None
    out = rig.run(0.9 * PS["demand_timeout_s"])
    assert out.state == "running"                       # not yet stale
    out = rig.run(0.2 * PS["demand_timeout_s"])
    _assert_failsafe(out, D.DEMAND_STALE)
    ok, msg = rig.d.reset()
    assert not ok and "no valid demand" in msg
    _assert_failsafe(rig.run(0.05), D.DEMAND_STALE)
    rig.demand = 40.0
    _assert_latched_then_reset(rig, D.DEMAND_STALE)


def test_stale_demand_with_hold_keeps_the_last_demand_and_latches_a_warning():
    rig = Rig(demand_timeout_action="hold")
    rig.valve = 0.3 * STROKE_RAD
    rig.healthy()
    rig.demand = None
    out = rig.run(1.2 * PS["demand_timeout_s"])
    assert out.state == "holding" and out.enable and out.faults == {}
    assert out.demand_pct == pytest.approx(40.0)
    assert out.current_a != 0.0                         # still controlling
    assert D.DEMAND_STALE in out.warnings
    assert rig.d.health().level == 1
    # fresh demands resume normal running, but the warning stays latched until a reset
    rig.demand = 45.0
    out = rig.run(0.05)
    assert out.state == "running" and out.demand_pct == pytest.approx(45.0)
    assert D.DEMAND_STALE in out.warnings
    ok, msg = rig.d.reset()
    assert ok and D.DEMAND_STALE in msg
    assert D.DEMAND_STALE not in rig.run(0.02).warnings


# ----------------------------------------------------------------------------- resolver
def test_stale_resolver_latches_and_reset_waits_for_samples():
    rig = Rig()
    rig.healthy()
    rig.resolver = False
    timeout = PS["faults.resolver_timeout_s"]
    assert rig.run(0.5 * timeout).state == "running"
    _assert_failsafe(rig.run(timeout), D.RESOLVER_STALE)
    ok, msg = rig.d.reset()
    assert not ok and "resolver" in msg
    rig.resolver = True
    _assert_latched_then_reset(rig, D.RESOLVER_STALE)


@pytest.mark.parametrize("case", ["nan_valve", "inf_motor", "beyond_open", "below_closed", "jump",
                                  "disagree"])
def test_implausible_resolver_sample_latches_and_is_dropped(case):
    rig = Rig()
    rig.healthy()
    v = rig.valve
    motor, valve = {
        "nan_valve": (N * v, math.nan),
        "inf_motor": (math.inf, v),
        "beyond_open": (N * (STROKE_RAD + 0.2), STROKE_RAD + 0.2),
        "below_closed": (N * -0.2, -0.2),
        "jump": (N * (v + 10 * PS["faults.resolver_max_step_rad"]), v + 10 * PS["faults.resolver_max_step_rad"]),
        "disagree": (N * v + 1.2 * N * ValveDriver(PS).twist_limits(PS["limits.peak_current_a"])[2], v),
    }[case]
    rig.t += T
    rig.d.resolver(rig.t, motor, valve)
    out = rig.d.step(rig.t)
    _assert_failsafe(out, D.RESOLVER_IMPLAUSIBLE)
    assert out.position_pct == pytest.approx(100.0 * v / STROKE_RAD)    # the bad sample was dropped
    ok, msg = rig.d.reset()
    assert not ok and "cannot reset" in msg
    _assert_latched_then_reset(rig, D.RESOLVER_IMPLAUSIBLE)


def test_slow_resolver_allows_a_proportionally_larger_step():
    """The jump limit is per period: a sample 5 periods late may move 5 limits."""
    rig = Rig()
    rig.healthy()
    step = PS["faults.resolver_max_step_rad"]
    rig.t += 3 * T
    rig.d.resolver(rig.t, N * (rig.valve + 2.5 * step), rig.valve + 2.5 * step)
    assert rig.d.step(rig.t).faults == {}


# ----------------------------------------------------------------------------- loop faults
def test_tracking_error_beyond_limit_for_the_time_latches():
    """A stuck valve far from the demand: the fault comes after ``tracking_error_time_s``, not
    before.  The cause (the stuck valve) cannot be seen without driving, so a reset is
    accepted and the fault latches again after the same time if the valve is still stuck."""
    rig = Rig(**{"faults.tracking_error_time_s": 0.3})
    rig.valve = 0.4 * STROKE_RAD
    rig.demand = 40.0 + 100.0 * 2.0 * PS["faults.tracking_error_rad"] / STROKE_RAD
    out = rig.run(0.25)
    assert out.state == "running" and out.enable
    out = rig.run(0.1)
    _assert_failsafe(out, D.TRACKING)
    ok, _ = rig.d.reset()
    assert ok
    assert rig.run(0.1).state == "running"              # re-armed ...
    _assert_failsafe(rig.run(0.3), D.TRACKING)           # ... and tripped again: still stuck
    rig.valve = 0.4 * STROKE_RAD                         # now free: demand reached
    rig.demand = 40.0
    _assert_latched_then_reset(rig, D.TRACKING)


def test_tracking_error_that_recovers_in_time_does_not_latch():
    rig = Rig(**{"faults.tracking_error_time_s": 0.3})
    rig.demand = 40.0 + 100.0 * 2.0 * PS["faults.tracking_error_rad"] / STROKE_RAD
    assert rig.run(0.2).state == "running"
    rig.demand = 40.0
    assert rig.run(0.2).state == "running"
    rig.demand = 40.0 + 100.0 * 2.0 * PS["faults.tracking_error_rad"] / STROKE_RAD
    assert rig.run(0.2).state == "running"               # the timer restarted


def test_jam_exhausts_the_i2t_budget_and_latches_overcurrent():
    """Valve jammed far short of the demand: the loop asks for more than the continuous
    current, the I²t budget runs out, and after ``i2t_fault_time_s`` at the limit the
    over-current fault latches (tracking fault time set long so it does not come first)."""
    fault_time = 0.2
    rig = Rig(**{"faults.tracking_error_time_s": 60.0, "faults.i2t_fault_time_s": fault_time})
    rig.valve = 0.2 * STROKE_RAD
    rig.demand = 80.0
    rig.healthy()
    peak = 0.0
    for _ in range(200):
        out = rig.run(0.01)
        if out.faults:
            break
        peak = max(peak, abs(out.current_a))
    _assert_failsafe(out, D.OVERCURRENT)
    assert peak <= PS["limits.peak_current_a"] + 1e-9
    assert abs(rig.d.controller.last_current) <= PS["limits.continuous_current_a"] + 1e-9
    assert rig.d.health().values["i2t_budget_used"] >= 1.0 - 1e-9
    rig.valve = 0.8 * STROKE_RAD                          # jam cleared
    _assert_latched_then_reset(rig, D.OVERCURRENT)
    assert rig.d.health().values["i2t_budget_used"] < 0.5    # reset refilled the budget


@pytest.mark.parametrize("amps", [1.2 * 37.0, -1.2 * 37.0, math.nan, math.inf])
def test_measured_overcurrent_latches(amps):
    rig = Rig()
    rig.healthy()
    rig.d.measured_current(rig.t, 0.9 * PS["limits.peak_current_a"])   # within the rating
    assert rig.run(0.01).state == "running"
    rig.d.measured_current(rig.t, amps)
    _assert_failsafe(rig.run(0.01), D.OVERCURRENT)
    _assert_latched_then_reset(rig, D.OVERCURRENT)


def test_commanded_trip_latches_until_reset():
    rig = Rig()
    rig.healthy()
    rig.d.trip("operator test")
    out = rig.run(0.01)
    _assert_failsafe(out, D.TRIPPED)
    assert out.faults[D.TRIPPED] == "operator test"
    _assert_latched_then_reset(rig, D.TRIPPED)


def test_reset_with_nothing_latched_says_so():
    rig = Rig()
    rig.healthy()
    ok, msg = rig.d.reset()
    assert ok and msg == "nothing to clear"
    assert rig.run(0.01).state == "running"


def test_first_fault_message_is_kept_and_all_causes_are_listed():
    rig = Rig()
    rig.healthy()
    rig.d.trip("first")
    rig.d.trip("second")
    rig.d.measured_current(rig.t, math.nan)
    out = rig.run(0.01)
    assert out.faults[D.TRIPPED] == "first"
    assert set(out.faults) == {D.TRIPPED, D.OVERCURRENT}
    health = rig.d.health()
    assert health.level == 2 and "first" in health.message
    assert health.values["faults"] == ",".join(out.faults)


def test_rearm_after_a_fault_starts_like_a_fresh_driver():
    """After a trip the loop re-arms from zero torque, exactly as a driver that has just
    started, not from the torque it had before the trip (the drive was off in between)."""
    rig = Rig()
    rig.valve = 0.3 * STROKE_RAD
    rig.healthy()
    assert rig.run(0.3).current_a > 0.0
    rig.d.trip()
    rig.run(0.01)
    assert rig.d.reset()[0]
    rig.t += T
    rig.d.resolver(rig.t, N * rig.valve, rig.valve)
    first = rig.d.step(rig.t)
    fresh = ValveDriver(PS)
    fresh.pressure_differential(0.0, rig.pressure)
    fresh.resolver(0.0, N * rig.valve, rig.valve)
    fresh.demand_percent(0.0, rig.demand)
    expected = fresh.step(0.0)
    assert first.enable and expected.enable
    assert first.current_a == pytest.approx(expected.current_a, rel=1e-9, abs=1e-12)

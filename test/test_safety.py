"""Fail-safe rules of the driver core and the parameter schemas (issue 13), without ROS.

Each test names the defect of issue 13 it pins.  The valve driver is driven with synthetic
inputs (the ``Rig`` of ``test_driver.py``) or closed around the simulated plant
(``fuel_valve_sim``'s offline loop) where the physics is the subject.
"""

import numpy as np
import pytest

from fuel_valve_control.common import contract
from fuel_valve_control.common.contract import STROKE_RAD
from fuel_valve_control.common.paramspec import ConfigError
from fuel_valve_control.core import driver as D
from fuel_valve_control.core.params import CONTROLLER_SPEC, FP_BETA_MAX, load_controller_params
from fuel_valve_control.tools import sim
from fuel_valve_plant.physics.params import load_plant_params
from fuel_valve_plant.physics.plant import Plant

from test_driver import N, T, Rig, _assert_failsafe

PS = CONTROLLER_SPEC.defaults()


# ------------------------------------------------------------------ 1. no silent loop death
@pytest.mark.parametrize("shaft", ["motor", "valve"])
def test_fp_beta_that_overflowed_is_out_of_range(shaft):
    # issue 13.1: fp.motor.beta 200 was in range and overflowed speed ** beta at ~35 rad/s
    with pytest.raises(ConfigError, match="out of range"):
        PS.replace({f"fp.{shaft}.beta": 200.0})


def test_fp_extremes_in_range_keep_the_loop_finite_and_fault_free():
    # every fp.* parameter at the end of its range that makes |v|^beta largest
    extreme = {f"fp.{s}.{k}": v for s in ("motor", "valve")
               for k, v in (("beta", FP_BETA_MAX), ("alpha", CONTROLLER_SPEC.params["fp.motor.alpha"].high))}
    for mode in ("observer_fc", "observer_ff"):
        r = sim.run("large_step", mode=mode, controller_overrides=extreme)
        assert not r.fault.any(), mode
        assert np.all(np.isfinite(r.column("current_cmd_a"))), mode


class Boom(RuntimeError):
    pass


def _raise(*_args, **_kwargs):
    raise Boom("injected")


def test_exception_in_the_law_latches_an_internal_fault_and_the_loop_goes_on(monkeypatch):
    rig = Rig()
    rig.healthy()
    monkeypatch.setattr(rig.d.controller.law, "update", _raise)
    out = rig.run(0.01)                          # no exception escapes step()
    _assert_failsafe(out, D.INTERNAL)
    assert "Boom: injected" in out.faults[D.INTERNAL]
    assert rig.d.health().level == 2 and "internal error" in rig.d.health().message
    # the loop keeps running (and stays off) while the defect persists
    _assert_failsafe(rig.run(0.1), D.INTERNAL)
    monkeypatch.undo()
    ok, msg = rig.d.reset()
    assert ok and D.INTERNAL in msg
    out = rig.run(0.05)
    assert out.enable and out.state == "running"


@pytest.mark.parametrize("handler", ["resolver", "demand_percent", "pressure_differential", "measured_current"])
def test_exception_in_an_input_handler_latches_an_internal_fault(monkeypatch, handler):
    rig = Rig()
    rig.healthy()
    # break what each handler calls inside the driver
    target = {"resolver": "_implausible", "demand_percent": "_check_percent",
              "pressure_differential": "_warn_pressure", "measured_current": "_latch"}[handler]
    if handler == "measured_current":
        monkeypatch.setattr(D.math, "isfinite", _raise)
        rig.d.measured_current(rig.t, 1.0)
        monkeypatch.undo()
    else:
        monkeypatch.setattr(rig.d, target, _raise)
        if handler == "pressure_differential":
            rig.d.pressure_differential(rig.t, float("nan"))
        elif handler == "resolver":
            rig.d.resolver(rig.t, N * rig.valve, rig.valve)
        else:
            rig.d.demand_percent(rig.t, 40.0)
        monkeypatch.undo()
    _assert_failsafe(rig.run(0.002), D.INTERNAL)


def test_non_finite_command_latches_an_internal_fault(monkeypatch):
    rig = Rig()
    rig.healthy()
    monkeypatch.setattr(rig.d.controller._limiter, "apply", lambda request: float("nan"))
    out = rig.run(0.002)
    _assert_failsafe(out, D.INTERNAL)
    assert "non-finite" in out.faults[D.INTERNAL]


# ------------------------------------------------------------------ 4. learned quantities
KICKS = """name: kicks
description: hold 30 % at max dp; two 60 ms load kicks of +-25 N*m
duration_s: 6.0
pressure_differential_kpa: 6206
initial_percent: 30
demand: {type: constant, percent: 30}
events:
  - {at_s: 1.0, action: set_plant, params: {load_torque_nm: 25.0}}
  - {at_s: 1.06, action: set_plant, params: {load_torque_nm: 0.0}}
  - {at_s: 2.5, action: set_plant, params: {load_torque_nm: -25.0}}
  - {at_s: 2.56, action: set_plant, params: {load_torque_nm: 0.0}}
"""


def _kick_run(tmp_path):
    from fuel_valve_control.tools.run_plan import OFFLINE, plan_run
    from fuel_valve_control.tools.scenarios import load_scenario
    path = tmp_path / "kicks.yaml"
    path.write_text(KICKS)
    return sim.simulate_plan(plan_run(load_scenario(str(path)), OFFLINE))


def test_two_load_kicks_do_not_leave_the_valve_off_its_demand(tmp_path, monkeypatch):
    # issue 13.4: the kicks' displacements and returns were learned as stick-slip jumps (ratio
    # x16) and the valve rested 0.0157 rad off; now implausible breakaways are not learned
    from fuel_valve_control.core.integral_policy import JumpLearner
    learners = []
    real_init = JumpLearner.__init__

    def init(self, *a, **k):
        real_init(self, *a, **k)
        learners.append(self)
    monkeypatch.setattr(JumpLearner, "__init__", init)
    r = _kick_run(tmp_path)
    final_error = abs(r.column("position_rad")[-1] - 0.30 * STROKE_RAD)
    assert final_error < 3e-3, final_error
    learner = learners[-1]
    assert learner.ratio < 2.0 and learner.rejected >= 2, (learner.ratio, learner.rejected)


def test_the_jump_learner_learns_the_drives_breakaways_not_displacements():
    from fuel_valve_control.core.integral_policy import JumpLearner
    nominal, band, target = 1e-3, 1e-3, 0.5

    def breakaway(learner, start, end, driven=True):
        learner.update(start, True, True, nominal, target, band)
        learner.update(start, False, True, nominal, target, band, driven)
        learner.update(end, True, True, nominal, target, band)
    j = JumpLearner()
    breakaway(j, target - 3e-3, target + 2e-3)          # the drive's breakaway, past the target
    assert j.ratio == pytest.approx(1.0 + j.gain * (5.0 - 1.0))
    learned = j.ratio
    breakaway(j, target + 5e-4, target - 1.2e-3, driven=False)  # not driven, not displaced: learned
    assert not j.disturbed and j.ratio != learned
    learned = j.ratio
    breakaway(j, target + 5e-4, target - 0.05, driven=False)    # a kick: displaced beyond the band
    breakaway(j, target - 0.05, target + 0.01)                  # the recovery from it
    assert j.ratio == learned and j.disturbed and j.rejected == 2
    breakaway(j, target + 0.01, target + 5e-4)                  # rests within the band again
    assert not j.disturbed and j.rejected == 3
    breakaway(j, target + 5e-4, target - 0.05, driven=False)
    j.update(target, True, False, nominal, target, band)        # a new move: the displacement is over
    assert not j.disturbed
    for _ in range(50):                                         # bounded whatever it measures
        breakaway(j, target - 0.2, target + 0.2)
    assert j.ratio == j.limits[1]
    j.reset()
    assert j.ratio == 1.0 and not j.disturbed


def test_a_fault_reset_forgets_what_the_law_learned():
    rig = Rig()
    rig.healthy()
    law = rig.d.controller.law
    law.jumps.ratio = 30.0                          # as after a disturbance
    rig.d.controller.learner.equilibrium[1][0] = 0.1
    rig.run(0.002)
    deadband_before = law.deadband_rad()
    assert deadband_before > 10 * PS["integral.deadband_min_rad"]
    rig.d.trip("test")
    ok, _ = rig.d.reset()
    assert ok
    assert law.jumps.ratio == 1.0 and rig.d.controller.learner.equilibrium[1][0] == 0.0
    rig.run(0.01)
    assert law.deadband_rad() < deadband_before


# ------------------------------------------------------------------ 3. resolver failure detection
def test_disagreement_limit_is_sized_from_the_coupling_not_the_stroke():
    d = D.ValveDriver(PS)
    low, high, peak = d.twist_limits(PS["limits.continuous_current_a"])
    m = d.controller.model
    torque = m.gear_ratio * m.torque_constant_nm_per_a * PS["limits.continuous_current_a"]
    assert low < torque / m.coupling_stiffness_nm_per_rad < high
    assert high < 0.6 * STROKE_RAD                   # was 1.5 rad, beyond the whole stroke
    assert peak < 1.5


def test_motor_resolver_stuck_at_zero_latches(monkeypatch):
    rig = Rig(**{"faults.resolver_disagreement_margin_rad": PS["faults.resolver_disagreement_margin_rad"]})
    rig.demand = 30.0
    rig.valve = 0.30 * STROKE_RAD
    rig.healthy()
    # the motor resolver freezes at 0 while the valve resolver keeps reading 30 %
    monkeypatch.setattr(rig.d, "resolver", lambda t, motor, valve, f=rig.d.resolver: f(t, 0.0, valve))
    _assert_failsafe(rig.run(0.3), D.RESOLVER_IMPLAUSIBLE)
    assert "resolver" in rig.d.health().message


def test_the_twist_check_is_held_while_the_drive_reports_itself_off(monkeypatch):
    # the commanded current is not the applied one while the drive reports it is off (its
    # watchdog, or not yet enabled): the twist is then no evidence about the resolvers.  Under
    # CPU load a loop that commanded 15 A into a drive still off latched "a resolver has failed"
    rig = Rig(**{"faults.resolver_disagreement_margin_rad": PS["faults.resolver_disagreement_margin_rad"]})
    rig.demand = 30.0
    rig.valve = 0.30 * STROKE_RAD
    rig.d.drive_status(rig.t, contract.DRIVE_STATE_DISABLED)     # the enable not yet echoed
    rig.healthy()
    # the motor resolver reads 0 while the valve reads 30 %: a twist no current explains
    monkeypatch.setattr(rig.d, "resolver", lambda t, motor, valve, f=rig.d.resolver: f(t, 0.0, valve))
    out = rig.run(0.3)
    assert not out.faults and out.enable, out.faults
    rig.d.drive_status(rig.t, contract.DRIVE_STATE_ENABLED)      # the drive applies the current now
    _assert_failsafe(rig.run(0.3), D.RESOLVER_IMPLAUSIBLE)


def test_tracking_error_that_dips_under_the_limit_still_latches():
    # issue 13.3: the timer restarted whenever the error dipped; a valve swinging around the
    # demand (a failed sensor) never tripped.  Beyond the limit 80 % of the time -> latches.
    limit = PS["faults.tracking_error_rad"]
    rig = Rig(**{"faults.tracking_error_time_s": 0.3, "faults.resolver_max_step_rad": 1.0})
    rig.healthy()
    demand_rad = 0.4 * STROKE_RAD
    out = None
    for k in range(200):
        rig.valve = demand_rad + (2.0 * limit if k % 5 else 0.0)
        out = rig.run(0.005)
        if out.faults:
            break
    _assert_failsafe(out, D.TRACKING)


# ------------------------------------------------------------------ 7. limits only tighten at run time
@pytest.mark.parametrize("name,wider", [
    ("limits.continuous_current_a", 40.0), ("limits.peak_current_a", 40.0), ("limits.peak_time_s", 1.0),
    ("faults.tracking_error_time_s", 60.0), ("faults.resolver_timeout_s", 5.0), ("demand_timeout_s", 60.0),
    ("demand_timeout_action", "hold"), ("faults.i2t_fault_time_s", 60.0), ("faults.tracking_error_rad", 1.0),
    ("faults.coupling_stiffness_min_fraction", 0.05), ("faults.resolver_disagreement_time_s", 1.0)])
def test_widening_a_limit_at_run_time_is_rejected(name, wider):
    d = D.ValveDriver(PS)
    with pytest.raises(ConfigError, match="restart with a parameter file to widen"):
        d.set_params({name: wider})
    assert d.ps[name] == PS[name]                    # nothing changed


def test_tightening_and_back_to_the_start_up_value_is_accepted():
    d = D.ValveDriver(PS)
    d.set_params({"limits.continuous_current_a": 10.0, "faults.tracking_error_time_s": 0.5})
    assert d.controller.current_limits[0] == PS["limits.peak_current_a"]
    d.set_params({"limits.continuous_current_a": PS["limits.continuous_current_a"]})   # back: allowed
    with pytest.raises(ConfigError):
        d.set_params({"limits.continuous_current_a": PS["limits.continuous_current_a"] + 1.0})
    # a start-up file may set wider values: the start-up set is the reference
    wide = D.ValveDriver(PS.replace({"faults.tracking_error_time_s": 30.0}))
    wide.set_params({"faults.tracking_error_time_s": 20.0})


# ------------------------------------------------------------------ 5. sample stamps
def test_future_stamped_sample_is_implausible_and_does_not_poison_the_reference():
    rig = Rig()
    rig.healthy()
    rig.d.resolver(rig.t + 3600.0, N * rig.valve, rig.valve, now=rig.t)     # an hour ahead
    out = rig.run(0.01)
    _assert_failsafe(out, D.RESOLVER_IMPLAUSIBLE)
    assert "ahead" in out.faults[D.RESOLVER_IMPLAUSIBLE]
    assert rig.d.last_resolver_time <= rig.t                        # the reference is a genuine sample
    rig.run(D.RESET_QUIET_S)
    ok, msg = rig.d.reset()                                         # genuine samples go on: reset works
    assert ok, msg
    out = rig.run(0.05)
    assert out.enable and out.state == "running", out.faults


# ------------------------------------------------------------------ 8. bad values, intermittent causes
def test_reset_is_refused_during_an_intermittent_resolver_fault():
    rig = Rig()
    rig.healthy()
    for _ in range(3):                        # a noise burst: every 30th sample is garbage
        rig.d.resolver(rig.t, N * rig.valve, float("nan"))
        rig.run(0.03)
        ok, msg = rig.d.reset()
        assert not ok and "implausible input" in msg
    rig.run(D.RESET_QUIET_S + 0.01)           # quiet long enough
    assert rig.d.reset()[0]


def test_a_stalled_loop_re_arms_from_the_measurement_and_keeps_the_i2t_state():
    rig = Rig(**{"faults.tracking_error_time_s": 60.0})
    rig.valve = 0.2 * STROKE_RAD
    rig.demand = 80.0                             # jammed short of the demand: the I2t budget drains
    rig.healthy()
    rig.run(0.3)
    used = rig.d.health().values["i2t_budget_used"]
    assert used > 0.5
    rig.t += 0.05             # the loop stalls for 50 ms (> the drive's 5 ms command timeout)
    out = rig.run(0.001)
    assert rig.d.stall_rearms == 1 and out.reenable and out.enable
    assert rig.d.health().values["i2t_budget_used"] >= used - 0.05


# ------------------------------------------------------------------ 2. the drive's own watchdog
def _spy_resets(monkeypatch, driver) -> list:
    """Record the (torque N*m, keep_limits) of every law re-arm of ``driver``."""
    calls, real = [], driver.controller.reset

    def spy(meas, pressure, torque=0.0, keep_limits=False):
        calls.append((torque, keep_limits))
        return real(meas, pressure, torque, keep_limits=keep_limits)
    monkeypatch.setattr(driver.controller, "reset", spy)
    return calls


def test_a_drive_watchdog_report_re_arms_from_the_holding_torque_and_re_enables(monkeypatch):
    # the soak defect: the drive switched itself off (and on) during loop gaps and the driver
    # went on with a stale law.  A drive that reports its watchdog trip: the next period
    # re-arms from the measurement (I2t state kept) and re-enables it, once.  It re-arms from
    # the torque that holds the valve where it is (the model's equilibrium at the measured
    # angle and Δp), neither the stale request nor zero torque (the spring then pulled the
    # valve down while the law wound up: _freezes below)
    rig = Rig()
    rig.d.drive_status(rig.t, contract.DRIVE_STATE_ENABLED)
    rig.demand = 60.0
    rig.healthy()
    stale = rig.run(0.005)
    assert abs(stale.current_a) > 1.0            # driving the valve: a command that would be stale
    calls = _spy_resets(monkeypatch, rig.d)
    rig.d.drive_status(rig.t, contract.DRIVE_STATE_WATCHDOG)
    out = rig.run(0.001)
    holding = rig.d.controller.model.equilibrium(rig.valve, rig.d.pressure_kpa)[1]
    assert abs(holding) > 0.01 and holding != pytest.approx(stale.current_a * rig.d.controller.model.torque_constant_nm_per_a)
    assert calls == [(pytest.approx(holding), True)] and rig.d.stall_rearms == 1
    assert out.enable and out.reenable and out.state == "running"
    assert rig.d.health().values["drive_state"] == "watchdog"
    rig.d.drive_status(rig.t, contract.DRIVE_STATE_ENABLED)       # the drive is back on
    out = rig.run(0.01)
    assert not out.reenable and rig.d.stall_rearms == 1 and len(calls) == 1


def test_a_reporting_drive_is_followed_not_the_loop_gap():
    rig = Rig()
    rig.d.drive_status(rig.t, contract.DRIVE_STATE_ENABLED)
    rig.healthy()
    rig.t += 0.05                # a 50 ms gap, but the drive says it stayed on: its state is not stale
    out = rig.run(0.001)
    assert rig.d.stall_rearms == 0 and not out.reenable
    # a report while the loop is not running the drive (waiting, faulted) needs no re-arm: the
    # enable edge of the next arming re-enables the drive anyway
    rig.d.trip()
    rig.run(0.01)
    rig.d.drive_status(rig.t, contract.DRIVE_STATE_WATCHDOG)
    rig.run(D.RESET_QUIET_S)
    assert rig.d.reset()[0]
    out = rig.run(0.001)
    assert rig.d.stall_rearms == 0 and out.enable and not out.reenable


@pytest.mark.parametrize("state", [contract.DRIVE_STATE_FAULT, 7])
def test_a_drive_fault_report_latches_a_fault(state):
    rig = Rig()
    rig.healthy()
    rig.d.drive_status(rig.t, state)
    _assert_failsafe(rig.run(0.01), D.DRIVE_FAULT)


@pytest.mark.parametrize("gap_s, timeout_s, rearms", [(0.004, 0.005, 0), (0.007, 0.005, 1), (0.012, 0.010, 1),
                                                      (0.05, 0.0, 0)])
def test_an_unreported_drive_re_arms_on_a_gap_beyond_its_command_timeout(gap_s, timeout_s, rearms):
    # hardware without a drive state word: the loop's own gap beyond the drive's command
    # timeout (faults.drive_command_timeout_s; 0: a drive without a watchdog) says it tripped
    rig = Rig(**{"faults.drive_command_timeout_s": timeout_s})
    rig.healthy()
    rig.t += gap_s - 0.001
    out = rig.run(0.001)
    assert rig.d.stall_rearms == rearms and out.reenable == bool(rearms) and out.enable


def _stalls(report: bool, gap_periods: int, demand: float = 47.5, stalls: int = 5) -> tuple[float, D.ValveDriver]:
    """Offline closed loop (default mode) held at ``demand`` %, then ``stalls`` controller
    stalls of ``gap_periods`` periods each, 0.3 s apart.  The drive keeps the last command for
    its 5 ms command timeout and is then off.  ``report``: the drive reports its trip and
    stays off until the driver re-enables it (plant_node); else the v1 drive that re-enabled
    itself on the next command, unseen by a driver with no gap rule.  The peak valve, %."""
    from test_param_swap import loop
    plant = Plant(load_plant_params(overrides={"pressure_sensor.noise_kpa": 0.0}))
    drv = D.ValveDriver(load_controller_params(overrides={"faults.drive_command_timeout_s": 0.0}))
    if report:
        drv.drive_status(0.0, contract.DRIVE_STATE_ENABLED)
    loop(drv, plant, 0.0, 1500, lambda t: demand)
    t, period, peak = 1.5, drv.period, 0.0
    on_periods = int(round(contract.DRIVE_COMMAND_TIMEOUT_S / period))
    for _ in range(stalls):
        last = drv.last
        for k in range(gap_periods):                      # the stall: nobody steps the driver
            on = k < on_periods
            plant.set_command(last.current_a if on else 0.0, last.enable and on)
            plant.advance(period)
            t += period
            peak = max(peak, plant.truth().valve_angle)
        if report:
            drv.drive_status(t, contract.DRIVE_STATE_WATCHDOG)
        drive_on, enabled = not report, True
        for _ in range(300):
            out, _ = sim.exchange_period(drv, plant, t, demand)
            # the drive comes back on an explicit re-enable or an enable edge (plant_node), and
            # a reporting drive says so
            if not drive_on and (out.reenable or (out.enable and not enabled)):
                drive_on = True
                if report:
                    drv.drive_status(t, contract.DRIVE_STATE_ENABLED)
            enabled = out.enable
            plant.set_command(out.current_a if drive_on else 0.0, out.enable and drive_on)
            plant.advance(period)
            t += period
            peak = max(peak, plant.truth().valve_angle)
    return 100.0 * peak / STROKE_RAD, drv


@pytest.mark.parametrize("freeze_periods", [7, 9])
def test_vcpu_freezes_during_a_moving_demand_re_arm_at_once_and_keep_the_valve_on_it(freezes_bench, freeze_periods):
    # the soak's watchdog trips: 6-9 ms freezes of a vCPU (benchmarks/vcpu_freezes.py), every
    # 0.25 s here on the soak's sine.  The driver re-armed only once the valve was "at rest"
    # (0.03 rad/s, below the speed of a moving demand), so every trip during a move left the
    # drive off until the spring had closed the valve -- 31.7 % under the demand here, 59 % in
    # the soak -- and then re-acquired the demand from the stop (re-arming from zero torque
    # dropped a valve it re-armed at once by 8 %).  A valve slower than the re-arm speed (or
    # closing) is re-armed at once, from its holding torque
    period = 1.0 / load_controller_params()["loop_rate_hz"]
    seconds = 2.5
    freezes = freezes_bench.regular_freezes(freeze_periods, 0.25, seconds, period)
    r = freezes_bench.simulate_freezes(freezes, seconds)
    drv = r["driver"]
    assert r["freezes"] == 6 and drv.stall_rearms == r["freezes"] and not drv.last.faults
    assert drv.last.state == "running"
    assert r["excess_pct"] <= 2.0 and r["shortfall_pct"] <= 2.0, r


def test_the_law_is_held_at_its_re_arm_until_the_drive_reports_it_is_back_on():
    # the soak's 4.4 %: re-armed and re-enabled after a trip, the plant took the re-enable 44 ms
    # late; meanwhile the law ran on against a drive that applied nothing while the spring
    # closed the valve, wound up to 37 A, and the valve shot from the stop past its demand.
    # Until the drive reports it is on, each period re-arms from the measurement: the command
    # is the torque that holds the valve where it is, never a wound-up one
    rig = Rig()
    rig.d.drive_status(rig.t, contract.DRIVE_STATE_ENABLED)
    rig.healthy()
    rig.d.drive_status(rig.t, contract.DRIVE_STATE_WATCHDOG)
    out = rig.run(T)
    assert out.enable and out.reenable and rig.d.stall_rearms == 1
    kt = rig.d.controller.model.torque_constant_nm_per_a
    for _ in range(40):                        # still off: the spring closes the valve, 0.5 rad/s
        rig.valve -= 0.5 * T
        out = rig.run(T)
        holding = rig.d.controller.model.equilibrium(rig.valve, rig.d.pressure_kpa)[1] / kt
        assert out.enable and not out.reenable and out.current_a == pytest.approx(holding, abs=0.05), \
            (out.current_a, holding)
    rig.d.drive_status(rig.t, contract.DRIVE_STATE_ENABLED)      # it has taken the re-enable
    currents = [rig.run(T).current_a for _ in range(20)]
    assert max(abs(c - currents[0]) for c in currents) > 0.05 and rig.d.stall_rearms == 1   # the law runs
    assert not rig.d.last.faults
    # a drive that does not report back: every DRIVE_BACK_TIMEOUT_S the re-enable is sent again
    # and the law stays held at its re-arm (before: the law ran on after the first timeout and,
    # under CPU load, commanded 15 A into a drive that was still off: a false "resolver has
    # failed" fault); after DRIVE_BACK_ATTEMPTS re-enables, a drive fault
    rig.d.drive_status(rig.t, contract.DRIVE_STATE_WATCHDOG)
    outs = [rig.run(T) for _ in range(int(round(D.DRIVE_BACK_ATTEMPTS * D.DRIVE_BACK_TIMEOUT_S / T)) - 5)]
    assert rig.d.stall_rearms == 2 and not rig.d.last.faults
    assert sum(o.reenable for o in outs) == D.DRIVE_BACK_ATTEMPTS, [k for k, o in enumerate(outs) if o.reenable]
    assert all(o.enable for o in outs)
    held = [o.current_a for o in outs[1:]]     # after the re-arm period
    assert max(held) - min(held) < 0.05, (min(held), max(held))     # held at the holding torque
    for _ in range(20):
        out = rig.run(T)
    assert D.DRIVE_FAULT in out.faults and not out.enable and out.current_a == 0.0, out


@pytest.mark.parametrize("direction", [+1.0, -1.0])
def test_a_valve_opening_in_full_swing_waits_for_the_re_arm_a_closing_one_does_not(direction):
    # re-arming a valve in full swing (its re-armed observer starts at rest) drove it 25 % past
    # its demand in a starved soak: an opening one still waits, drive off, until it is slow.
    # A closing one is re-armed at once: with the drive off the spring only speeds it up, and
    # waiting closed the valve (a stick-slip slip caught by a trip: 52 -> 0 % in the soak)
    rig = Rig()
    rig.d.drive_status(rig.t, contract.DRIVE_STATE_ENABLED)
    rig.healthy()
    speed = direction * 4.0 * rig.d.rearm_speed_rad_s        # in full swing, drive already off
    for _ in range(D.REST_WINDOW_SAMPLES):
        rig.valve += speed * T
        rig.run(T)
    rig.d.drive_status(rig.t, contract.DRIVE_STATE_WATCHDOG)
    rig.valve += speed * T
    out = rig.run(T)
    assert rig.d.stall_rearms == 1
    if direction < 0:
        assert out.enable and out.reenable and out.state == "running"
        return
    for _ in range(5):
        assert not out.enable and out.state == "waiting"
        rig.valve += speed * T
        out = rig.run(T)
    for _ in range(D.REST_WINDOW_SAMPLES):                       # slower than the re-arm speed
        rig.valve += 0.5 * rig.d.rearm_speed_rad_s * T
        out = rig.run(T)
    assert out.enable and out.state == "running" and rig.d.stall_rearms == 1


@pytest.mark.parametrize("gap_periods", [12, 19])
def test_controller_stalls_at_a_hold_keep_the_valve_within_demand_plus_2_percent(gap_periods):
    # 12-19 ms stalls at a 47.5 % hold, five times.  A drive that re-enabled itself under a
    # driver that did not know (v1) ran the valve beyond demand + 2 % (the soak's defect,
    # reproduced here as the control case); reported and re-armed, it stays within.  The
    # control case stalls 22 periods: with the fine stage's stiff hold (observer_fp) the v1
    # driver reached 49.44 % after 19-period stalls (observer_ff: 50.14 %) and 50.53 % after 22
    peak, drv = _stalls(True, gap_periods)
    assert peak <= 47.5 + 2.0 and not drv.last.faults and drv.stall_rearms == 5, (peak, drv.last.faults)
    assert drv.last.enable and drv.last.state == "running"
    v1_peak, _ = _stalls(False, 22)
    assert v1_peak > 47.5 + 2.0, v1_peak

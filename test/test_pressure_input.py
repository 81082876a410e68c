"""Δp as an input, without ROS: the plant's pressure transducer (rate, noise, seeding) and the
valve driver's handling of the measured pressure differential (used by the law while valid;
missing, stale or implausible -> a latched warning, not a trip, and the fallback schedule; with
``pressure.recover_s`` > 0 a gap's warning clears itself after that long of timely readings; in real
time the first arm's wait for a steady stream waits out Δp gaps too).

The DDS side (the plant publishes it, the controller schedules for it, ``ros2 param set`` on
the plant reaches the controller) is in ``test_parameters.py``.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from fuel_valve_control.common.contract import PRESSURE_MAX_KPA
from fuel_valve_control.core.driver import PRESSURE_INPUT, ValveDriver
from fuel_valve_control.core.params import load_controller_params
from fuel_valve_control.core.signals import Measurement
from fuel_valve_plant.physics.params import load_plant_params
from fuel_valve_plant.physics.plant import Plant
from prefetch import ModuleRuns, jobs, selected_items

PERIOD = 1e-3
VALVE = 0.2          # rad, a valve at rest part-open
N = 48.019           # nominal gear ratio (motor angle of a resting drivetrain)


def driver(**overrides) -> ValveDriver:
    return ValveDriver(load_controller_params(overrides=overrides))


def run(drv: ValveDriver, periods: int, dp=None, every: int = 10, t0: float = 0.0):
    """``periods`` control periods of a valve at rest at 20 % demand; ``dp`` (kPa, or a function
    of the period index) is fed every ``every`` periods (None: never).  Returns the outputs."""
    outs = []
    for k in range(periods):
        t = t0 + k * PERIOD
        drv.demand_percent(t, 100.0 * VALVE / drv.stroke)
        drv.resolver(t, VALVE * N, VALVE)
        value = dp(k) if callable(dp) else dp
        if value is not None and k % every == 0:
            drv.pressure_differential(t, value)
        outs.append(drv.step(t))
    return outs


# ------------------------------------------------------------------ the plant's transducer
def test_transducer_samples_at_its_rate_with_exact_value_without_noise():
    plant = Plant(load_plant_params(overrides={"pressure_differential_kpa": 3103.0,
                                               "pressure_sensor.noise_kpa": 0.0}))
    samples = []
    for _ in range(1000):                       # 1 s of 1 kHz control periods
        samples.append(plant.pressure_sample())
        plant.advance(PERIOD)
    got = [s for s in samples if s is not None]
    assert len(got) == 100                      # pressure_sensor.rate_hz default 100 Hz
    assert samples[0] == 3103.0 and samples[1] is None and samples[10] == 3103.0
    assert set(got) == {3103.0}


def test_transducer_noise_is_seeded_and_leaves_the_resolvers_alone():
    def record(noise, seed=0):
        plant = Plant(load_plant_params(overrides={"pressure_sensor.noise_kpa": noise, "seed": seed,
                                                   "pressure_differential_kpa": 3000.0}))
        dps, resolver = [], []
        for _ in range(2000):
            dp = plant.pressure_sample()
            if dp is not None:
                dps.append(dp)
            resolver.append(plant.resolver().valve_rad)
            plant.advance(PERIOD)
        return np.array(dps), np.array(resolver)

    a, ra = record(20.0)
    b, rb = record(20.0)
    c, rc = record(0.0)
    np.testing.assert_array_equal(a, b)                  # same seed, same readings
    np.testing.assert_array_equal(ra, rc)                # Δp noise draws do not shift the resolver noise
    assert abs(a.mean() - 3000.0) < 4 * 20.0 / math.sqrt(len(a))
    assert 14.0 < a.std() < 26.0
    assert not np.array_equal(a, record(20.0, seed=1)[0])


def test_transducer_noise_changes_at_run_time():
    plant = Plant(load_plant_params(overrides={"pressure_sensor.noise_kpa": 0.0}))
    assert plant.pressure_differential() == plant.params["pressure_differential_kpa"]
    plant.set_params({"pressure_sensor.noise_kpa": 50.0})
    readings = [plant.pressure_differential() for _ in range(50)]
    assert np.std(readings) > 10.0


# ------------------------------------------------------------------ the driver's input
def test_valid_pressure_schedules_the_law():
    measured = driver()
    outs = run(measured, 50, dp=3103.0)
    assert all(o.enable and not o.warnings for o in outs)
    assert measured.pressure_kpa == 3103.0
    assert measured.health().values["pressure_source"] == "measured"
    # the law sees exactly the measured value: a driver whose fallback is that value and that
    # never gets a reading commands the same currents (until its missing-Δp warning, 0.1 s)
    told = driver(**{"pressure.fallback_kpa": 3103.0})
    assert [o.current_a for o in run(told, 50)] == [o.current_a for o in outs]
    # and the schedule matters: another Δp gives another command
    other = run(driver(), 50, dp=0.0)
    assert max(abs(a.current_a - b.current_a) for a, b in zip(outs, other)) > 0.05


def test_reading_within_the_margin_is_clamped_to_full_scale():
    drv = driver()
    run(drv, 5, dp=PRESSURE_MAX_KPA + 100.0)
    assert drv.pressure_kpa == PRESSURE_MAX_KPA and not drv.warnings


def test_missing_pressure_warns_after_the_timeout_and_uses_the_fallback():
    drv = driver(**{"pressure.fallback_kpa": 1000.0})
    outs = run(drv, 150)                                   # timeout 0.1 s
    assert not outs[90].warnings
    assert PRESSURE_INPUT in outs[-1].warnings and "no pressure differential reading received" in \
        outs[-1].warnings[PRESSURE_INPUT]
    assert all(o.enable and o.state == "running" for o in outs)    # a warning, never a trip
    assert drv.pressure_kpa == 1000.0
    h = drv.health()
    assert h.level == 1 and h.values["pressure_source"] == "fallback" and "fallback" in h.message


def test_stale_pressure_warns_and_falls_back():
    drv = driver()
    outs = run(drv, 300, dp=lambda k: 4000.0 if k < 50 else None, every=10)
    assert not outs[120].warnings                       # last reading at 40 ms: 80 ms old, valid
    assert "no pressure differential reading for" in outs[-1].warnings[PRESSURE_INPUT]
    assert outs[-1].enable and drv.pressure_kpa == 0.0  # the fallback (default 0 kPa)


@pytest.mark.parametrize("bad, words", [
    (math.nan, "not a finite number"),
    (math.inf, "not a finite number"),
    (-1000.0, "outside"),
    (7000.0, "outside"),
    ("6206", "not a finite number"),
])
def test_implausible_reading_warns_and_falls_back(bad, words):
    drv = driver(**{"pressure.fallback_kpa": 500.0})
    run(drv, 20, dp=3000.0)
    assert drv.pressure_kpa == 3000.0
    drv.pressure_differential(0.02, bad)
    out = drv.step(0.02)
    assert words in out.warnings[PRESSURE_INPUT]
    assert out.enable and not out.faults
    assert drv.pressure_kpa == 500.0


def test_physically_impossible_rate_is_implausible():
    drv = driver()
    run(drv, 11, dp=1000.0)                             # readings at 0 and 10 ms
    drv.pressure_differential(0.012, 6000.0)           # +5000 kPa in 2 ms: 2.5e6 kPa/s
    assert "changed +5000 kPa in 2.0 ms" in drv.step(0.012).warnings[PRESSURE_INPUT]
    assert drv.pressure_kpa == 0.0
    # a fast but physical change (1000 kPa in 10 ms = 1e5 kPa/s) is accepted
    ok = driver()
    run(ok, 20, dp=lambda k: 1000.0 if k < 10 else 2000.0)
    assert ok.pressure_kpa == 2000.0 and not ok.warnings


def test_schedule_recovers_when_valid_and_an_implausible_readings_warning_clears_on_reset():
    drv = driver()
    run(drv, 20, dp=3000.0)
    drv.pressure_differential(0.02, math.nan)
    drv.step(0.02)
    outs = run(drv, 1500, dp=3000.0, t0=0.021)            # 1.5 s of timely readings > pressure.recover_s
    assert drv.pressure_kpa == 3000.0                     # valid again: measured value used
    assert PRESSURE_INPUT in outs[-1].warnings            # ... but the transducer's warning stays latched
    assert drv.pressure_gap_episodes == 0
    ok, message = drv.reset()
    assert ok and PRESSURE_INPUT in message
    assert not run(drv, 5, dp=3000.0, t0=1.53)[-1].warnings


RECOVER = {"pressure.recover_s": 1.0}


def test_a_gaps_warning_clears_itself_after_timely_readings_if_asked():
    """With pressure.recover_s > 0 a stale Δp (a transport gap) warns, then clears itself once the
    readings have arrived without a gap that long (here 1 s); it is counted."""
    drv = driver(**RECOVER)
    gap = lambda k: None if 200 <= k < 400 else 4000.0     # noqa: E731 -- 0.2 s without a reading
    outs = run(drv, 1800, dp=gap)
    assert "no pressure differential reading for" in outs[399].warnings[PRESSURE_INPUT]
    assert outs[399].enable and drv.health().values["pressure_gap_episodes"] == 1
    # readings again from 0.4 s: the schedule at once, the warning after 1 s of them
    assert drv.pressure_kpa == 4000.0
    assert PRESSURE_INPUT in outs[1390].warnings
    assert PRESSURE_INPUT not in outs[1410].warnings and not outs[-1].warnings
    assert drv.health().level == 0 and drv.pressure_gap_episodes == 1


def test_a_gap_inside_the_recovery_restarts_it_and_by_default_the_warning_is_latched():
    drv = driver(**RECOVER)
    gaps = lambda k: None if 200 <= k < 400 or 900 <= k < 1050 else 4000.0    # noqa: E731
    outs = run(drv, 2600, dp=gaps)
    assert drv.pressure_gap_episodes == 1                  # one warning, never cleared in between
    assert PRESSURE_INPUT in outs[2000].warnings           # 1.05 s + 1 s of readings not yet reached
    assert PRESSURE_INPUT not in outs[-1].warnings
    latched = driver()                                     # SPEC §4: latched until ~/reset
    assert PRESSURE_INPUT in run(latched, 1800, dp=lambda k: None if 200 <= k < 400 else 4000.0)[-1].warnings
    assert latched.pressure_gap_episodes == 1


def test_missing_at_start_clears_once_the_source_arrives_if_asked():
    """A Δp source matched late (none received within pressure.timeout_s of the loop's first
    period) is a gap too: with pressure.recover_s 1 s the warning clears 1 s after its readings start."""
    drv = driver(**RECOVER)
    outs = run(drv, 1500, dp=lambda k: None if k < 300 else 2000.0)
    assert "no pressure differential reading received" in outs[299].warnings[PRESSURE_INPUT]
    assert PRESSURE_INPUT in outs[1290].warnings and not outs[-1].warnings


def _real_time(drv: ValveDriver, periods: int, dp, t0: float = 0.0, resolver=lambda k: True):
    """Periods as the node runs them in real time (the sample's timing told to the driver); ``dp(k)``
    kPa or None, ``resolver(k)``: whether the period's resolver sample arrives."""
    outs = []
    for k in range(periods):
        t = t0 + k * PERIOD
        drv.demand_percent(t, 100.0 * VALVE / drv.stroke)
        if resolver(k):
            drv.resolver(t, VALVE * N, VALVE, now=t)
            drv.loop_timing(t, t)
        value = dp(k)
        if value is not None:
            drv.pressure_differential(t, value)
        outs.append(drv.step(t))
    return outs


def test_in_real_time_a_start_up_stall_before_the_first_arm_is_no_pressure_gap():
    """A node process's start-up stall silences the resolver and the Δp transducer alike: the first
    arm waits for a steady resolver stream (faults.arm_steady_s), and the Δp watch with it.  The
    same silence after the arm latches the warning (under ros2 launch a 0.27 s start-up stall had
    left the node at WARN until ~/reset)."""
    stall = lambda k: not 20 <= k < 290                         # noqa: E731 -- 0.27 s silent, from 20 ms
    drv = driver()
    outs = _real_time(drv, 900, dp=lambda k: 3000.0 if stall(k) else None, resolver=stall)
    armed = next(i for i, o in enumerate(outs) if o.enable)
    assert armed > 290 + 200                                    # the arm waited out the stall
    assert not outs[-1].faults and not outs[-1].warnings and drv.pressure_gap_episodes == 0
    assert drv.health().level == 0
    # armed, the same stall is a Δp gap: latched (the resolver's silence too: a fault)
    late = _real_time(drv, 400, dp=lambda k: 3000.0 if stall(k) else None, t0=0.9, resolver=stall)
    assert PRESSURE_INPUT in late[-1].warnings and drv.pressure_gap_episodes == 1


def test_warning_latches_again_after_reset_while_the_input_is_still_missing():
    drv = driver()
    run(drv, 150)
    assert drv.reset()[0]
    assert PRESSURE_INPUT in run(drv, 2, t0=0.15)[-1].warnings


def test_fallback_value_changes_at_run_time():
    drv = driver()
    run(drv, 5)
    assert drv.pressure_kpa == 0.0
    drv.set_params({"pressure.fallback_kpa": 2000.0})
    run(drv, 1, t0=0.005)
    assert drv.pressure_kpa == 2000.0


# ------------------------------------------------------------------ a transducer that reads wrong
def test_transducer_bias_gain_error_and_silence():
    plant = Plant(load_plant_params(overrides={"pressure_differential_kpa": 3000.0}))
    assert plant.pressure_differential() == 3000.0                 # defaults: an exact transducer
    plant.set_params({"pressure_sensor.bias_kpa": -500.0, "pressure_sensor.gain_error": 0.1})
    assert plant.pressure_differential() == pytest.approx(3000.0 * 1.1 - 500.0)
    plant.set_params({"pressure_sensor.silent": True})
    samples = []
    for _ in range(50):
        samples.append(plant.pressure_sample())
        plant.advance(PERIOD)
    assert samples == [None] * 50


def test_friction_check_reads_the_static_friction_of_a_quasi_static_breakaway():
    from fuel_valve_control.core.friction_check import FrictionCheck
    from fuel_valve_control.core.model import NominalModel
    from fuel_valve_control.common.contract import RESOLVER_COUNT_RAD
    ps = load_controller_params()
    m = NominalModel.from_params(ps)
    check = FrictionCheck(m, PERIOD, RESOLVER_COUNT_RAD)
    ts = 1.2                                   # N*m: the valve's static friction (Δp ~ 0.14 max)
    k = m.coupling_stiffness_nm_per_rad
    valve = VALVE
    for direction in (1, -1, 1, -1):
        load = m.load_torque(valve, 0.0)
        # wind the drive up slowly (quasi-static) until the valve torque reaches +-Ts, then slip
        for i in range(60):
            net = direction * ts * i / 59
            torque_valve = load + net
            motor = (valve + torque_valve / k) * m.gear_ratio
            motor_torque = (torque_valve + direction * m.gear_ratio * m.motor_coulomb_nm) / m.gear_ratio
            check.update(Measurement(motor, valve), motor_torque, 0.0)
        valve += direction * 2e-3          # the slip: the valve outruns the drive (the coupling unwinds)
        for _ in range(3):
            check.update(Measurement(motor, valve), motor_torque, 0.0)
    assert check.breakaways == 4
    assert check.met_static_nm == pytest.approx(ts, rel=0.05)
    assert check.plausible(0.0)                                 # Ts(0) = 0.5 N*m: ratio 2.4 (x0.5..3)
    assert not check.plausible(PRESSURE_MAX_KPA)                # Ts(max) = 5.5 N*m: ratio 0.22
    assert check.friction_pressure_kpa() == pytest.approx((ts - 0.5) / 5.0 * PRESSURE_MAX_KPA, rel=0.1)


def _hold_and_small_steps(mode, true_kpa, told_kpa, check=None):
    """:func:`_simulate_hold_and_small_steps`'s run, from the module's look-ahead workers while
    the module fixture below is active (test/prefetch.py), else run here."""
    return _AHEAD.result(mode, true_kpa, told_kpa, check)


def _simulate_hold_and_small_steps(mode, true_kpa, told_kpa, check=None):
    """9 s offline at 20 %: a 1.5 s hold (the check needs breakaways both ways: observer_fc,
    told max on a valve at Δp 0, is caught at 0.46 s), +-0.5 % and +1 % steps, a 3 s final hold, with the Δp transducer
    biased so that it reads ``told_kpa`` while the valve is at ``true_kpa``; ``check``: pressure.friction_check
    (None: the default)."""
    from fuel_valve_control.tools import metrics as M
    from fuel_valve_control.tools import sim
    from fuel_valve_control.tools.scenarios import parse_scenario
    points = [[0, 20], [1.5, 20], [1.5, 20.5], [3.0, 20.5], [3.0, 20.0], [4.5, 20.0], [4.5, 21.0], [6.0, 21.0],
              [6.0, 20.5], [9.0, 20.5]]
    sc = parse_scenario({"name": "dp_wrong", "duration_s": 9.0, "initial_percent": 20,
                         "pressure_differential_kpa": true_kpa,
                         "demand": {"type": "points", "points": points, "interpolation": "previous"}})
    ctrl = {} if check is None else {"pressure.friction_check": check}     # None: the default (on)
    p, c = sim.build(sc, {"pressure_sensor.bias_kpa": told_kpa - true_kpa}, ctrl, 0, mode)
    res = sim.simulate(sc, p, c)
    log = res.log
    tr = M.Trace(log[:, 0], log[:, 1], log[:, 2], np.hypot(log[:, 7], log[:, 8]), log[:, 9], res.stroke_rad)
    return M.plateau_results(tr), res


#: the module's look-ahead runs (test/prefetch.py); none outside the module fixture below
_AHEAD = ModuleRuns(_simulate_hold_and_small_steps)


def _planned(item) -> list[tuple]:
    """The runs (``_hold_and_small_steps``' arguments, positional) a selected test asks for; a run
    left out here is simulated when the test asks, as before."""
    name, params = item.originalname, getattr(getattr(item, "callspec", None), "params", {})
    if name == "test_wrong_pressure_reading_is_caught_by_the_friction_met_and_never_hunts":
        return [(params["mode"], params["true_kpa"], params["told_kpa"], None)]
    if name == "test_without_the_friction_check_a_wrong_reading_does_not_hunt":
        return [("observer_ff", params["true_kpa"], params["told_kpa"], False)]
    if name == "test_a_right_reading_raises_no_friction_warning":
        return [("observer_ff", PRESSURE_MAX_KPA, PRESSURE_MAX_KPA, None)]
    return []


@pytest.fixture(scope="module", autouse=True)
def _look_ahead(request):
    """The module's 9 s runs on both cores (test/prefetch.py); each test still takes and asserts
    its own run."""
    keys = [key for item in selected_items(request) for key in _planned(item)]
    with _AHEAD.planned(keys, jobs(request.config)):
        yield


@pytest.mark.slow
@pytest.mark.parametrize("mode, true_kpa, told_kpa", [
    ("observer_ff", 0.0, PRESSURE_MAX_KPA),
    ("observer_ff", PRESSURE_MAX_KPA, 0.0),
    ("observer_fc", 0.0, PRESSURE_MAX_KPA),
])
def test_wrong_pressure_reading_is_caught_by_the_friction_met_and_never_hunts(mode, true_kpa, told_kpa):
    from fuel_valve_control.core.driver import PRESSURE_FRICTION
    plateaus, res = _hold_and_small_steps(mode, true_kpa, told_kpa)
    assert len(plateaus) == 4
    assert not any(pl["hunts"] for pl in plateaus), [(pl["hunting_amplitude_rad"], pl["hunting_reversals"])
                                                     for pl in plateaus]
    assert PRESSURE_FRICTION in res.warnings and "implausible" in res.warnings[PRESSURE_FRICTION]
    assert not res.fault.any()


@pytest.mark.slow
@pytest.mark.parametrize("true_kpa, told_kpa", [(0.0, PRESSURE_MAX_KPA), (PRESSURE_MAX_KPA, 0.0)])
def test_without_the_friction_check_a_wrong_reading_does_not_hunt(true_kpa, told_kpa):
    """The default mode's hold is scheduled on the friction it meets, the Δp reading only the
    prior (IntegralPolicy.hold_static_nm, SlipEdges; h16w).  Before, with the check off, told
    max on a valve at Δp 0 hunted on all 4 plateaus (26 counts): the held load learned from
    the schedule's static level flipped sign slip after slip, the drive test rejected every
    real breakaway and the stuck ramp ran 11x too fast."""
    plateaus, res = _hold_and_small_steps("observer_ff", true_kpa, told_kpa, False)
    assert len(plateaus) == 4
    assert not any(pl["hunts"] for pl in plateaus), [(pl["hunting_amplitude_rad"], pl["hunting_reversals"])
                                                     for pl in plateaus]
    assert not res.warnings and not res.fault.any()


@pytest.mark.slow
def test_a_right_reading_raises_no_friction_warning():
    plateaus, res = _hold_and_small_steps("observer_ff", PRESSURE_MAX_KPA, PRESSURE_MAX_KPA)
    assert not res.warnings and not any(pl["hunts"] for pl in plateaus)

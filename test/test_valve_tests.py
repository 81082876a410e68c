"""Valve signature and partial-stroke tests (issue 12, core/valve_tests.py), offline.

The signature test runs in the offline simulator on the same core objects as the node; its
measured friction is compared with the plant's TRUE friction (read from the plant's own
parameters through the shared friction law): the drivetrain's Coulomb friction referred to the
valve shaft, valve level at the Δp + N x motor level, plus the viscous torque at the ramp speed.
"""
from __future__ import annotations

import functools
import json
import math

import numpy as np
import pytest

from fuel_valve_plant.physics.friction import friction_levels
from fuel_valve_plant.physics.params import load_plant_params

from fuel_valve_control.core.driver import ValveDriver
from fuel_valve_control.core.params import load_controller_params
from fuel_valve_control.core.valve_tests import PARTIAL_STROKE, SIGNATURE, ValveTests, unit_of
from fuel_valve_control.tools.run_plan import OFFLINE, plan_run
from fuel_valve_control.tools.scenarios import parse_scenario
from fuel_valve_control.tools.sim import simulate_plan
from prefetch import ModuleRuns, jobs, selected_items

#: stated tolerance of the measured friction against the plant's true level (nominal plant):
#: measured -0.3 % at 0 kPa, +1.0 % at 3103 kPa, +7.4 % at 6206 kPa (stick-slip at high Δp
#: dissipates a little more in the fast jumps: viscous and coupling damping)
FRICTION_TOLERANCE = 0.10
#: a shortened signature (fewer steps) to keep the suite fast; same ramp as the default
SHORT = {"tests.enable": True, "tests.signature.steps_pct": [0.5, 2.0], "tests.signature.step_time_s": 0.5,
         "tests.signature.dwell_s": 0.5}
RAMP_PCT = (20.0, 60.0)


def signature_scenario(pressure_kpa: float, events=((1.0, "signature_test"),), duration_s=21.0,
                       controller=None) -> dict:
    return {"name": "signature", "description": "test", "duration_s": duration_s,
            "pressure_differential_kpa": pressure_kpa, "initial_percent": RAMP_PCT[0],
            "demand": {"type": "constant", "percent": RAMP_PCT[0]},
            "controller": dict(SHORT, **(controller or {})),
            "events": [{"at_s": at, "action": action} for at, action in events]}


def run(doc: dict, friction_scale=1.0, baselines=()):
    plan = plan_run(parse_scenario(doc), OFFLINE, seed=0, plant_overrides={"friction_scale": friction_scale})
    return simulate_plan(plan, baselines=list(baselines))


def true_friction_nm(pressure_kpa: float, friction_scale: float = 1.0) -> float:
    """The plant's drivetrain Coulomb friction at the valve shaft plus the viscous torque at the
    signature's ramp speed, N*m (what the signature measures)."""
    ps = load_plant_params(overrides={"pressure_differential_kpa": pressure_kpa, "friction_scale": friction_scale})
    lv = friction_levels(ps)
    n = ps["gearbox.ratio"]
    speed = load_controller_params()["tests.signature.ramp_rate_pct_s"] / 100.0 * ps["valve.stroke_rad"]
    viscous = (ps["valve.viscous_nms"] + n * n * ps["motor.viscous_nms"]) * speed
    return lv.valve_coulomb_nm + n * lv.motor_coulomb_nm + viscous


def signature(pressure_kpa: float, friction_scale: float = 1.0, base_kpa: float | None = None):
    """The short signature at ``pressure_kpa`` on the plant with ``friction_scale``; ``base_kpa``: judged against
    the stored baseline of the nominal plant's signature at that Δp (None: no baseline, the run is its own)."""
    return _result("signature", pressure_kpa, friction_scale,
                   None if base_kpa is None else ("signature", base_kpa, 1.0, None))


#: per process (this one, or a look-ahead worker): the runs made or taken here by key (:func:`_run_key`'s
#: arguments) -- a judged run takes its baseline from here
_RUNS: dict = {}


def _result(*key):
    """The run ``key`` (:func:`_run_key`), once per test process: from the look-ahead where the module fixture
    planned the bundle holding it (:data:`BUNDLES`), else simulated here (that run alone)."""
    if key not in _RUNS:
        bundle = next((b for b in BUNDLES if key in b), None)
        if bundle is not None and _AHEAD.waiting(*bundle):
            _RUNS.update(_AHEAD.result(*bundle))
        else:
            _RUNS[key] = _run_key(*key)
    return _RUNS[key]


def _run_key(what: str, pressure_kpa: float = 0.0, friction_scale: float = 1.0, base: tuple | None = None):
    """A run: the signature at ``pressure_kpa``, or the nominal-Δp partial stroke (``pressure_kpa`` unused), on
    the plant with ``friction_scale``; ``base``: the key of the baseline-free nominal run whose test result is
    this run's stored baseline (None: none; made here first if this process has not made or taken it)."""
    doc = signature_scenario(pressure_kpa) if what == "signature" else partial_scenario(PARTIAL_EVENTS)
    if base is None:
        return run(doc, friction_scale)
    if base not in _RUNS:
        _RUNS[base] = _run_key(*base)
    stored = _RUNS[base].valve_tests[SIGNATURE if base[0] == "signature" else PARTIAL_STROKE]
    return run(doc, friction_scale, [stored])


def _simulate(*keys) -> dict:
    """A bundle of runs (here or in a look-ahead worker, test/prefetch.py): ``{key: run}``, in order -- a judged
    run after its baseline, which it reuses (one worker makes both: no baseline is simulated twice)."""
    out = {}
    for key in keys:
        out[key] = _RUNS[key] = _run_key(*key)
    return out


#: the module's look-ahead runs (test/prefetch.py); none outside the module fixture below
_AHEAD = ModuleRuns(_simulate)
#: the partial-stroke runs' events (the nominal partial stroke and the ones judged against it)
PARTIAL_EVENTS = [(2.5, "partial_stroke_test")]
_SIG0, _SIG3103, _SIG6206 = (("signature", p, 1.0, None) for p in (0.0, 3103.0, 6206.0))
_PARTIAL = ("partial", 0.0, 1.0, None)
#: the look-ahead's work units, the longest first (~5.5, 4.2, 3, 1.9 s of CPU): each baseline with the runs
#: judged against it
BUNDLES = ((_SIG6206, ("signature", 6206.0, 2.0, _SIG6206), ("signature", 6206.0, 1.0, _SIG6206)),
           (_SIG0, ("signature", 6206.0, 1.0, _SIG0)),
           (_PARTIAL, ("partial", 0.0, 1.0, _PARTIAL), ("partial", 0.0, 2.0, _PARTIAL)),
           (_SIG3103,))
#: the runs each test asks for (the bundles holding any of them are planned)
_PLANNED = {"test_signature_detects_friction_x2_against_the_nominal_baseline": BUNDLES[0],
            "test_baseline_taken_at_another_pressure_still_compares": BUNDLES[1],
            "test_partial_stroke_nominal_passes_and_friction_x2_is_flagged": BUNDLES[2],
            "test_partial_stroke_returns_the_valve_to_its_start": [_PARTIAL],
            "test_report_recognises_valve_tests_and_plots_them_next_to_the_baseline": BUNDLES[0][:2]}


@pytest.fixture(scope="module", autouse=True)
def _look_ahead(request):
    """The module's 21 s signatures and its nominal partial stroke on both cores; each test
    still takes and asserts its own run."""
    keys = set()
    for item in selected_items(request):
        if item.originalname == "test_signature_recovers_true_friction":
            keys.add(("signature", item.callspec.params["pressure_kpa"], 1.0, None))
        keys.update(_PLANNED.get(item.originalname, []))
    with _AHEAD.planned([b for b in BUNDLES if keys.intersection(b)], jobs(request.config)):
        yield


# 3103 kPa was a strict xfail (the signature's 2 % step up did not settle within its hold since the
# deadband was sized per direction, h14r); it settles with the default mode's hold on the friction met (h16w)
@pytest.mark.parametrize("pressure_kpa", [0.0, 3103.0, 6206.0])
def test_signature_recovers_true_friction(pressure_kpa):
    result = signature(pressure_kpa)
    res = result.valve_tests[SIGNATURE]
    assert res["status"] == "completed", res["reason"]
    figs = res["figures"]
    truth = true_friction_nm(pressure_kpa)
    assert figs["friction_mean_nm"] == pytest.approx(truth, rel=FRICTION_TOLERANCE)
    # friction is flat over the stroke (the plant's law has no position dependence)
    assert figs["friction_max_nm"] - figs["friction_min_nm"] < 0.05 * truth
    # spring (flow torque taken off with the nominal model): the plant's 4 N*m/rad, 8 N*m
    plant = load_plant_params()
    assert figs["spring_rate_nm_per_rad"] == pytest.approx(plant["spring.rate_nm_per_rad"], rel=0.05)
    assert figs["spring_preload_nm"] == pytest.approx(plant["spring.preload_nm"], rel=0.02)
    # breakaway: at least the Coulomb level, at most the static level + motor static + 30 %
    lv = friction_levels(load_plant_params(overrides={"pressure_differential_kpa": pressure_kpa}))
    static = lv.valve_static_nm + plant["gearbox.ratio"] * lv.motor_static_nm
    for direction in ("open", "close"):
        assert truth * 0.95 < figs[f"breakaway_{direction}_nm"] < 1.3 * static
    # every step answered, settled, small final error; the first run is its own baseline
    assert figs["deadband_pct"] <= 0.5
    assert figs["step_2pct_up_settling_time_s"] < 0.5
    # (0.19 % at 6206 kPa: the loop's own stick-slip accuracy within the 0.5 s hold, not the test's)
    assert abs(figs["step_2pct_up_final_error_pct"]) < 0.3
    assert 0.0 <= figs["hysteresis_pct"] < 1.0
    assert res["baseline"]["source"] == "this run" and res["findings"] == []
    # curve for the plot: both directions, opening above closing by twice the friction
    curve = res["curve"]
    assert len(curve["torque_open_nm"]) == len(curve["torque_close_nm"]) == len(curve["position_pct"])
    assert all(o > c for o, c in zip(curve["torque_open_nm"], curve["torque_close_nm"]))
    assert unit_of("friction_mean_nm") == "N*m" and unit_of("spring_rate_nm_per_rad") == "N*m/rad"


def test_signature_detects_friction_x2_against_the_nominal_baseline():
    worn = signature(6206.0, 2.0, base_kpa=6206.0).valve_tests[SIGNATURE]
    assert worn["status"] == "completed"
    assert worn["baseline"]["source"] == "stored"
    assert worn["figures"]["friction_mean_to_baseline_ratio"] > 1.6
    assert any("maintenance required" in f and "friction_mean_nm" in f for f in worn["findings"])
    # the nominal plant against its own baseline: nothing to report
    again = signature(6206.0, 1.0, base_kpa=6206.0).valve_tests[SIGNATURE]
    assert again["findings"] == [] and again["figures"]["friction_mean_to_baseline_ratio"] == pytest.approx(1.0, abs=0.05)


def test_baseline_taken_at_another_pressure_still_compares():
    """A Δp-0 baseline judges a full-Δp run through the nominal friction schedule."""
    res = signature(6206.0, 1.0, base_kpa=0.0).valve_tests[SIGNATURE]
    assert res["findings"] == [], res["findings"]


def test_signature_refused_with_test_mode_off_and_loop_unchanged():
    doc = signature_scenario(0.0, duration_s=3.0, controller={"tests.enable": False})
    result = run(doc)
    assert result.valve_tests == {}
    assert len(result.valve_test_refusals) == 1 and "test mode is off" in result.valve_test_refusals[0]
    # the refused request left the loop alone: identical to the run without any test event
    plain = run(dict(doc, events=[]))
    assert (result.log == plain.log).all()


def test_signature_aborted_by_a_new_demand_hands_back():
    doc = signature_scenario(0.0, duration_s=6.0)
    doc["demand"] = {"type": "step", "initial": 20, "final": 30, "at_s": 3.0}
    result = run(doc)
    res = result.valve_tests[SIGNATURE]
    assert res["status"] == "aborted" and "demand moved" in res["reason"]
    position = result.column("position_rad")[-1] / result.stroke_rad * 100.0
    assert position == pytest.approx(30.0, abs=0.3)          # the operator's demand, followed


def test_signature_aborted_by_a_fault():
    doc = signature_scenario(0.0, events=((1.0, "signature_test"), (2.0, "trip")), duration_s=2.5)
    res = run(doc).valve_tests[SIGNATURE]
    assert res["status"] == "aborted" and "fault" in res["reason"]


# ------------------------------------------------------------------ partial stroke
def partial_scenario(events, demand=None, duration_s=9.0) -> dict:
    return {"name": "partial_stroke", "description": "test", "duration_s": duration_s,
            "pressure_differential_kpa": 6206.0, "initial_percent": 50.0,
            "demand": demand or {"type": "constant", "percent": 50.0},
            "events": [{"at_s": at, "action": action} for at, action in events]}


@functools.cache
def nominal_partial_stroke():
    """The nominal partial-stroke run (two tests read it; simulated once)."""
    return _result(*_PARTIAL)


def test_partial_stroke_nominal_passes_and_friction_x2_is_flagged():
    nominal = nominal_partial_stroke()
    base = nominal.valve_tests[PARTIAL_STROKE]
    assert base["status"] == "completed", base["reason"]
    figs = base["figures"]
    assert figs["travel_pct"] == pytest.approx(10.0)
    assert 0.0 < figs["travel_time_out_s"] < 2.0
    assert figs["friction_mean_nm"] == pytest.approx(true_friction_nm(6206.0), rel=0.15)
    assert figs["breakaway_nm"] > 0.9 * true_friction_nm(6206.0)
    again = _result("partial", 0.0, 1.0, _PARTIAL).valve_tests[PARTIAL_STROKE]
    assert again["findings"] == []
    worn = _result("partial", 0.0, 2.0, _PARTIAL).valve_tests[PARTIAL_STROKE]
    assert worn["status"] == "completed"
    assert any("maintenance required" in f for f in worn["findings"])
    assert worn["figures"]["friction_mean_to_baseline_ratio"] > 1.6


def test_partial_stroke_returns_the_valve_to_its_start():
    res = nominal_partial_stroke().valve_tests[PARTIAL_STROKE]
    assert abs(res["figures"]["return_error_pct"]) < 0.5
    assert res["figures"]["travel_time_back_s"] < 2.0


def test_the_fine_stage_stands_aside_while_a_valve_test_measures():
    """observer_fp: the fine stage's preloads and pulses add torque the position loop does not;
    a valve test reads friction from the drive torque, so the stage must not act while a test
    owns the demand (acting on the partial stroke's rests it read the breakaway back 10.5 vs
    6.0 N*m).  It stops when the test starts (the main law takes the plateau over), never
    engages during it, and finishes the operator's plateau after it (the test's return leaves
    the valve ~0.2-0.3 % off; with its breakaway watch cleared the stage waited for good).
    (Plateau 49.8 %: at 50.3 % the return ends within the stage's tolerance, 0.025 %, since the
    main law's hold is handed the plateau back uncocked when the test's ramp starts, task h19r; at
    50.2 % too (0.02 %) once the stage had put the valve on target before the test, task h20p --
    from 49.8 % the return leaves 0.36 %.)"""
    from fuel_valve_plant.physics.plant import Plant
    from test_param_swap import loop
    from fuel_valve_control.core.fine_positioning import IDLE
    plant = Plant(load_plant_params(overrides={"pressure_sensor.noise_kpa": 0.0}))
    driver = ValveDriver(load_controller_params(overrides={"mode": "observer_fp"}))
    tests = ValveTests(driver)
    law = driver.controller.law
    log = []                          # per period, after the step: (t, stage in charge, test running)

    def each(k, t):
        if k:
            log.append((t, law.fine.phase != IDLE, tests.running is not None))
        if k == 2500:
            assert tests.start(PARTIAL_STROKE)[0]
    valve = loop(driver, plant, 0.0, 9000, lambda t: 50.0 if t < 1.0 else 49.8, each)
    res = tests.last_result(PARTIAL_STROKE)
    assert res["status"] == "completed", res["reason"]
    assert any(active for t, active, running in log if not running and t < 2.5)     # it had the plateau
    assert not any(active for t, active, running in log if running)
    after = [t for t, active, running in log if active and not running and t > 2.5]
    assert after, "the stage never engaged after the test"
    end = 2.5 + res["figures"]["duration_s"]
    left = valve[int(round(end / driver.period))] - 49.8
    assert abs(valve[-1] - 49.8) < abs(left), (left, valve[-1] - 49.8)


def test_plain_reversing_ramp_ends_at_the_demand():
    """The loop alone (no valve test) after a closing then opening ramp of 10 %/s at max Δp:
    the valve ends at the demand.  It stopped 1.7 % short (48.32 %) when the breakaway-jump
    learner read the valve's travel along the ramp as a jump and froze the integrator."""
    ramp = {"type": "points", "points": [[0.0, 50.0], [0.5, 50.0], [1.5, 40.0], [2.0, 40.0], [3.0, 50.0]]}
    result = run(partial_scenario([], demand=ramp, duration_s=4.5))
    stroke = result.stroke_rad
    position = result.column("position_rad")
    t = result.column("t")
    at_40 = position[np.searchsorted(t, 1.95)] / stroke * 100.0
    final = position[-1] / stroke * 100.0
    assert abs(at_40 - 40.0) < 0.5, at_40
    assert abs(final - 50.0) < 0.5, final


def test_partial_stroke_refused_while_the_demand_changes():
    ramp = {"type": "ramp", "initial": 50, "final": 52, "start_s": 1.0, "duration_s": 2.0}
    result = run(partial_scenario([(2.5, "partial_stroke_test")], demand=ramp, duration_s=3.0))
    assert result.valve_tests == {}
    assert "demand is changing" in result.valve_test_refusals[0]


def test_partial_stroke_refused_with_a_fault_active():
    result = run(partial_scenario([(1.0, "trip"), (2.5, "partial_stroke_test")], duration_s=3.0))
    assert result.valve_tests == {}
    assert "a fault is active" in result.valve_test_refusals[0]


def test_partial_stroke_refused_beyond_the_tolerated_travel_and_time():
    driver = ValveDriver(load_controller_params(overrides={"tests.partial.fraction_pct": 20.0}))
    tests = ValveTests(driver)
    _settle(driver)
    ok, message = tests.start(PARTIAL_STROKE)
    assert not ok and "max_travel_pct" in message
    driver.set_params({"tests.partial.fraction_pct": 10.0, "tests.partial.rate_pct_s": 1.0})
    ok, message = tests.start(PARTIAL_STROKE)
    assert not ok and "max_time_s" in message
    driver.set_params({"tests.partial.rate_pct_s": 10.0})
    ok, message = tests.start(PARTIAL_STROKE)
    assert ok, message
    assert tests.running == PARTIAL_STROKE
    ok, message = tests.start(SIGNATURE)
    assert not ok and "running already" in message


def _settle(driver: ValveDriver, seconds: float = 2.5) -> None:
    """A driver on a steady demand with a valve resting at it (measurements, no plant)."""
    period, angle = driver.period, 0.5 * driver.stroke
    for k in range(int(seconds / period)):
        t = k * period
        driver.demand_percent(t, 50.0)
        driver.pressure_differential(t, 0.0)
        driver.resolver(t, angle * driver.n, angle)
        driver.step(t)
    assert driver.last.state == "running"


def test_signature_refused_while_hunting_or_tracking_error():
    driver = ValveDriver(load_controller_params(overrides={"tests.enable": True}))
    tests = ValveTests(driver)
    _settle(driver)
    assert tests.start(SIGNATURE)[0]            # healthy: accepted
    driver2 = ValveDriver(load_controller_params(overrides={"tests.enable": True}))
    tests2 = ValveTests(driver2)
    period, mid = driver2.period, 0.5 * driver2.stroke
    for k in range(int(2.5 / period)):          # the valve swings +-5 mrad about the demand
        t = k * period
        angle = mid + 0.005 * math.sin(2 * math.pi * 5.0 * t)
        driver2.demand_percent(t, 50.0)
        driver2.pressure_differential(t, 0.0)
        driver2.resolver(t, angle * driver2.n, angle)
        driver2.step(t)
    ok, message = tests2.start(SIGNATURE)
    assert not ok and "hunting" in message
    driver3 = ValveDriver(load_controller_params(overrides={"tests.enable": True}))
    tests3 = ValveTests(driver3)
    _settle(driver3)
    for k in range(50):                          # 10 % demanded, the valve has not moved yet
        t = 2.5 + k * driver3.period
        driver3.demand_percent(t, 60.0)
        driver3.resolver(t, mid * driver3.n, mid)
        driver3.step(t)
    ok, message = tests3.start(SIGNATURE)
    assert not ok and "tracking error" in message


def test_report_recognises_valve_tests_and_plots_them_next_to_the_baseline(tmp_path, capsys):
    """``fuel_valve_report``: results recorded on ``valve_test`` in a bag, or in a JSON file."""
    import json
    from pathlib import Path

    from fuel_valve_control.tools import report
    from fuel_valve_control.tools.bag_io import Bag

    base = signature(6206.0).valve_tests[SIGNATURE]
    worn = signature(6206.0, 2.0, base_kpa=6206.0).valve_tests[SIGNATURE]
    bag = Bag(Path(tmp_path / "bag"), "mcap", {}, {}, {},
              texts={"/fuel_valve/valve_test": [json.dumps(base), json.dumps(worn)], "/other": ["not json"]})
    found = report.valve_test_results(bag)
    assert [r["figures"]["friction_mean_nm"] for r in found] == [base["figures"]["friction_mean_nm"],
                                                                 worn["figures"]["friction_mean_nm"]]
    written = report.plot_valve_tests(found, tmp_path / "run.png")       # baseline: the bag's first run
    assert written == [str(tmp_path / "run_signature.png")] and Path(written[0]).stat().st_size > 10_000
    # as fuel_valve_sim --json writes it: NaN figures (a step that never settled) become null
    written_by_sim = dict(worn, figures=dict(worn["figures"], step_2pct_up_settling_time_s=None))
    (tmp_path / "worn.json").write_text(json.dumps({"valve_tests": {SIGNATURE: written_by_sim}}))
    (tmp_path / "base.json").write_text(json.dumps(base))
    assert report.main([str(tmp_path / "worn.json"), "--baseline", str(tmp_path / "base.json"),
                        "--plot", str(tmp_path / "offline.png")]) == 0
    out = capsys.readouterr().out
    assert "maintenance required" in out and (tmp_path / "offline_signature.png").is_file()
    (tmp_path / "empty.json").write_text("{}")
    assert report.main([str(tmp_path / "empty.json")]) == 2


def test_every_runtime_tests_parameter_is_read_by_the_valve_tests():
    """The ``tests.*`` run-time keys (test_runtime_params leaves them to this test): a short
    signature and a partial stroke run on the plant read each one."""
    from collections.abc import Mapping

    from fuel_valve_plant.physics.plant import Plant

    from fuel_valve_control.core.params import CONTROLLER_SPEC

    class Reads(Mapping):
        def __init__(self, values):
            self.values, self.read = values, set()

        def __getitem__(self, name):
            self.read.add(name)
            return self.values[name]

        def __iter__(self):
            return iter(self.values)

        def __len__(self):
            return len(self.values)

    plant = Plant(load_plant_params(overrides={"pressure_differential_kpa": 0.0, "initial_position_rad": 0.3}))
    ps = load_controller_params(overrides={"tests.enable": True, "tests.signature.start_pct": 30.0,
                                           "tests.signature.end_pct": 34.0, "tests.signature.steps_pct": [1.0],
                                           "tests.signature.dwell_s": 0.2, "tests.signature.step_time_s": 0.2,
                                           "tests.partial.fraction_pct": 2.0, "tests.partial.dwell_s": 0.2})
    driver = ValveDriver(ps)
    tests = ValveTests(driver)
    reads = Reads(driver.ps)
    driver.ps = reads
    t, period = 0.0, driver.period

    def loop(seconds):
        nonlocal t
        for _ in range(int(round(seconds / period))):
            driver.demand_percent(t, 30.0)
            driver.pressure_differential(t, 0.0)
            s = plant.resolver()
            driver.resolver(s.stamp_s, s.motor_rad, s.valve_rad)
            out = driver.step(t)
            plant.set_command(out.current_a, out.enable)
            plant.advance(period)
            t += period

    loop(2.5)
    for name in (SIGNATURE, PARTIAL_STROKE):
        assert tests.start(name)[0], tests.refusals
        while tests.running:
            loop(0.1)
        assert tests.last_result(name)["status"] == "completed", tests.last_result(name)["reason"]
        loop(2.2)
    for name in (SIGNATURE, PARTIAL_STROKE):         # the second runs are judged: degradation_ratio
        tests.start(name)
        while tests.running:
            loop(0.1)
        loop(2.2)
    wanted = {p.name for p in CONTROLLER_SPEC if p.runtime and p.name.startswith("tests.")}
    assert wanted - reads.read == set()


def test_valve_tests_feed_ne107_function_check_and_maintenance_required():
    """The wiring into the NE107 status (core/health.py): a running test is a function check,
    a test's degradation finding raises maintenance required until a clean run clears it."""
    from fuel_valve_control.core import health
    driver = ValveDriver(load_controller_params(overrides={"tests.enable": True}))
    tests = ValveTests(driver)
    vh = driver.valve_health
    tests.report_health(vh)
    assert vh.test_running is None and not any(k.startswith("valve_test:") for k in vh.maintenance)
    tests._pending = PARTIAL_STROKE              # accepted, starts at the next period
    tests.report_health(vh)
    status = driver.ne107()
    assert status.category == health.FUNCTION_CHECK, status
    assert "partial_stroke" in vh.test_running
    tests._pending = None
    tests.findings_by_test[SIGNATURE] = ["friction 2.06 x baseline"]
    tests.report_health(vh)
    assert vh.test_running is None
    assert driver.ne107().category == health.MAINTENANCE and "2.06" in vh.maintenance[f"valve_test:{SIGNATURE}"]
    tests.findings_by_test[SIGNATURE] = []       # a later clean run
    tests.report_health(vh)
    assert f"valve_test:{SIGNATURE}" not in vh.maintenance

"""Valve health without ROS (issue 12): the NAMUR NE107 mapping (each cause -> its category,
priority when several), the duty counters on a synthetic trajectory, the learned-state file
(round trip, corrupt / missing / wrong version), and the driver's lifecycle inhibit.

The driver tests reuse ``test_driver.Rig``: a valve that sits where the test puts it."""
import json
import math

import pytest

from fuel_valve_control.common.contract import PRESSURE_MAX_KPA, STROKE_RAD
from fuel_valve_control.core import health as H
from fuel_valve_control.core.fine_positioning import FineLearner
from fuel_valve_control.core.params import CONTROLLER_SPEC

from test_driver import Rig, T

PS = CONTROLLER_SPEC.defaults()
HYST = PS["health.reversal_hysteresis_rad"]


def _health(**params):
    return H.ValveHealth(PS.replace(params))


def _still(h, seconds, valve=0.5, demand=0.5, dp=0.0, t0=0.0, driving=True, trend=None):
    """``seconds`` of periods with the valve at ``valve`` and the demand at ``demand`` (rad)."""
    n = int(round(seconds / T))
    for k in range(1, n + 1):
        h.update(t0 + k * T, T, valve, demand, dp, driving, None if trend is None else (lambda: trend))
    return t0 + n * T


# ------------------------------------------------------------------ NE107: each cause
def _cause(name):
    """A health object with exactly one cause ``name``; returns (health, faults, warnings, t)."""
    h, faults, warnings = _health(), {}, {}
    t = _still(h, 0.1)
    if name == "fault":
        faults = {"resolver_stale": "no resolver sample for 30 ms"}
    elif name == "trip":
        faults = {H.MANUAL_TRIP: "trip requested through ~/trip"}
    elif name == "lifecycle":
        h.set_lifecycle_state("inactive")
    elif name == "test":
        h.set_test_running(True, "signature test")
    elif name == "warning":
        warnings = {"pressure_differential": "no pressure differential reading received"}
    elif name == "tracking":
        t = _still(h, PS["health.tracking_error_time_s"] + 0.05, valve=0.5,
                   demand=0.5 + 2 * PS["health.tracking_error_rad"], t0=t)
    elif name == "hunting":
        amp = 3 * HYST
        for k in range(PS["health.hunting_reversals"] + 1):       # a limit cycle at a steady demand
            t = _still(h, 0.05, valve=0.5 + (amp if k % 2 else -amp), demand=0.5, t0=t)
    elif name == "friction":
        h.set_friction_baseline(1.0)
        t = _still(h, 0.01, trend=1.0 + 2 * PS["health.friction_band"], t0=t)
    elif name == "breakaway":
        h.observe_breakaway(5.0)
        h.observe_breakaway(5.0 + 2 * PS["health.breakaway_rise_nm"])
    elif name == "travel":
        h.counters.travel_rad = PS["health.travel_limit_rad"] + 1.0
    elif name == "reversals":
        h.counters.reversals = PS["health.reversal_limit"] + 1
    elif name == "external":
        h.raise_maintenance("partial_stroke", "travel time 20 % above baseline")
    return h, faults, warnings, t


CAUSES = [("fault", H.FAILURE, "fault:resolver_stale"), ("trip", H.FUNCTION_CHECK, "fault:commanded_trip"),
          ("lifecycle", H.FUNCTION_CHECK, "lifecycle"), ("test", H.FUNCTION_CHECK, "test"),
          ("warning", H.OUT_OF_SPEC, "warning:pressure_differential"), ("tracking", H.OUT_OF_SPEC, "tracking"),
          ("hunting", H.OUT_OF_SPEC, "hunting"), ("friction", H.MAINTENANCE, "friction"),
          ("breakaway", H.MAINTENANCE, "breakaway"), ("travel", H.MAINTENANCE, "travel"),
          ("reversals", H.MAINTENANCE, "reversals"), ("external", H.MAINTENANCE, "partial_stroke")]


@pytest.mark.parametrize("name, category, key", CAUSES)
def test_each_cause_gives_its_category_alone(name, category, key):
    h, faults, warnings, t = _cause(name)
    status = h.assess(t, faults, warnings)
    assert status.category == category, status.causes
    assert list(status.causes) == [category] and list(status.causes[category]) == [key], status.causes
    assert status.level == {H.FAILURE: 2}.get(category, 1)
    assert key in status.summary()


def test_nothing_wrong_is_good_and_ok():
    h, _, _, t = _cause("none")
    status = h.assess(t, {}, {})
    assert (status.category, status.level, status.letter, status.causes) == (H.GOOD, 0, "N", {})


def test_cleared_causes_return_to_good():
    h = _health()
    h.raise_maintenance("x", "y")
    h.set_test_running(True)
    h.set_lifecycle_state("inactive")
    assert h.assess(0.0, {}, {}).category == H.FUNCTION_CHECK
    h.set_test_running(False)
    h.set_lifecycle_state("active")
    assert h.assess(0.0, {}, {}).category == H.MAINTENANCE
    h.clear_maintenance("x")
    assert h.assess(0.0, {}, {}).category == H.GOOD


def test_priority_is_ne107_order_and_every_cause_is_listed():
    h, _, _, t = _cause("hunting")
    h.raise_maintenance("wear", "worn packing")
    h.set_test_running(True)
    faults = {"tracking_error": "stuck", H.MANUAL_TRIP: "tripped"}
    warnings = {"demand_range": "clamped"}
    got = h.assess(t, faults, warnings)
    assert got.category == H.FAILURE
    assert set(got.causes) == {H.FAILURE, H.FUNCTION_CHECK, H.OUT_OF_SPEC, H.MAINTENANCE}
    assert set(got.causes[H.FUNCTION_CHECK]) == {"test", "fault:commanded_trip"}
    assert set(got.causes[H.OUT_OF_SPEC]) == {"hunting", "warning:demand_range"}
    # take the causes away from the top down: the next category in NE107's order shows
    assert h.assess(t, {H.MANUAL_TRIP: "tripped"}, warnings).category == H.FUNCTION_CHECK
    h.set_test_running(False)
    assert h.assess(t, {}, warnings).category == H.OUT_OF_SPEC
    assert h.assess(t + 10.0, {}, {}).category == H.MAINTENANCE      # hunting window passed


def test_level_mapping_and_letters_cover_every_category():
    assert set(H.NE107_DIAGNOSTIC_LEVEL) == set(H.NE107_LETTER) == set(H.NE107_PRIORITY)
    assert [H.NE107_DIAGNOSTIC_LEVEL[c] for c in H.NE107_PRIORITY] == [2, 1, 1, 1, 0]
    assert "".join(H.NE107_LETTER[c] for c in H.NE107_PRIORITY) == "FCSMN"


def test_tracking_and_hunting_need_their_time_and_a_steady_demand():
    h = _health()
    limit = PS["health.tracking_error_time_s"]
    t = _still(h, 0.5 * limit, demand=0.5 + 2 * PS["health.tracking_error_rad"])
    assert "tracking" not in h.assess(t, {}, {}).causes.get(H.OUT_OF_SPEC, {})     # a move, not yet
    t = _still(h, limit, demand=0.5 + 2 * PS["health.tracking_error_rad"], t0=t, driving=False)
    assert h.assess(t, {}, {}).category == H.GOOD                                   # drive off: not assessed
    # reversals that follow a changing demand are not hunting
    h2, t = _health(), 0.0
    for k in range(2 * PS["health.hunting_reversals"]):
        x = 0.5 + (0.01 if k % 2 else -0.01)
        t = _still(h2, 0.05, valve=x, demand=x, t0=t)
    assert h2.counters.reversals >= PS["health.hunting_reversals"]
    assert h2.assess(t, {}, {}).category == H.GOOD


def test_friction_baseline_is_learned_after_the_driven_time_then_compared():
    after = 0.2
    h = _health(**{"health.baseline_after_s": after, "health.trend_time_constant_s": 0.01})
    t = _still(h, 0.5 * after, trend=1.2)
    assert h.friction_baseline is None
    t = _still(h, after, trend=1.2, t0=t)
    assert h.friction_baseline == pytest.approx(1.2)
    assert h.assess(t, {}, {}).category == H.GOOD
    t = _still(h, 0.2, trend=1.2 * (1 + 2 * PS["health.friction_band"]), t0=t)
    assert "friction" in h.assess(t, {}, {}).causes[H.MAINTENANCE]


# ------------------------------------------------------------------ counters
def test_counters_on_a_synthetic_trajectory_are_exact():
    """0.2 -> 0.7 -> 0.4 -> 0.9 -> 0.9 rad in straight ramps, with noise below the hysteresis
    riding on it: travel 0.5 + 0.3 + 0.5 = 1.3 rad, 2 reversals; Δp above the threshold for
    exactly the second half of the run."""
    c = H.ValveCounters(HYST, 5000.0)
    points = [0.2, 0.7, 0.4, 0.9, 0.9]
    n_seg, k, t = 500, 0, 0.0
    xs = []
    for a, b in zip(points, points[1:]):
        for i in range(n_seg):
            xs.append(a + (b - a) * i / n_seg)
    xs.append(points[-1])
    noise = 0.4 * HYST
    total = len(xs)
    for k, x in enumerate(xs):
        wiggle = noise * (1 if k % 2 else -1) if 0 < k < total - 1 else 0.0
        dp = 6000.0 if k >= total // 2 else 1000.0
        t += T
        c.update(t, x + wiggle, dp, T)
    # the noise adds at most its peak-to-peak at each extreme, the ends are exact
    assert c.reversals == 2
    assert c.travel_rad == pytest.approx(1.3, abs=4 * 2 * noise)
    assert c.high_dp_s == pytest.approx((total - total // 2) * T, rel=1e-12)
    # and without noise it is exact to rounding
    c2 = H.ValveCounters(HYST, 5000.0)
    for k, x in enumerate(xs):
        c2.update(k * T, x, 0.0, T)
    assert c2.reversals == 2 and c2.travel_rad == pytest.approx(1.3, abs=1e-9) and c2.high_dp_s == 0.0


def test_noise_at_rest_counts_nothing():
    c = H.ValveCounters(HYST, 5000.0)
    for k in range(5000):
        c.update(k * T, 0.3 + 0.9 * HYST * math.sin(0.7 * k), None, T)
    assert c.reversals == 0 and c.travel_rad < 2 * HYST


# ------------------------------------------------------------------ persistence
def _learned():
    h = _health()
    _still(h, 0.01)
    h.counters.travel_rad, h.counters.reversals, h.counters.high_dp_s = 123.25, 4567, 89.5
    h.set_friction_baseline(1.35)
    h.observe_breakaway(7.5)
    learner = FineLearner(PS["fine.pressure_bands"], PS["fine.learn_limit_rad"])
    learner.set("breakaway", 1, 2, 0.0125)
    learner.set("equilibrium", -1, 0, -0.004)
    return h, learner


def test_learned_state_round_trip(tmp_path):
    path = tmp_path / "valve.json"
    h, learner = _learned()
    H.save_state(path, h, learner)
    doc = json.loads(path.read_text())
    assert doc["format"] == H.STATE_FORMAT and doc["version"] == H.STATE_VERSION
    h2, l2 = _health(), FineLearner(PS["fine.pressure_bands"], PS["fine.learn_limit_rad"])
    ok, message = H.load_state(path, h2, l2)
    assert ok, message
    assert h2.counters.to_dict() == h.counters.to_dict() == {"travel_rad": 123.25, "reversals": 4567,
                                                             "high_dp_time_s": 89.5}
    assert (h2.friction_baseline, h2.breakaway_baseline_nm) == (1.35, 7.5)
    assert l2.to_dict() == learner.to_dict() and l2.breakaway[1][2] == 0.0125
    # counting goes on from the loaded values
    _still(h2, 0.01)
    h2.counters.update(1.0, 0.9, 0.0, T)
    assert h2.counters.travel_rad > 123.25


@pytest.mark.parametrize("content, why", [
    (None, "not found"),
    ("{not json", "JSONDecodeError"),
    ('["a list"]', "not a fuel_valve.learned_state"),
    (json.dumps({"format": H.STATE_FORMAT, "version": 99}), "version 99"),
    (json.dumps({"format": H.STATE_FORMAT, "version": H.STATE_VERSION, "counters": {"travel_rad": "nan",
     "reversals": 1, "high_dp_time_s": 0}, "baselines": {}}), "finite"),
    (json.dumps({"format": H.STATE_FORMAT, "version": H.STATE_VERSION, "counters": {"travel_rad": 1.0}}),
     "KeyError"),
    (json.dumps({"format": H.STATE_FORMAT, "version": H.STATE_VERSION, "counters": {"travel_rad": 1.0,
     "reversals": 2, "high_dp_time_s": 0}, "baselines": {}, "fine_learner": {"version": 1, "bands": 3}}),
     "bands"),
])
def test_missing_or_corrupt_file_says_why_and_starts_from_zero(tmp_path, content, why):
    path = tmp_path / "valve.json"
    if content is not None:
        path.write_text(content)
    h, learner = _health(), FineLearner(PS["fine.pressure_bands"], PS["fine.learn_limit_rad"])
    before = learner.to_dict()
    ok, message = H.load_state(path, h, learner)
    assert not ok and why in message and str(path) in message and "start from zero" in message
    assert h.counters.to_dict() == {"travel_rad": 0.0, "reversals": 0, "high_dp_time_s": 0.0}
    assert h.friction_baseline is None and learner.to_dict() == before


def test_save_replaces_the_file_atomically(tmp_path):
    path = tmp_path / "valve.json"
    path.write_text("old")
    h, learner = _learned()
    H.save_state(path, h, learner)
    assert json.loads(path.read_text())["counters"]["reversals"] == 4567
    assert [p.name for p in tmp_path.iterdir()] == ["valve.json"]


# ------------------------------------------------------------------ the driver
def test_inhibited_driver_never_enables_not_even_after_a_reset():
    rig = Rig()
    rig.healthy()
    rig.d.set_inhibited(True)
    out = rig.run(0.05)
    assert (out.enable, out.current_a, out.state) == (False, 0.0, "inactive")
    rig.d.trip("test")
    rig.run(0.01)
    ok, _ = rig.d.reset()
    assert ok
    out = rig.run(0.2)
    assert (out.enable, out.current_a, out.state) == (False, 0.0, "inactive")
    rig.d.set_inhibited(False)
    out = rig.run(0.05)
    assert out.enable and out.state == "running"


def test_driver_reports_ne107_and_counters_on_its_health():
    rig = Rig()
    rig.healthy()
    values = rig.d.health().values
    assert values["ne107"] == H.GOOD and values["ne107_level"] == 0
    rig.d.valve_health.set_lifecycle_state("inactive")
    rig.d.set_inhibited(True)
    rig.run(0.01)
    values = rig.d.health().values
    assert values["ne107"] == H.FUNCTION_CHECK and "lifecycle" in values["ne107_causes"]
    # travel counted from the resolver samples; Δp at max counts as high Δp time
    rig.valve = 0.4 * STROKE_RAD + 0.05
    rig.run(0.1)
    values = rig.d.health().values
    assert values["travel_total_rad"] == pytest.approx(0.05, abs=1e-9)
    assert rig.pressure == PRESSURE_MAX_KPA and values["high_dp_time_s"] > 0.1


def test_driver_runtime_change_of_a_health_parameter_takes_effect():
    rig = Rig()
    rig.healthy()
    rig.d.set_params({"health.travel_limit_rad": 0.01})
    rig.valve += 0.05
    rig.run(0.01)
    assert rig.d.ne107().category == H.MAINTENANCE and "travel" in rig.d.ne107().causes[H.MAINTENANCE]

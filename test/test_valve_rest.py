"""The valve's rest on a noisy resolver (``fine.rest_noise_rate``, task s35, docs §119): the stage's sample-to-sample
rest test (a step under half the tolerance) reads 0.5-1 count rms of resolver noise as motion, so the stage seldom
engaged and read the main law's breakaways from a stale rest (nominal box seed 1000: 14 / 43 / 137 / 200 plateaus
> 8e-4 rad of 480 at 0.25 / 0.5 / 0.8 / 1 count).  :class:`~fuel_valve_control.core.valve_rest.ValveRest` reads the
noise from the readings and, where they are noisy, tests rest on two windows' means and reads a slide's twist at its
onset."""
from __future__ import annotations

import numpy as np
import pytest

from fuel_valve_control.common.contract import RESOLVER_COUNT_RAD as Q
from fuel_valve_control.core import valve_rest as vr
from fuel_valve_control.core.params import CONTROLLER_SPEC

PERIOD = 1e-3
STEP = 1.5 * Q                   # half the default 3-count tolerance


def _readings(true, sigma_counts, seed=0):
    """Quantised resolver readings (rad) of the true angles ``true`` (rad) with white noise of ``sigma_counts``."""
    rng = np.random.default_rng(seed)
    return np.round((np.asarray(true) + sigma_counts * Q * rng.standard_normal(len(true))) / Q) * Q


RATE = 0.015


def _fed(readings, noisy_rate=RATE, twist=None, held=True):
    rest = vr.ValveRest(10, STEP, noisy_rate, PERIOD)
    tw = np.zeros(len(readings)) if twist is None else twist
    for v, t in zip(readings, tw):
        rest.update(float(v), float(t), held)
    return rest


@pytest.mark.parametrize("sigma", [0.6, 1.0, 1.5])
def test_the_noise_is_read_from_a_held_valves_readings(sigma):
    rest = _fed(_readings(np.full(2000, 0.3 + 0.37 * Q), sigma))
    if sigma <= 1.0:
        assert rest.noise_counts == pytest.approx(sigma, rel=0.15)
    else:
        assert 1.0 < rest.noise_counts < sigma        # the clip at D2_CLIP counts reads a larger noise low
    assert rest.noisy


def test_a_reading_dithering_across_a_count_boundary_is_not_noisy():
    """0.25 count rms on a valve resting on a count boundary toggles between two counts: its second differences read
    ~0.5 count, but no step fails the sample-to-sample test -- which is sound there, and stays in force."""
    rest = _fed(_readings(np.full(2000, 0.3 + 0.5 * Q), 0.25))
    assert rest.noise_counts > 0.4
    assert rest.step_rate < 0.1 * RATE
    assert not rest.noisy


def test_a_creeping_valve_feeds_no_noise_estimate():
    """A valve creeping under the hold (2 counts a period) fails the sample-to-sample test at every step, but the
    windows' means show it moving: none of it is read as noise (the `startup` scenario's first 0.14 s had read 26 %
    of failing steps on the nominal resolver)."""
    rest = _fed(_readings(0.3 + 2 * Q * np.arange(1000), 0.25))
    assert rest.step_rate == 0.0 and not rest.noisy


def test_nothing_is_noisy_before_the_estimate_is_trusted_or_with_the_option_off():
    readings = _readings(np.full(2000, 0.3), 1.0)
    assert not _fed(readings[: int(vr.TRUST_S / PERIOD) - 5]).noisy
    assert _fed(readings[: int(vr.TRUST_S / PERIOD) + 40]).noisy
    assert not _fed(readings, noisy_rate=0.0).noisy
    assert not _fed(readings, held=False).noisy and _fed(readings, held=False).noise_counts == 0.0


def test_rest_by_means_holds_through_noise_and_not_through_a_creep():
    still = _fed(_readings(np.full(300, 0.3), 1.0))
    assert still.at_rest()
    # the sample-to-sample test on the same readings fails every few periods
    r = _readings(np.full(300, 0.3), 1.0)
    assert np.mean(np.abs(np.diff(r)) >= STEP) > 0.2
    creep = 0.3 + 0.05 * PERIOD * np.arange(300)        # 0.05 rad/s: 0.5 count a period, which that test passes
    assert not _fed(_readings(creep, 1.0)).at_rest()
    assert np.all(np.abs(np.diff(np.round(creep / Q))) < 1.5)


def test_a_slides_twist_is_read_at_its_onset():
    """The valve sits still while the twist ramps toward its level, then slides at 625 rad/s^2 while the gear output
    drives the twist on past the level (a main-law move): the twist read is the onset's, not the last rest period's
    or the furthest."""
    n_still, n_slide = 300, 8
    t = np.arange(n_slide + 1) * PERIOD
    valve = np.concatenate([np.full(n_still, 0.3), 0.3 + 0.5 * 625.0 * t[1:] ** 2])
    level = 0.0120
    twist = np.concatenate([np.linspace(0.0100, level, n_still), level + 0.4 * np.arange(1, n_slide + 1) * PERIOD])
    readings = _readings(valve, 1.0, seed=3)
    rest = _fed(readings, twist=twist)
    assert rest.noisy
    onset = rest.onset_twist(1, 0.3)
    assert abs(onset - level) < 0.1 * 2.3e-3                  # within a tenth of the nominal static band
    assert twist[-1] - level > 2e-3                            # ... where the last twist lay 2.8e-3 past it


def test_the_stage_reads_a_noisy_valve_through_a_short_mean():
    readings = _readings(np.full(400, 0.3), 1.0, seed=5)
    rest = _fed(readings)
    assert vr.SMOOTH_PERIODS == 4
    assert rest.smoothed() == pytest.approx(np.mean(readings[-4:]), abs=1e-15)
    assert _fed(readings[:2]).smoothed() == pytest.approx(np.mean(readings[:2]), abs=1e-15)


def test_a_rearm_keeps_the_noise_read_and_a_learning_reset_forgets_it():
    rest = _fed(_readings(np.full(500, 0.3), 1.0))
    n, rate = rest.noise_counts, rest.step_rate
    rest.reset()
    assert rest.noisy and (rest.noise_counts, rest.step_rate) == (n, rate)
    assert not rest.at_rest()                         # ... but its windows start afresh
    rest.forget()
    assert not rest.noisy and rest.noise_counts == 0.0


def test_the_option_is_on_by_default_and_reported():
    assert CONTROLLER_SPEC.defaults()["fine.rest_noise_rate"] == RATE
    from fuel_valve_control.core.position_controller import PositionController
    pc = PositionController(CONTROLLER_SPEC.defaults().replace({"mode": "observer_fp"}))
    assert pc.law.fine.valve_rest.noisy_rate == RATE
    health = pc.law.fine.health()
    assert health["valve_noise_counts"] == 0.0 and health["valve_rest_step_rate"] == 0.0


@pytest.mark.parametrize("seed", [1007, 1017])
def test_a_noisy_resolver_no_longer_keeps_the_stage_out(robustness_bench, seed):
    """Nominal box runs with the valve resolver's noise at 1 count rms: without the option most of their plateaus end
    at the main law's deadband (the stage seldom sees a rest, and reads the main law's breakaways from stale rests as a
    misfit of its model); with it they end as on the nominal resolver."""
    case = {**robustness_bench.sample_case(seed, "nominal"), "valve_noise_counts": 1.0}
    off = robustness_bench.run_case((case, None, {"fine.rest_noise_rate": 0.0}))
    on = robustness_bench.run_case((case, None, {}))
    e_off = np.array([p["final_error_rad"] for p in off["plateaus"]])
    e_on = np.array([p["final_error_rad"] for p in on["plateaus"]])
    assert np.sum(e_off > 8e-4) >= 5
    assert np.sum(e_on > 8e-4) <= 2
    assert not on["hunts"] and not on["fault"]


def test_the_nominal_resolver_is_read_as_quiet(robustness_bench):
    """On the nominal box's 0.25-count resolver the sample-to-sample test stays in force (the nominal pools are
    bit-identical with the option, docs §119)."""
    case = robustness_bench.sample_case(1016, "nominal")
    on = robustness_bench.run_case((case, None, {}))
    off = robustness_bench.run_case((case, None, {"fine.rest_noise_rate": 0.0}))
    assert [p["final_error_rad"] for p in on["plateaus"]] == [p["final_error_rad"] for p in off["plateaus"]]


def test_the_campaign_sets_the_valve_resolvers_noise_of_every_run(robustness_bench, tmp_path, capsys):
    out = tmp_path / "noisy.json"
    assert robustness_bench.main(["--runs", "1", "--jobs", "1", "--box", "nominal", "--seed", "1005",
                                  "--valve-noise-counts", "1.0", "--json", str(out)]) == 0
    import json
    doc = json.loads(out.read_text())
    assert doc["valve_noise_counts"] == 1.0 and doc["results"][0]["case"]["valve_noise_counts"] == 1.0
    assert "valve resolver noise 1.0 counts rms" in capsys.readouterr().out
    assert robustness_bench.main(["--runs", "1", "--valve-noise-counts", "-1"]) == 2


def test_a_one_period_window_reads_its_readings():
    """``fine.engage_time_s`` at its least on a slow loop makes a window of one period: two readings are both windows,
    and a second difference needs three."""
    rest = vr.ValveRest(1, STEP, RATE, 2e-3)
    for _ in range(3):
        rest.update(0.3, 0.0, True)
    assert rest.at_rest() and rest.noise_counts == 0.0 and rest.step_rate == 0.0

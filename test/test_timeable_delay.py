"""The stage stays out where its servo has no phase margin with the measured resolver delay (``fine.timeable_delay``,
task s35, docs §119).  The 60 Hz gear-output servo of the 1 kHz loop keeps 33 deg of margin against the period's lag;
the resolver's delay takes ~37 deg per ms more, none is left from ~0.9 ms.  Found once the stage engaged on noisy
resolvers (``fine.rest_noise_rate``): full box seed 3109 (1 ms, 1.2e-3 rad of backlash, 0.96 count rms) -- the
observe servo limit-cycled at +-30 A, threw the landed valve 1.9e-2 rad and the main law's restart hunted."""
from __future__ import annotations

import pytest

from fuel_valve_control.core.params import CONTROLLER_SPEC
from fuel_valve_control.core.position_controller import PositionController


def _fine(**sets):
    return PositionController(CONTROLLER_SPEC.defaults().replace({"mode": "observer_fp", **sets})).law.fine


@pytest.mark.parametrize("delay_s, timeable", [(0.0, True), (5e-5, True), (6e-4, True), (9.5e-4, False),
                                               (1e-3, False)])
def test_the_stage_is_timeable_only_with_phase_margin_left_at_the_told_delay(delay_s, timeable):
    fine = _fine(resolver_delay_s=delay_s)
    assert CONTROLLER_SPEC.defaults()["fine.timeable_delay"] is True
    margin = fine.servo_margin_rad(fine.m.j1, fine.kp, fine.kd, fine.period + delay_s)
    assert (margin > 0.0) == timeable and fine.timeable == timeable
    # without the option the period's lag alone decides, as before
    assert _fine(resolver_delay_s=delay_s, **{"fine.timeable_delay": False}).timeable


def test_a_servo_without_margin_no_longer_throws_a_noisy_delayed_valve(robustness_bench):
    case = robustness_bench.sample_case(3109, "full")
    assert case["resolver_delay_s"] > 9.5e-4
    unguarded = robustness_bench.run_case((case, None, {"fine.timeable_delay": False}))
    assert unguarded["hunts"] and not unguarded["beyond_rating"]
    assert max(p["hunting_amplitude_rad"] for p in unguarded["plateaus"]) > 1e-2
    guarded = robustness_bench.run_case((case, None, {}))
    assert not guarded["hunts"] and not guarded["fault"]

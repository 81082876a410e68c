"""The dissertation's own modes made to work (issue 14, deliverable 5): ``observer_fc``
(Luenberger observer + two Friedland-Park observers, F̂1 + F̂2/N fed forward) and ``kalman_fc``
(steady-state Kalman filter + LQR), measured in the offline simulator at max Δp."""
import functools

import pytest

from fuel_valve_control.core.compensation import Context, FriedlandPark
from fuel_valve_control.core.params import CONTROLLER_SPEC
from fuel_valve_control.core.position_controller import PositionController
from fuel_valve_control.tools import sim
from fuel_valve_control.tools.metrics import RESOLVER_COUNT_RAD


@functools.lru_cache(maxsize=None)
def _metrics(scenario: str, mode: str) -> dict:
    return sim.run(scenario, mode, seed=0).metrics


_OBSERVER_FC_SMALL_STEP = ("observer_fc's 2 % step: the move stops ~8e-3 rad short (the valve sticks as the "
                           "reference decelerates) and, with the Friedland-Park valve term off while holding "
                           "(it made the hold hunt), the integrator and the stuck ramp finish it: overshoot "
                           "22.4/23.5 % (seeds 0/1), settling 0.36 s.  With the term on while holding: 0 % on "
                           "seed 0 but 9.6e-3 rad hunting in load_step and 1.0e-2 rad in startup")
_KALMAN_SMALL_STEP = ("kalman_fc's 2 % step: overshoot 0/11.4/0/0 % (seeds 0-3) but it stops 1.4-2.5e-3 rad off "
                      "(inside its integral deadband, beyond the settling band of 1.75e-3 rad) on 2 of 4 seeds")


@pytest.mark.parametrize("mode", [pytest.param("observer_fc", marks=pytest.mark.xfail(
    strict=True, reason=_OBSERVER_FC_SMALL_STEP)), pytest.param("kalman_fc", marks=pytest.mark.xfail(
        strict=True, reason=_KALMAN_SMALL_STEP))])
def test_small_step_overshoot_and_settling(mode):
    m = _metrics("step_small", mode)
    assert m["overshoot_pct"] <= 10.0
    assert m["peak_current_a"] <= 30.0
    assert m["settling_time_s"] is not None and m["settling_time_s"] <= 0.2


@pytest.mark.parametrize("mode, seed", [("observer_fc", 0), ("observer_fc", 1), ("kalman_fc", 0), ("kalman_fc", 3)])
def test_bandwidth_at_least_10_hz(mode, seed):
    # kalman_fc before the LQR/Kalman redesign: 1.9-20 Hz over seeds 0-3 (a coin flip); seed 3
    # read 7.9 Hz until the observers started with the valve in equilibrium, 20 Hz since
    m = sim.run("sine_sweep", mode, seed=seed).metrics
    assert m["bandwidth_hz"] >= 10.0
    assert m["peak_current_a"] <= 30.0


def test_kalman_fc_stays_off_the_current_limit():
    """The 37 A of kalman_fc came from the LQR weights (a 35 Hz pair, the coupling mode at
    zeta 0.09), not the filter's structure; a soft coupling (K x 0.1) turned it into a 37 A
    oscillation."""
    m = _metrics("large_step", "kalman_fc")
    assert m["peak_current_a"] <= 30.0
    assert CONTROLLER_SPEC.params["lqr.current_a"].default <= 1.0


@pytest.mark.parametrize("seed", [0, 3])
def test_kalman_fc_large_step_overshoot(seed):
    # seeds 0-7 after the redesign: 0.7-0.95 %; before: 0-2.94 % (a coin flip)
    assert sim.run("large_step", "kalman_fc", seed=seed).metrics["overshoot_pct"] <= 1.0


@pytest.mark.parametrize("mode", ["observer", "observer_fc", "fc_gain", "observer_ff"])
def test_no_current_peak_at_start_on_a_soft_coupling(mode):
    """flexible_worst (coupling K x 0.1): the observers start in equilibrium with the measured
    twist and torque; started with zero disturbance states they read the twist as a 10x torque
    and every state-feedback mode hit 36.3 A in its first periods."""
    assert _metrics("flexible_worst", mode)["peak_current_a"] <= 30.0


@pytest.mark.parametrize("seed", [0, 1])
def test_kalman_fc_peak_current_on_a_soft_coupling(seed):
    """flexible_worst (K x 0.1): the Friedland-Park valve term signed by the estimated velocity
    of a stuck valve (which follows the motor through the nominal coupling model) drove a
    300 rad/s motor oscillation at 31-37 A; it is now off while the reference stands still."""
    assert sim.run("flexible_worst", "kalman_fc", seed=seed).metrics["peak_current_a"] <= 30.0


def test_friedland_park_estimates_stay_out_of_the_observer_and_learn_only_while_sliding():
    pc = PositionController(CONTROLLER_SPEC.defaults().replace({"mode": "observer_fc"}))
    comp = pc.law.compensator
    assert isinstance(comp, FriedlandPark) and not comp.feeds_observer
    comp.reset(pc.model, 6206.0)
    level = comp.valve.level
    # the valve estimate says "moving" but the valve resolver shows it stuck: no learning
    ctx = Context(6206.0, 0.2, 0.5, 0.2, 0.5, 0.0, 0.3, 0.0, 0.0, False, 0.0, False)
    for _ in range(50):
        comp.update(ctx)
    assert comp.valve.level == level
    # sliding confirmed by the resolver: it adapts
    ctx = Context(6206.0, 0.2, 0.5, 0.2, 0.5, 0.5, 0.3, 0.0, 0.0, False, 0.0, False)
    for _ in range(50):
        comp.update(ctx)
    assert comp.valve.level != level
    # boundary layer: one valve resolver count per loop period
    assert comp.valve.boundary_velocity == pytest.approx(RESOLVER_COUNT_RAD / pc.period)


@pytest.mark.parametrize("scenario, mode", [
    ("load_step", "observer_fc"), ("load_step", "kalman_fc"), ("startup", "observer_fc"),
    pytest.param("startup", "kalman_fc", marks=pytest.mark.xfail(
        strict=True, reason="kalman_fc in startup still limit-cycles 2.4e-3 rad (seed 0; was 2.0e-2 rad): "
        "mechanism not traced yet"))])
def test_dissertation_modes_do_not_hunt_while_holding(scenario, mode):
    """Holding, the valve-velocity estimate of a stuck valve follows the motor through the
    coupling model; the ±Tc term signed by it kept a ~20 Hz motor oscillation that shook the
    valve loose (observer_fc: 9.6e-3 rad in load_step, 1.0e-2 in startup; kalman_fc: 7.5e-3 /
    2.0e-2).  The valve term is on only while the reference moves."""
    assert _metrics(scenario, mode)["limit_cycle_amplitude_rad"] <= 2 * RESOLVER_COUNT_RAD

"""Lockstep nodes run the offline simulator's periods at the simulator's times (issue 11: two
lockstep runs agreed with each other but not with ``fuel_valve_sim``).

Two ways the nodes' time base differed from the simulator's, each amplified by the loop:

* the ``/clock`` stamp read as ``sec + 1e-9 nanosec`` differs from ``k * period`` in the last
  bit on many ticks (the demand profile evaluated there: 4.7e-7 rad after a breakaway at
  t = 4.53 s);
* the lockstep controller timed a demand by the period it had answered *before* it (one period
  early): the demand filter's noise estimate differed in the last bit, the command from
  t = 6.018 s of the start-up profile, the valve by 6.3e-6 rad at 8.013 s and 3.1e-3 rad later
  (the real-CLI ``test_two_valves_in_lockstep_each_deterministic`` failed whenever its run got
  past 8 s of simulated time).

So stamps go through one conversion (:mod:`fuel_valve_control.common.timebase`) and a period's
inputs reach the driver through one exchange (:class:`~fuel_valve_control.core.period_inputs.PeriodInputs`)
in the simulator and in the controller node."""
import numpy as np

from fuel_valve_control.common.timebase import stamp_seconds, to_stamp
from fuel_valve_control.core.driver import ValveDriver
from fuel_valve_control.core.period_inputs import PeriodInputs
from fuel_valve_control.tools.run_plan import LOCKSTEP, OFFLINE, REAL_TIME, plan_run
from fuel_valve_control.tools.scenarios import load_scenario
from fuel_valve_control.tools.sim import LOG_COLUMNS, simulate_plan
from fuel_valve_plant.physics.plant import Plant


def _stamp(t_ns: int) -> tuple[int, int]:
    return t_ns // 1_000_000_000, t_ns % 1_000_000_000


def test_tick_stamps_map_to_the_simulators_period_grid():
    period = 1e-3
    naive_differs = 0
    for k in range(0, 10_000):
        sec, ns = _stamp(k * 1_000_000)
        assert stamp_seconds(sec, ns, period) == k * period, k
        naive_differs += stamp_seconds(sec, ns) != k * period
    # the grid matters: the plain stamp differs from the simulator's time on many ticks
    assert naive_differs > 100


def test_the_plants_clock_stamps_read_back_as_the_simulators_times():
    """The plant node stamps its time (a whole number of physics steps, 20 per 1 ms period)
    with :func:`to_stamp`; read back with the loop period it is the simulator's ``k * period``
    on every tick of 200 s."""
    plant_dt, period = 1.0 / 20000.0, 1e-3
    for k in range(0, 200_000):
        sec, ns = to_stamp((20 * k) * plant_dt)
        assert 0 <= ns < 1_000_000_000
        assert stamp_seconds(sec, ns, period) == k * period, k


def test_to_stamp_rounds_to_the_nanosecond_and_carries_into_the_next_second():
    assert to_stamp(2.5) == (2, 500_000_000)
    assert to_stamp(6.018) == (6, 18_000_000)          # 6.01799999...: not truncated to ...999
    assert to_stamp(0.9999999999) == (1, 0)            # never nanosec = 1e9


def test_a_stamp_off_the_grid_is_kept_as_it_is():
    sec, ns = _stamp(4_530_500_000)         # half a period off the 1 ms grid
    assert stamp_seconds(sec, ns, 1e-3) == sec + 1e-9 * ns
    # and a period that does not match the clock (a 2 kHz loop told 1 ms) does not distort it
    sec, ns = _stamp(1_500_000)
    assert stamp_seconds(sec, ns, 1e-3) == 1.5e-3


def test_the_run_plan_gives_the_demand_node_the_loops_period_in_lockstep():
    scenario = load_scenario("step_small")
    demand = plan_run(scenario, LOCKSTEP, controller_overrides={"loop_rate_hz": 2000.0}).node_parameters()["demand"]
    assert demand["tick_period_s"] == 1.0 / 2000.0
    assert "tick_period_s" not in plan_run(scenario, REAL_TIME).node_parameters()["demand"]


# --------------------------------------------------------------- the nodes' exchange, ROS-free
#: the start-up profile up to past the first position difference the one-period-early demand
#: made (command from 6.018 s, valve from 8.013 s)
LOCKSTEP_RUN_S = 8.1


def _lockstep_as_the_nodes(plan, demand_one_period_early=False):
    """The start-up run as the lockstep nodes exchange it, without ROS: the plant's time as
    the plant node stamps it, read back by the demand node (the profile's time) and by the
    controller (the period's time); the Δp and the demand arrive in either order (DDS gives
    none between topics: alternated here) and the controller runs the period through
    :class:`PeriodInputs`.  ``demand_one_period_early``: the controller node before the fix,
    which timed the demand by the period answered before it.  Commands (A) and true valve
    angles (rad) per period."""
    plant, driver = Plant(plan.plant_params), ValveDriver(plan.controller_params)
    plan.start_held(plant, driver)
    period = driver.period
    n = int(round(plan.duration_s / period))
    current, position = np.empty(n), np.empty(n)
    inputs, answered = PeriodInputs(), 0.0
    for k in range(n):
        sec, ns = to_stamp(plant.time)                          # plant node: /clock, samples
        demand = plan.demand.value(stamp_seconds(sec, ns, period))   # demand node's tick
        t = stamp_seconds(sec, ns, period)                      # controller: the period's time
        dp = plant.pressure_sample()
        arrivals = [("demand", demand)] + ([("dp", dp)] if dp is not None else [])
        for kind, value in (arrivals if k % 2 else arrivals[::-1]):
            if kind == "dp":
                inputs.pressure_differential(value)
            elif demand_one_period_early:
                driver.demand_percent(answered, value)
            else:
                inputs.demand_percent(value)
        sample = plant.resolver()
        out = inputs.run(driver, t, sample.motor_rad, sample.valve_rad, now=t)
        answered = t
        current[k], position[k] = out.current_a, plant.truth().valve_angle
        plant.set_command(out.current_a, out.enable)
        plant.advance(period)
    return current, position


def test_the_lockstep_exchange_gives_the_offline_simulators_commands_exactly():
    plan = plan_run(None, OFFLINE, duration_s=LOCKSTEP_RUN_S)
    offline = simulate_plan(plan).log
    current, position = _lockstep_as_the_nodes(plan)
    np.testing.assert_array_equal(current, offline[:, LOG_COLUMNS.index("current_cmd_a")])
    np.testing.assert_array_equal(position, offline[:, LOG_COLUMNS.index("position_rad")])


def test_the_start_up_run_tells_a_one_period_early_demand_apart():
    """The run above is sensitive to the regression it guards: the demand timed one period
    early (the node before the fix) gives other commands within it."""
    plan = plan_run(None, OFFLINE, duration_s=LOCKSTEP_RUN_S)
    offline = simulate_plan(plan).log
    current, position = _lockstep_as_the_nodes(plan, demand_one_period_early=True)
    differs = np.nonzero(current != offline[:, LOG_COLUMNS.index("current_cmd_a")])[0]
    assert len(differs) > 0
    assert np.max(np.abs(position - offline[:, LOG_COLUMNS.index("position_rad")])) > 0.0


def test_the_plant_re_publishes_a_tick_only_after_the_demand_node_may_have_held_it_back():
    # the start handshake's flake: the plant re-published tick 0 after 1 s while the demand
    # node was still allowed (up to 2 s) to wait for a late-matching subscriber of the demand
    from fuel_valve_control.ros.demand_node import MATCH_WAIT_S
    from fuel_valve_plant.ros.plant_node import LOCKSTEP_RESEND_S
    assert LOCKSTEP_RESEND_S > MATCH_WAIT_S

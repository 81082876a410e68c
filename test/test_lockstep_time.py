"""The lockstep demand is evaluated at the offline simulator's times (issue 11: two lockstep
runs agreed with each other but not with ``fuel_valve_sim``, 4.7e-7 rad after a breakaway at
t = 4.53 s, because the /clock stamp's ``sec + 1e-9 nanosec`` differs from ``k * period`` in
the last bit on some ticks)."""
from fuel_valve_control.ros.demand_node import tick_time
from fuel_valve_control.tools.run_plan import LOCKSTEP, REAL_TIME, plan_run
from fuel_valve_control.tools.scenarios import load_scenario


def _stamp(t_ns: int) -> tuple[int, int]:
    return t_ns // 1_000_000_000, t_ns % 1_000_000_000


def test_tick_stamps_map_to_the_simulators_period_grid():
    period = 1e-3
    naive_differs = 0
    for k in range(0, 10_000):
        sec, ns = _stamp(k * 1_000_000)
        assert tick_time(sec, ns, period) == k * period, k
        naive_differs += (sec + 1e-9 * ns) != k * period
    # the grid matters: the plain stamp differs from the simulator's time on many ticks
    assert naive_differs > 100


def test_a_stamp_off_the_grid_is_kept_as_it_is():
    sec, ns = _stamp(4_530_500_000)         # half a period off the 1 ms grid
    assert tick_time(sec, ns, 1e-3) == sec + 1e-9 * ns
    # and a period that does not match the clock (a 2 kHz loop told 1 ms) does not distort it
    sec, ns = _stamp(1_500_000)
    assert tick_time(sec, ns, 1e-3) == 1.5e-3


def test_the_run_plan_gives_the_demand_node_the_loops_period_in_lockstep():
    scenario = load_scenario("step_small")
    demand = plan_run(scenario, LOCKSTEP, controller_overrides={"loop_rate_hz": 2000.0}).node_parameters()["demand"]
    assert demand["tick_period_s"] == 1.0 / 2000.0
    assert "tick_period_s" not in plan_run(scenario, REAL_TIME).node_parameters()["demand"]

"""The run-plan (one run's set-up) and the launcher's ROS-free parts: parameter layering, the
initial held state for objects and for nodes, events, clock wiring, parameter files, stop."""
from __future__ import annotations

import signal
import subprocess
import sys

import numpy as np
import pytest

from fuel_valve_control.common.paramspec import ConfigError, read_ros_param_file
from fuel_valve_control.core.driver import ValveDriver
from fuel_valve_control.tools import sim
from fuel_valve_control.tools.launcher import Launcher, clock_participants, lockstep_parameters, write_params_file
from fuel_valve_control.tools.run_plan import LOCKSTEP, OFFLINE, REAL_TIME, EventQueue, plan_run
from fuel_valve_control.tools.scenarios import Event, load_scenario, parse_scenario
from fuel_valve_plant.physics.plant import Plant


def test_layering_scenario_then_overrides_then_seed_and_mode():
    sc = load_scenario("flexible_worst")
    assert sc.plant and sc.pressure_kpa is not None
    key, value = next(iter(sc.plant.items()))
    plan = plan_run(sc, OFFLINE)
    assert plan.plant_params[key] == value
    assert plan.plant_params["pressure_differential_kpa"] == sc.pressure_kpa
    over = plan_run(sc, OFFLINE, mode="pi", seed=7, plant_overrides={key: value * 1.5, "seed": 1},
                    controller_overrides={"mode": "observer"})
    assert over.plant_params[key] == value * 1.5
    assert over.plant_params["seed"] == 7 and over.mode == "pi"      # --seed / --controller win
    assert over.plant_overrides["seed"] == 7 and over.controller_overrides["mode"] == "pi"


def test_offline_rejects_unknown_parameters_nodes_get_theirs():
    sc = load_scenario("step_small")
    with pytest.raises(ConfigError):
        plan_run(sc, OFFLINE, controller_overrides={"telemetry_decimation": 1})
    with pytest.raises(ConfigError, match="mode"):
        plan_run(sc, REAL_TIME, mode="bang_bang")
    with pytest.raises(ConfigError):                # a schema parameter is still checked
        plan_run(sc, REAL_TIME, plant_overrides={"pressure_differential_kpa": "lots"})
    plan = plan_run(sc, REAL_TIME, controller_overrides={"telemetry_decimation": 1})
    assert plan.node_parameters()["controller"]["telemetry_decimation"] == 1


def test_node_parameters_are_typed_as_the_schema_says():
    # `--set controller.fine.late_loop_holdoff_first_s=2` parses to the integer 2: a node's DOUBLE parameter refused
    # it ("expecting type 'DOUBLE'") and the demo's controller did not come up (stop 30)
    plan = plan_run(load_scenario("startup"), REAL_TIME, plant_overrides={"friction_scale": 2, "command_timeout_s": 0.01},
                    controller_overrides={"fine.late_loop_holdoff_first_s": 2, "fine.max_pulses": 4.0})
    nodes = plan.node_parameters()
    assert type(nodes["controller"]["fine.late_loop_holdoff_first_s"]) is float
    assert type(nodes["controller"]["fine.max_pulses"]) is int
    assert type(nodes["plant"]["friction_scale"]) is float
    assert nodes["plant"]["command_timeout_s"] == 0.01           # a node-only parameter: as given


def test_node_parameters_carry_initial_state_demand_and_timing():
    sc = load_scenario("step_small")
    assert sc.initial_percent > 0
    plan = plan_run(sc, LOCKSTEP, duration_s=2.0)
    nodes = plan.node_parameters()
    angle = sc.initial_percent / 100.0 * plan.plant_params["valve.stroke_rad"]
    assert nodes["plant"]["start_held"] is True and nodes["plant"]["initial_position_rad"] == angle
    assert nodes["plant"]["pressure_differential_kpa"] == sc.pressure_kpa
    assert nodes["plant"]["stop_after_s"] == 2.0 and plan.duration_s == 2.0
    hold = Plant(plan.plant_params).hold_at(angle)
    assert nodes["controller"]["initial_current_a"] == hold > 0
    assert nodes["demand"] == {"profile": "step", "initial": 20.0, "final": 22.0, "at_s": 0.5, "lockstep": True,
                               "tick_period_s": 1.0 / plan.controller_params["loop_rate_hz"]}
    assert all(p["lockstep"] is True for p in nodes.values())
    rt = plan_run(sc, REAL_TIME).node_parameters()
    assert "stop_after_s" not in rt["plant"] and rt["plant"]["lockstep"] is False
    closed = plan_run(parse_scenario({"name": "c", "duration_s": 1.0, "demand": {"type": "constant", "percent": 5}}),
                      REAL_TIME).node_parameters()
    assert "start_held" not in closed["plant"] and "initial_current_a" not in closed["controller"]


def test_held_start_is_the_same_for_objects_and_for_nodes():
    """The nodes turn initial_position_rad / start_held / initial_current_a into the calls
    RunPlan.start_held makes: both drivers then command the same current."""
    plan = plan_run(load_scenario("step_small"), OFFLINE)
    plant_a, driver_a = Plant(plan.plant_params), ValveDriver(plan.controller_params)
    plan.start_held(plant_a, driver_a)
    nodes = plan_run(load_scenario("step_small"), REAL_TIME).node_parameters()
    plant_b = Plant(plan.plant_params)
    plant_b.hold_at(nodes["plant"]["initial_position_rad"])           # the plant node's start_held
    driver_b = ValveDriver(plan.controller_params)                    # the controller node's initial_current_a
    driver_b.start_from_torque(nodes["controller"]["initial_current_a"]
                               * driver_b.controller.model.torque_constant_nm_per_a)
    cold = ValveDriver(plan.controller_params)                        # no take-over: starts from zero
    for plant, driver in ((plant_a, driver_a), (plant_b, driver_b), (plant_b, cold)):
        driver.demand_percent(0.0, 20.0)
        s = plant.resolver()
        driver.resolver(s.stamp_s, s.motor_rad, s.valve_rad)
    out_a, out_b, out_cold = driver_a.step(0.0), driver_b.step(0.0), cold.step(0.0)
    assert out_a.enable and out_b.enable
    assert out_a.current_a == out_b.current_a
    assert abs(out_cold.current_a - out_a.current_a) > 1.0


def test_events_are_handed_out_once_in_time_order():
    q = EventQueue([Event(0.5, "reset"), Event(0.2, "trip"), Event(0.5 - 1e-13, "set_plant", {"load_torque_nm": 1})])
    assert q.due(0.1) == []
    assert [e.action for e in q.due(0.3)] == ["trip"]
    assert [e.action for e in q.due(0.499)] == []
    assert [e.action for e in q.due(0.5 - 1e-12)] == ["set_plant", "reset"]   # within the tolerance
    assert q.due(10.0) == [] and len(q) == 0


def test_simulate_with_external_parameter_sets_equals_the_plan():
    sc = load_scenario("trip")
    p, c = sim.build(sc, seed=2, mode="pi")
    a = sim.simulate(sc, p, c)
    b = sim.simulate_plan(plan_run(sc, OFFLINE, seed=2, mode="pi"))
    np.testing.assert_array_equal(a.log, b.log)
    assert a.metrics == b.metrics and a.controller == "pi"


# ------------------------------------------------------------------------------- launcher
@pytest.mark.parametrize("bag", [False, True])
def test_launcher_clock_wiring(tmp_path, bag):
    plan = plan_run(load_scenario("step_small"), LOCKSTEP)
    la = Launcher(plan, "ns", tmp_path, tmp_path / "bag" if bag else None, observers=1)
    assert la.namespace == "/ns"
    assert la.clock_participants() == clock_participants(bag, 1) == (4 if bag else 3)
    plant = la.node_parameters("plant")
    assert plant["use_sim_time"] is False and plant["lockstep_participants"] == la.clock_participants()
    assert plant["start_held"] is True
    for name in ("controller", "demand"):
        assert la.node_parameters(name)["use_sim_time"] is True
    rt = Launcher(plan_run(load_scenario("step_small"), REAL_TIME), "ns", tmp_path)
    assert all("use_sim_time" not in rt.node_parameters(n) for n in ("plant", "controller", "demand"))
    assert lockstep_parameters("recorder", False, 3) == {}


def test_params_file_round_trips(tmp_path):
    f = tmp_path / "c.params.yaml"
    values = {"mode": "pi", "fp.bandwidth_hz": np.float64(12.5), "points": [0.0, np.float64(20.0)], "lockstep": True}
    write_params_file(f, values)
    back = read_ros_param_file(f)
    assert back == {"mode": "pi", "fp.bandwidth_hz": 12.5, "points": [0.0, 20.0], "lockstep": True}


def test_stop_escalates_to_sigterm_for_a_process_ignoring_sigint(tmp_path):
    la = Launcher(plan_run(None, REAL_TIME), "ns", tmp_path)
    code = "import signal, sys, time; signal.signal(signal.SIGINT, signal.SIG_IGN); print('up', flush=True); " \
           "time.sleep(60)"
    la.procs["stubborn"] = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE)
    assert la.procs["stubborn"].stdout.readline().strip() == b"up"
    # up before the SIGINT: an interpreter still starting (slow beside a busy CPU) can outlast the grace
    # its own SIGINT handler: a pytest started from a non-interactive shell in the background
    # (``cmd &``) inherits SIGINT ignored, Python then installs no KeyboardInterrupt handler and
    # the child ignores SIGINT too (seen: -15 instead of -2 in such runs)
    polite = subprocess.Popen([sys.executable, "-c", "import signal, time; "
                               "signal.signal(signal.SIGINT, signal.default_int_handler); "
                               "print('up', flush=True); time.sleep(60)"],
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    la.procs["polite"] = polite
    assert polite.stdout.readline().strip() == b"up"
    codes = la.stop(["stubborn"], grace_s=0.5)
    # the polite one gets a grace its exit (KeyboardInterrupt, interpreter shutdown) cannot
    # outlast on a loaded machine; the stubborn one's 0.5 s is all this test spends waiting
    codes.update(la.stop(["polite"], grace_s=30.0))
    assert codes == {"stubborn": -signal.SIGTERM, "polite": -signal.SIGINT}
    assert la.failed() == ["stubborn", "polite"]

"""Every run-time parameter of the plant, the controller and the demand node, set through the
ROS parameter service of the running node, takes effect; and the measured Δp travels from the
plant to the controller (``ros2 param set`` on the plant changes what the controller schedules).

The three nodes run in this process, in lockstep (deterministic, robust under CPU load), on one
executor thread; the parameters are set from a separate context (``ros_probe.Probe``), as
``ros2 param set`` would.  "Takes effect" is checked on the running node's core object:

* controller: the driver's (and the position controller's) parameter set holds the new value;
  if the running law was built from that parameter, it has been replaced by one whose build
  read it (``law_params``), and the current limits are reconfigured;
* plant: the plant's parameter set holds it and the physics kernel's packed parameter array is
  exactly what the new set packs to;
* demand: the node's set holds it and the profile was rebuilt from it.

ROS-free detail (which law reads what, behaviour changes, bumpless transfer): test_runtime_params.py.
"""
from __future__ import annotations

import threading

import numpy as np
import pytest

pytestmark = [pytest.mark.ros]

rclpy = pytest.importorskip("rclpy")

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from ros_probe import Probe  # noqa: E402

from fuel_valve_control.core.params import CONTROLLER_SPEC  # noqa: E402
from fuel_valve_control.core.driver import PRESSURE_INPUT  # noqa: E402
from fuel_valve_control.tools.profiles import DEMAND_NODE_SPEC  # noqa: E402
from fuel_valve_plant.physics.params import PLANT_SPEC  # noqa: E402
from fuel_valve_plant.physics.plant import pack_parameters  # noqa: E402
from test_runtime_params import RUNTIME, changed_value  # noqa: E402

NS = "/params"


def _params(**values):
    return [Parameter(k, value=v) for k, v in values.items()]


@pytest.fixture(scope="module")
def suite():
    from fuel_valve_control.ros.controller_node import ControllerNode
    from fuel_valve_control.ros.demand_node import DemandNode
    from fuel_valve_plant.ros.plant_node import PlantNode

    context = rclpy.context.Context()
    rclpy.init(context=context)
    common = {"context": context, "namespace": NS}
    plant = PlantNode(**common, parameter_overrides=_params(
        lockstep=True, lockstep_participants=2, initial_position_rad=0.3, start_held=True,
        **{"pressure_sensor.noise_kpa": 0.0}))
    controller = ControllerNode(**common, parameter_overrides=_params(
        lockstep=True, use_sim_time=True, initial_current_a=plant._iq))
    demand = DemandNode(**common, parameter_overrides=_params(
        lockstep=True, use_sim_time=True, profile="constant", percent=28.65))
    executor = SingleThreadedExecutor(context=context)
    for node in (plant, controller, demand):
        executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    probe = Probe(NS)
    try:
        probe.wait_for(lambda: controller.driver.last.state == "running" and controller.driver.pressure_kpa > 0,
                       60.0, "the lockstep loop running with the measured Δp")
        yield plant, controller, demand, probe
    finally:
        probe.close()
        executor.shutdown(timeout_sec=2.0)
        for node in (plant, controller, demand):
            node.destroy_node()
        rclpy.shutdown(context=context)
        thread.join(timeout=2.0)


def _set(probe, node, name, value):
    results = probe.set_params(node, {name: value}, timeout=10.0)
    assert results[0].successful, results[0].reason


def _set_controller(probe, controller, name, value):
    """Set and wait for the loop to swap the change in (the controller queues an accepted
    change for a period boundary; a law replacement waits for a hold, at most 1 s: issue 13)."""
    _set(probe, "controller", name, value)
    probe.wait_for(lambda: not controller.driver.params_pending, 30.0, f"the swap of {name}")


def _runtime(spec):
    return [p.name for p in spec if p.runtime]


@pytest.mark.parametrize("name", RUNTIME)
def test_controller_runtime_parameter_takes_effect(suite, name):
    _, controller, _, probe = suite
    p = CONTROLLER_SPEC.params[name]
    value = changed_value(p)
    with controller._lock:
        law, old = controller.driver.controller.law, controller.driver.ps[name]
        law_reads = name == "mode" or name in controller.driver.controller.law_params
    try:
        _set_controller(probe, controller, name, value)
        with controller._lock:
            ctl = controller.driver.controller
            assert controller.driver.ps[name] == value and ctl.ps[name] == value
            if law_reads:
                assert ctl.law is not law and (name == "mode" or name in ctl.law_params)
            else:
                assert ctl.law is law
            if name.startswith("limits."):
                assert ctl.current_limits[0] == ctl.ps["limits.peak_current_a"]
    finally:
        _set_controller(probe, controller, name, old)


@pytest.mark.parametrize("name", _runtime(PLANT_SPEC))
def test_plant_runtime_parameter_takes_effect(suite, name):
    plant, _, _, probe = suite
    value = changed_value(PLANT_SPEC.params[name])
    old = plant.plant.params[name]
    try:
        _set(probe, "plant", name, value)
        assert plant.plant.params[name] == value
        packed = np.zeros_like(plant.plant.P)
        pack_parameters(plant.plant.params, packed)
        np.testing.assert_array_equal(plant.plant.P, packed)
    finally:
        _set(probe, "plant", name, old)


@pytest.mark.parametrize("name", _runtime(DEMAND_NODE_SPEC))
def test_demand_runtime_parameter_takes_effect(suite, name):
    _, _, demand, probe = suite
    p = DEMAND_NODE_SPEC.params[name]
    special = {"points": [0.0, 28.0, 1.0, 29.0], "csv_path": "unused_unless_profile_is_csv.csv"}
    value = special[name] if name in special else changed_value(p)
    old, profile = demand.ps[name], demand.profile
    try:
        if name == "profile" and value == "csv":
            value = "sine"
        _set(probe, "demand", name, value)
        assert demand.ps[name] == value and demand.profile is not profile
    finally:
        _set(probe, "demand", name, old)


def test_invalid_values_are_rejected_and_change_nothing(suite):
    plant, controller, _, probe = suite
    ps = controller.driver.ps
    res = probe.set_params("controller", {"limits.continuous_current_a": 39.0})
    assert not res[0].successful and "continuous" in res[0].reason
    res = probe.set_params("controller", {"loop_rate_hz": 500.0})     # start-up only: read-only
    assert not res[0].successful
    assert controller.driver.ps is ps
    res = probe.set_params("plant", {"friction.valve.static_nm": 0.1})
    assert not res[0].successful


def test_plant_pressure_differential_reaches_the_controller(suite):
    """The README example that used to desynchronise the nodes: Δp is set on the plant only,
    the plant publishes the measured value and the controller schedules for it."""
    plant, controller, _, probe = suite
    with controller._lock:
        controller.driver.reset()              # clear warnings earlier tests may have latched
    try:
        probe.wait_for(lambda: controller.driver.pressure_kpa == 6206.0, 10.0, "controller at 6206 kPa")
        _set(probe, "plant", "pressure_differential_kpa", 3103.0)
        probe.wait_for(lambda: controller.driver.pressure_kpa == 3103.0, 10.0, "controller scheduling 3103 kPa")
        health = controller.driver.health()
        assert health.values["pressure_source"] == "measured"
        assert PRESSURE_INPUT not in controller.driver.warnings
        # and on /diagnostics
        probe.wait_for(lambda: probe.driver_values().get("pressure_differential_kpa") == "3103", 10.0,
                       "/diagnostics reporting 3103 kPa")
    finally:
        _set(probe, "plant", "pressure_differential_kpa", 6206.0)


def test_controller_warns_and_falls_back_when_the_plant_stops_publishing_pressure(suite):
    plant, controller, _, probe = suite
    publish = plant.pub_pressure.publish
    plant.pub_pressure.publish = lambda msg: None        # the transducer goes silent
    try:
        probe.wait_for(lambda: PRESSURE_INPUT in controller.driver.warnings, 20.0, "Δp warning")
        assert controller.driver.pressure_kpa == controller.driver.ps["pressure.fallback_kpa"]
        assert controller.driver.last.enable           # a warning, not a trip
        # generous: /diagnostics comes from a timer of this process's executor, which a loaded
        # machine can starve for seconds
        probe.wait_for(lambda: probe.driver_level() == 1, 30.0, "WARN on /diagnostics")
    finally:
        plant.pub_pressure.publish = publish
    probe.wait_for(lambda: controller.driver.pressure_kpa == 6206.0, 10.0, "measured again")
    with controller._lock:
        ok, message = controller.driver.reset()
    assert ok and PRESSURE_INPUT in message

"""Fault-injection and fuzz campaign on the real node objects (issue 13, item 10): the
controller, plant and demand nodes built in this process (rclpy, a DDS domain of the module's
own), their callbacks called directly with bad messages -- fast, no process to wait for, and a
callback that raised would fail the test, where in a node process it would end the loop.

Generated from the nodes themselves and the one schema per node, so new inputs and
parameters are covered automatically:

* every subscription of every node (``Node.subscriptions``) gets the bad messages of its type
  (:func:`bad_messages`: NaN, ±inf, huge, negative, wrong joint names and lengths, wrong
  stamps); the controller's subscriptions must all be in the ROS-free campaign's input table
  (``test_fuzz.CONTROLLER_INPUTS``), where the closed-loop safety of each is checked;
* every declared parameter of every node gets its schema's boundary values, NaN and a wrong
  type through ``set_parameters`` (rclpy's type and range checks, then the node's own);
* the controller's ``~/trip`` and ``~/reset`` at odd times.

What must hold: nothing raises; the controller ends with no internal error (bad input is
handled as such), and a latched fault means the drive is off.
"""
from __future__ import annotations

import math

import pytest

pytest.importorskip("rclpy")

import rclpy  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from fuel_valve_control.core.driver import INTERNAL  # noqa: E402
from fuel_valve_control.core.params import CONTROLLER_NODE_SPEC  # noqa: E402
from fuel_valve_control.tools.profiles import DEMAND_NODE_SPEC  # noqa: E402
from fuel_valve_plant.physics.params import PLANT_NODE_SPEC  # noqa: E402

from test_fuzz import BAD_NUMBERS, CONTROLLER_INPUTS, boundary_values  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def bad_messages(msg_type) -> list:
    """Bad instances of ``msg_type`` (what DDS lets through: right type, wrong content)."""
    name = f"{msg_type.__module__.split('.')[0]}/{msg_type.__name__}"
    out = []
    if name in ("std_msgs/Float64",):
        out = [msg_type(data=v) for v in BAD_NUMBERS]
    elif name == "std_msgs/Bool":
        out = [msg_type(data=True), msg_type(data=False), msg_type(data=True)]
    elif name == "std_msgs/UInt8":                 # the drive's state word: every code, unknown ones
        out = [msg_type(data=v) for v in (0, 1, 2, 3, 4, 127, 255, 2, 1)]
    elif name == "sensor_msgs/JointState":
        from builtin_interfaces.msg import Time
        stamps = [Time(sec=2**31 - 1), Time(sec=-2**31), Time(sec=0, nanosec=999_999_999), Time()]
        shapes = [(["motor_shaft", "valve_shaft"], [v, v]) for v in BAD_NUMBERS] + [
            ([], []), (["valve_shaft"], [0.3]), (["motor_shaft", "valve_shaft"], [1.0]),
            (["a", "b"], [1.0, 0.3]), (["valve_shaft", "valve_shaft"], [0.3, 0.3]),
            (["motor_shaft", "valve_shaft", "x"], [14.0, 0.3, 1.0])]
        for names, pos in shapes:
            for stamp in stamps:
                m = msg_type(name=names, position=pos)
                m.header.stamp = stamp
                out.append(m)
    elif name == "std_msgs/Float64MultiArray":
        from std_msgs.msg import MultiArrayDimension
        for labels, data in ([("i_d", "i_q"), (v, v)] for v in BAD_NUMBERS):
            out.append(msg_type(data=list(data), layout=type(msg_type().layout)(
                dim=[MultiArrayDimension(label=x, size=1, stride=1) for x in labels])))
        out.append(msg_type(data=[1.0, 2.0, 3.0]))
        out.append(msg_type())
    elif name == "rosgraph_msgs/Clock":
        from builtin_interfaces.msg import Time
        out = [msg_type(clock=Time(sec=s, nanosec=n)) for s, n in
               ((2**31 - 1, 0), (-2**31, 0), (0, 0), (5, 999_999_999), (1, 0))]
    else:
        pytest.fail(f"no bad messages for {name}: add them to bad_messages()")
    return out


@pytest.fixture(scope="module")
def nodes():
    from fuel_valve_control.ros.controller_node import ControllerNode
    from fuel_valve_control.ros.demand_node import DemandNode
    from fuel_valve_plant.ros.plant_node import PlantNode
    context = rclpy.context.Context()
    rclpy.init(context=context)
    made = {}
    try:
        made["controller"] = ControllerNode(context=context)
        # lockstep: no tick thread of its own (the callbacks are what is fuzzed here)
        made["plant"] = PlantNode(context=context, parameter_overrides=[Parameter("lockstep", value=True)])
        made["demand"] = DemandNode(context=context, parameter_overrides=[Parameter("lockstep", value=True)])
        yield made
    finally:
        for node in made.values():
            node.destroy_node()
        rclpy.shutdown(context=context)


def relative(topic: str) -> str:
    return topic.rstrip("/").rsplit("/", 1)[-1]


def test_every_controller_input_is_in_the_closed_loop_campaign(nodes):
    subscribed = {relative(s.topic_name) for s in nodes["controller"].subscriptions}
    assert subscribed <= {relative(t) for t in CONTROLLER_INPUTS}, subscribed


@pytest.mark.parametrize("node_name", ["controller", "plant", "demand"])
def test_every_subscription_survives_bad_messages(nodes, node_name):
    node = nodes[node_name]
    subs = list(node.subscriptions)
    assert subs or node_name == "demand"
    for sub in subs:
        for msg in bad_messages(sub.msg_type):
            sub.callback(msg)                     # raises: the test fails (a node would lose its loop)
    if node_name == "controller":
        node.publish_step(node.now_s())
        out = node.driver.last
        assert INTERNAL not in out.faults, out.faults
        assert not out.faults or (not out.enable and out.current_a == 0.0)


SPECS = {"controller": CONTROLLER_NODE_SPEC, "plant": PLANT_NODE_SPEC, "demand": DEMAND_NODE_SPEC}


@pytest.mark.parametrize("node_name", ["controller", "plant", "demand"])
def test_every_parameter_boundary_value_is_answered(nodes, node_name):
    """``set_parameters`` answers every value (accepted or refused with a reason), never raises
    beyond rclpy's own refusal of a value whose type cannot be a parameter; afterwards the
    controller has no internal error."""
    node = nodes[node_name]
    spec = SPECS[node_name]
    answered = 0
    for p in spec:
        before = current = node.get_parameter(p.name).value
        for value in boundary_values(p):
            try:
                param = Parameter(p.name, value=value)
            except (TypeError, ValueError):       # not a ROS parameter value at all (DDS cannot carry it)
                continue
            try:
                results = node.set_parameters([param])
            except rclpy.exceptions.InvalidParameterTypeException:
                continue                          # rclpy refuses a type change: a refusal
            assert len(results) == 1
            answered += 1
            if not results[0].successful:           # refused: the value in force is unchanged
                assert results[0].reason
                now = node.get_parameter(p.name).value
                assert now == current or (isinstance(now, float) and math.isnan(now) and math.isnan(current))
            current = node.get_parameter(p.name).value
        # back to the start value where it changed (run-time ones)
        try:
            node.set_parameters([Parameter(p.name, value=before)])
        except rclpy.exceptions.InvalidParameterTypeException:
            pass
    assert answered > len(spec.params)
    if node_name == "controller":
        node.publish_step(node.now_s())
        assert INTERNAL not in node.driver.last.faults, node.driver.last.faults


def test_trip_and_reset_services_at_odd_times(nodes):
    from std_srvs.srv import Trigger
    node = nodes["controller"]
    for call in (node.on_reset, node.on_trip, node.on_trip, node.on_reset, node.on_reset, node.on_trip):
        res = call(Trigger.Request(), Trigger.Response())
        assert isinstance(res, Trigger.Response) and res.message
    assert node.driver.last.faults and not node.driver.last.enable      # tripped last: drive off
    res = node.on_reset(Trigger.Request(), Trigger.Response())
    assert not res.success and "cannot reset" in res.message            # no inputs: refused
    node.publish_step(node.now_s())
    assert not node.driver.last.enable and node.driver.last.current_a == 0.0

"""The SROS2 policy the repository keeps (``config/sros2/policy.xml``, issue 13 item 10) is
the one the suite's nodes imply, and it gives the drive's inputs to the controller alone.

The policy is generated from the node objects (``tools/sros2_policy.py``); here the nodes are
built again and the file must match, so a new topic or service cannot leave the secured plant
with a node that silently receives nothing.  sros2 itself (XSD validation, signed
permissions) and the comparison with ``ros2 security generate_policy`` on a live graph run in
``test_ros2_cli.py`` where sros2 is installed."""
from __future__ import annotations

import pytest

pytest.importorskip("rclpy")

from fuel_valve_control.common import contract  # noqa: E402
from fuel_valve_control.tools import sros2_policy as sp  # noqa: E402

pytestmark = [pytest.mark.ros]


@pytest.fixture(scope="module")
def endpoints(ros_domain):
    return sp.suite_endpoints(sp.DEFAULT_NAMESPACE)


@pytest.fixture(scope="module")
def kept() -> str:
    return sp.policy_path().read_text()


def test_the_kept_policy_is_the_one_the_nodes_imply(endpoints, kept):
    assert sp.policy_xml(endpoints) == kept, "config/sros2/policy.xml is stale: run fuel_valve_sros2_policy"


def test_only_the_controller_may_command_the_drive(kept):
    ns = sp.DEFAULT_NAMESPACE
    for topic in (contract.CURRENT_COMMAND, contract.DRIVE_ENABLE):
        assert sp.publishers_of(kept, topic) == {f"{ns}/controller"}, topic
    for topic in (contract.RESOLVER, contract.JOINT_STATES, contract.DRIVE, contract.DRIVE_STATUS,
                  contract.PRESSURE_DIFFERENTIAL, "clock"):
        assert sp.publishers_of(kept, topic) == {f"{ns}/plant"}, topic
    for topic in (contract.DEMAND, contract.DEMAND_MA):
        assert sp.publishers_of(kept, topic) == {f"{ns}/demand"}, topic


def test_the_recorder_subscribes_to_every_suite_topic_and_publishes_only_what_every_node_does(endpoints):
    rec = endpoints["recorder"]
    assert rec["publish"] == {"/rosout", "/parameter_events"}
    ns = sp.DEFAULT_NAMESPACE
    wanted = {t if t.startswith("/") else f"{ns}/{t}" for t in contract.TOPIC_TYPES}
    assert wanted <= rec["subscribe"], sorted(wanted - rec["subscribe"])


def test_reset_and_trip_are_the_controllers_services(endpoints):
    ns = sp.DEFAULT_NAMESPACE
    assert {f"{ns}/controller/reset", f"{ns}/controller/trip"} <= endpoints["controller"]["reply"]
    # a managed node: rcl_lifecycle's transition events (no rclpy publisher object) are in too
    assert f"{ns}/controller/transition_event" in endpoints["controller"]["publish"]
    others = set().union(*(endpoints[n]["reply"] | endpoints[n]["request"] for n in ("plant", "demand", "recorder")))
    assert not {s for s in others if s.endswith(("/reset", "/trip"))}


def test_lockstep_endpoints_are_included(endpoints):
    """The union covers lockstep: the plant publishes the valve's clock, the others subscribe."""
    clock = f"{sp.DEFAULT_NAMESPACE}/clock"
    assert clock in endpoints["plant"]["publish"]
    assert all(clock in endpoints[n]["subscribe"] for n in ("controller", "demand"))


def test_a_node_endpoint_added_in_code_reaches_the_policy(ros_domain):
    """The policy follows the node objects, not a list: a publisher created on a node shows up."""
    import rclpy
    from std_msgs.msg import Float64

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node("controller", namespace=sp.DEFAULT_NAMESPACE, context=context)
        node.create_publisher(Float64, "new_output", 1)
        node.create_service(__import__("std_srvs.srv", fromlist=["Trigger"]).Trigger, "~/new_service", lambda r, s: s)
        eps = sp.node_endpoints(node)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    assert f"{sp.DEFAULT_NAMESPACE}/new_output" in eps["publish"]
    assert f"{sp.DEFAULT_NAMESPACE}/controller/new_service" in eps["reply"]
    text = sp.policy_xml({n: (eps if n == "controller" else {k: set() for k in eps}) for n in sp.SUITE_NODES})
    assert sp.publishers_of(text, "new_output") == {f"{sp.DEFAULT_NAMESPACE}/controller"}
    assert "<service>~/new_service</service>" in text


@pytest.mark.parametrize("fqn, namespace, node, expected", [
    ("/fuel_valve/controller/reset", "/fuel_valve", "controller", "~/reset"),
    ("/fuel_valve/current_command", "/fuel_valve", "controller", "current_command"),
    ("/fuel_valve/current_command", "/fuel_valve/", "controller", "current_command"),
    ("/parameter_events", "/fuel_valve", "plant", "/parameter_events"),
    ("/other/clock", "/fuel_valve", "plant", "/other/clock"),
    ("/chatter", "/", "talker", "chatter"),
    ("/talker/x", "/", "talker", "~/x"),
    ("/a/b", "/", "talker", "/a/b"),
])
def test_names_follow_the_rules_of_ros2_security_generate_policy(fqn, namespace, node, expected):
    assert sp.relative_name(fqn, namespace, node) == expected

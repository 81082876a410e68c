"""The controller node as clients outside the suite meet it (h24u, docs §44): a supervisory
stack that publishes the demand and Δp with QoS of its own choosing, two publishers on one
input, a learned-state file that belongs to another valve.

One controller node in this process (real time, no plant: nothing here needs the loop to
run, so a loaded machine cannot starve it into a fault), shared by the module; the clients
are nodes of another context (as another process's would be), spun on a thread.  What is
asserted is what the clients can see: their publishers match the controller's subscriptions,
the value reaches the driver, ``/diagnostics`` names a conflict.
"""
from __future__ import annotations

import json
import threading

import pytest

from ros_probe import in_process_controller, spin_in_thread, stop_spinning, wait_for  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]

import rclpy  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402

from fuel_valve_control.common import contract  # noqa: E402

NS = "/clients"
#: discovery and matching on a loaded 2-core machine, s
MATCH_S = 10.0


def qos(reliability, durability=DurabilityPolicy.VOLATILE, depth=1) -> QoSProfile:
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=reliability, durability=durability)


#: the publisher profiles a client may choose: best-effort (the sensor-data profile's
#: reliability), reliable, transient-local, depth 1 and deep
CLIENT_QOS = {
    "best_effort": qos(ReliabilityPolicy.BEST_EFFORT, depth=5),
    "reliable_depth1": qos(ReliabilityPolicy.RELIABLE),
    "transient_local": qos(ReliabilityPolicy.RELIABLE, DurabilityPolicy.TRANSIENT_LOCAL),
    "best_effort_transient_local": qos(ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.TRANSIENT_LOCAL, depth=10),
}


class Client:
    """A node of its own context: publishers it creates, the latest controller status."""

    def __init__(self):
        from diagnostic_msgs.msg import DiagnosticArray
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("outside_client", namespace=NS, context=self.context)
        self.lock = threading.Lock()
        self.status = None
        self.node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, self._on_diag, 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = spin_in_thread(self.executor, self._stop)

    def _on_diag(self, msg):
        for st in msg.status:
            if st.name.startswith(NS + "/") and st.name.endswith("valve driver"):
                with self.lock:
                    self.status = st

    def values(self) -> dict:
        with self.lock:
            return {} if self.status is None else {kv.key: kv.value for kv in self.status.values}

    def message(self) -> str:
        with self.lock:
            return "" if self.status is None else self.status.message

    def close(self):
        stop_spinning(self._thread, self._stop, self.executor)
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


@pytest.fixture(scope="module")
def controller():
    """The controller node (real time, autostart, /diagnostics at 10 Hz) spinning in this process."""
    with in_process_controller(NS, {"diagnostics_rate_hz": 10.0, "demand_timeout_s": 60.0}) as (node, _thread):
        yield node


@pytest.fixture(scope="module")
def client(controller):
    c = Client()
    yield c
    c.close()


def accepted_demand(node):
    """The demand the driver holds, percent (its health reports the one of the last period, and
    without a plant no period runs)."""
    with node._lock:
        return node.driver._demand_pct


@pytest.mark.parametrize("profile", sorted(CLIENT_QOS))
def test_a_demand_published_with_any_client_qos_reaches_the_driver(controller, client, profile):
    # found: the controller's RELIABLE subscription never matched a best-effort publisher
    # (DDS pairs a reliable reader with reliable writers only), so a supervisor publishing its
    # demand with the sensor-data profile was ignored and the valve tripped on a stale demand
    from std_msgs.msg import Float64
    value = 20.0 + 5.0 * sorted(CLIENT_QOS).index(profile)      # a different demand per profile
    pub = client.node.create_publisher(Float64, contract.DEMAND, CLIENT_QOS[profile])
    try:
        wait_for(lambda: pub.get_subscription_count() >= 1, MATCH_S, f"a {profile} demand publisher to match")

        def arrived():
            pub.publish(Float64(data=value))
            return accepted_demand(controller) == value
        wait_for(arrived, MATCH_S, f"demand {value} % from a {profile} publisher at the driver")
    finally:
        client.node.destroy_publisher(pub)


@pytest.mark.parametrize("topic", [contract.DEMAND_MA, contract.PRESSURE_DIFFERENTIAL])
def test_the_other_inputs_match_a_best_effort_publisher(controller, client, topic):
    from std_msgs.msg import Float64
    pub = client.node.create_publisher(Float64, topic, CLIENT_QOS["best_effort"])
    try:
        wait_for(lambda: pub.get_subscription_count() >= 1, MATCH_S, f"a best-effort {topic} publisher to match")
    finally:
        client.node.destroy_publisher(pub)


def test_two_demand_publishers_are_named_on_diagnostics_while_they_last(controller, client):
    # found: two supervisors publishing 30 and 50 % interleaved, the demand filter took the
    # alternation for noise and the valve sat at 38 % with the status OK
    from std_msgs.msg import Float64
    first = client.node.create_publisher(Float64, contract.DEMAND, CLIENT_QOS["reliable_depth1"])
    second = client.node.create_publisher(Float64, contract.DEMAND, CLIENT_QOS["best_effort"])
    try:
        wait_for(lambda: client.values().get("demand_publishers") == "2", MATCH_S, "demand_publishers 2")
        wait_for(lambda: f"2 publishers on {NS}/demand" in client.message(), 2.0, "the conflict in the status message")
        assert client.status.level[0] >= 1
        client.node.destroy_publisher(second)
        second = None
        wait_for(lambda: client.values().get("demand_publishers") == "1", MATCH_S, "demand_publishers 1")
        wait_for(lambda: "publishers on" not in client.message(), 2.0, "the conflict gone from the status")
    finally:
        client.node.destroy_publisher(first)
        if second is not None:
            client.node.destroy_publisher(second)


def test_a_second_pressure_source_is_named_on_diagnostics(controller, client):
    from std_msgs.msg import Float64
    pubs = [client.node.create_publisher(Float64, contract.PRESSURE_DIFFERENTIAL, CLIENT_QOS["reliable_depth1"])
            for _ in range(2)]
    try:
        wait_for(lambda: client.values().get("pressure_publishers") == "2", MATCH_S, "pressure_publishers 2")
        wait_for(lambda: f"2 publishers on {NS}/pressure_differential" in client.message(), 2.0, "the conflict")
    finally:
        for pub in pubs:
            client.node.destroy_publisher(pub)


def test_a_learned_state_file_of_another_valve_is_neither_loaded_nor_saved_over(tmp_path):
    # found: the file had no owner, so two valves given one learned_state_file (one
    # controller.yaml for a launch of valves:=valve1,valve2) loaded each other's friction and
    # duty and saved over each other; a file copied from another valve loaded silently
    from rclpy.parameter import Parameter
    from fuel_valve_control.ros.controller_node import ControllerNode

    path = tmp_path / "learned.json"
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)

    def start(namespace):
        return ControllerNode(context=ctx, namespace=namespace,
                              parameter_overrides=[Parameter("learned_state_file", value=str(path))])

    try:
        first = start("/valve1")
        assert first._state_status.startswith("not loaded"), first._state_status
        first.trigger_deactivate()                    # saves: the file now names its owner
        first.trigger_cleanup()
        first.destroy_node()
        doc = json.loads(path.read_text())
        assert doc["owner"] == "/valve1/controller"
        written = path.read_bytes()

        other = start("/valve2")
        assert other._state_status.startswith("foreign (/valve1/controller)"), other._state_status
        other.trigger_deactivate()
        other.trigger_shutdown()
        other.save_on_exit()
        other.destroy_node()
        assert path.read_bytes() == written           # valve1's state survives valve2

        again = start("/valve1")                      # the owner's restart loads it
        assert again._state_status == "loaded", again._state_status
        again.destroy_node()

        doc.pop("owner")                              # a file from before owners: accepted
        path.write_text(json.dumps(doc))
        legacy = start("/valve2")
        assert legacy._state_status == "loaded", legacy._state_status
        legacy.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_a_typo_in_a_parameter_file_is_reported_not_silently_dropped(controller, client):
    # found: rclpy drops an override of a parameter the node does not have without a word, so
    # `faults.resolver_timeout: 0.5` (the `_s` forgotten) left 0.02 s in force unnoticed
    from rclpy.parameter import Parameter
    from fuel_valve_control.ros.controller_node import ControllerNode
    from fuel_valve_control.ros import interface as ri

    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        node = ControllerNode(context=ctx, namespace="/typo", parameter_overrides=[
            Parameter("autostart", value=False), Parameter("faults.resolver_timeout", value=0.5),
            Parameter("demand_timeout_s", value=1.0)])
        assert node._unknown_params == ["faults.resolver_timeout"]
        assert node.get_parameter("faults.resolver_timeout_s").value == 0.02     # the default, still
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)
    # and the shared node reports none on /diagnostics
    wait_for(lambda: client.values().get("ignored_parameters") == "none", MATCH_S, "ignored_parameters none")
    assert ri.unknown_overrides(controller) == []


def test_a_demand_publisher_of_the_wrong_type_is_named_on_diagnostics(controller, client):
    # found: `ros2 topic pub .../demand std_msgs/msg/Float32 ...` never matches (type mismatch):
    # the demand went stale and the valve tripped, the status naming only the stale demand
    from std_msgs.msg import Float32
    pub = client.node.create_publisher(Float32, contract.DEMAND, CLIENT_QOS["reliable_depth1"])
    try:
        wait_for(lambda: "std_msgs/msg/Float32 on /clients/demand is ignored" in client.message(), MATCH_S,
                 "the wrong-type publisher named in the status")
        assert client.status.level[0] >= 1
        assert client.values().get("demand_publishers") == "0"          # not counted as a source
    finally:
        client.node.destroy_publisher(pub)


def test_a_demand_on_the_other_scaling_is_named_on_diagnostics(controller, client):
    # a supervisor publishing 4-20 mA to a controller set to demand_source: percent was ignored
    # with only the stale demand to show for it
    from std_msgs.msg import Float64
    pub = client.node.create_publisher(Float64, contract.DEMAND_MA, CLIENT_QOS["reliable_depth1"])
    try:
        wait_for(lambda: f"published on {NS}/demand_ma, but demand_source is 'percent'" in client.message(),
                 MATCH_S, "the unused demand topic named in the status")
    finally:
        client.node.destroy_publisher(pub)


def test_the_learned_state_path_expands_home_and_variables(tmp_path, monkeypatch):
    # a technician's `~/...` or `$STATE_DIR/...` was taken literally (a directory named `~`)
    from rclpy.parameter import Parameter
    from fuel_valve_control.ros.controller_node import ControllerNode

    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.setenv("FV_STATE_DIR", str(tmp_path))
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        for text in ("~/a.json", "$FV_STATE_DIR/b.json"):
            node = ControllerNode(context=ctx, namespace="/paths", parameter_overrides=[
                Parameter("learned_state_file", value=text)])
            node.trigger_deactivate()                 # saves
            node.destroy_node()
        assert (tmp_path / "a.json").is_file() and (tmp_path / "b.json").is_file()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_a_replayed_resolver_sample_is_named_as_a_second_source():
    # a bag replayed into a live valve: a resolver sample stamped an hour ago became the
    # measurement and the next period latched "no resolver sample for 3600000 ms" while
    # samples kept arriving; now the sample is refused, and the fault says what it was
    from fuel_valve_control.core.driver import RESOLVER_IMPLAUSIBLE, ValveDriver
    from fuel_valve_control.core.params import load_controller_params

    def running_driver():
        d = ValveDriver(load_controller_params())
        for k in range(50):
            t = 1000.0 + k * 1e-3
            d.demand_percent(t, 20.0)
            d.resolver(t, 0.2 * 48.019, 0.2, now=t)
            d.pressure_differential(t, 6206.0)
            assert d.step(t).enable
        return d, t

    d, t = running_driver()
    d.resolver(t - 3600.0, 0.2 * 48.019, 0.2, now=t + 1e-3)
    out = d.step(t + 1e-3)
    assert not out.enable and set(out.faults) == {RESOLVER_IMPLAUSIBLE}, out.faults
    assert "second source" in out.faults[RESOLVER_IMPLAUSIBLE]
    # a system clock stepped back moves the stamp and the loop's clock together: no fault
    d, t = running_driver()
    d.resolver(t - 10.0, 0.2 * 48.019, 0.2, now=t - 10.0 + 1e-4)
    assert d.step(t - 10.0 + 1e-4).enable

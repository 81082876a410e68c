"""Test-side rclpy helper: a node in its own context, spun in a background thread, that keeps
the latest message (and, on request, every message) of the suite's topics, publishes test
inputs and calls services and parameter services with timeouts.

The probe is the supervisor that sends the demand.  In real time it publishes it every 10 ms
of wall time.  With ``lockstep=True`` it is a lockstep participant instead, as the ``demand``
node is in a lockstep run: it subscribes to the plant's ``/clock`` and publishes the demand
once per tick, which is what the controller waits for before each period; simulated time then
advances only as fast as every participant keeps up, so a loaded machine slows the run down
instead of starving the loop into timeouts.  (Silence cannot be tested that way: a lockstep
loop waits for the demand and the resolver instead of timing out.)"""
from __future__ import annotations

import contextlib
import threading
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from fuel_valve_control.common import contract  # noqa: E402
from fuel_valve_control.ros import interface as ri

DEEP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2000, reliability=ReliabilityPolicy.RELIABLE)
#: latched topics: every change kept (the writer keeps the last one for a late joiner)
DEEP_LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2000, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)



def spin_in_thread(executor, stop: threading.Event) -> threading.Thread:
    """Spin ``executor`` on a daemon thread until ``stop`` is set (:func:`stop_spinning`)."""
    def spin():
        while not stop.is_set() and executor.context.ok():
            executor.spin_once(timeout_sec=0.1)
    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    return thread


def stop_spinning(thread: threading.Thread, stop: threading.Event, executor) -> None:
    """End a :func:`spin_in_thread` spin, then shut its executor down.  The thread leaves its
    loop first: an executor shut down (or its nodes destroyed) under a spin still running on
    a loaded machine raised in that thread (InvalidHandle; a guard condition already None)."""
    stop.set()
    thread.join(timeout=30.0)
    executor.shutdown(timeout_sec=2.0)

def wait_for(predicate, timeout: float, what: str = "condition", detail=None):
    """Poll ``predicate`` every 10 ms until it returns a true value (returned) or ``timeout`` s
    pass (AssertionError naming ``what``, and ``detail()`` if given)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(0.01)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}" + (f"; {detail()}" if detail else ""))


@contextlib.contextmanager
def in_process_controller(namespace: str, overrides: dict):
    """The controller node (real time) spinning on a thread of this process in the nodes' own
    timed EventsExecutor loop (``node_runner.spin``), so a test can reach into its driver and
    law; ``overrides``: parameter name -> value.  Yields ``(node, thread)``; tears it down."""
    from rclpy.parameter import Parameter

    from fuel_valve_control.ros.controller_node import ControllerNode
    from fuel_valve_control.ros.node_runner import make_executor, spin

    context = rclpy.context.Context()
    rclpy.init(context=context)
    node = ControllerNode(context=context, namespace=namespace,
                          parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])
    executor = make_executor(context=context)
    executor.add_node(node)
    stop = threading.Event()
    thread = threading.Thread(target=spin, args=(executor, context, stop.is_set), daemon=True)
    thread.start()
    try:
        yield node, thread
    finally:
        stop.set()
        thread.join(timeout=5.0)
        executor.remove_node(node)
        node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown(context=context)


class Probe:
    def __init__(self, namespace: str, keep_all: tuple[str, ...] = (), lockstep: bool = False):
        from diagnostic_msgs.msg import DiagnosticArray
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Bool, Float64, UInt8

        self.context = rclpy.context.Context()
        rclpy.init(context=self.context)
        from fuel_valve_control.tools.launcher import clock_remap
        # in lockstep the valve's own clock, as the launcher gives it to the valve's nodes
        cli = ["--ros-args", *clock_remap(namespace, True)] if lockstep else None
        self.node = rclpy.create_node("test_probe", namespace=namespace, context=self.context, cli_args=cli)
        self.lock = threading.Lock()
        self.latest: dict[str, tuple[float, object]] = {}
        self.history: dict[str, list[tuple[float, object]]] = {t: [] for t in keep_all}
        self.diagnostics: dict[str, object] = {}       # status name -> latest DiagnosticStatus
        # only what the tests read: each 1 kHz subscription is Python work per period, and in
        # lockstep the probe's executor paces the whole loop
        types = {contract.POSITION: Float64, contract.CURRENT_COMMAND: Float64, contract.DRIVE_ENABLE: Bool,
                 contract.JOINT_STATES: JointState, contract.DRIVE_STATUS: UInt8}
        for topic, mtype in types.items():
            qos = (ri.LATCHED_QOS if topic == contract.DRIVE_ENABLE
                   else DEEP_LATCHED if topic in contract.LATCHED_TOPICS else DEEP)
            self.node.create_subscription(mtype, topic, lambda m, t=topic: self._store(t, m), qos)
        self.node.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, self._on_diag, DEEP)
        self.pub_demand = self.node.create_publisher(Float64, contract.DEMAND, ri.LOOP_QOS)
        self.pub_demand_ma = self.node.create_publisher(Float64, contract.DEMAND_MA, ri.LOOP_QOS)
        self.pub_resolver = self.node.create_publisher(JointState, contract.RESOLVER, ri.LOOP_QOS)
        self._float = Float64
        self._clients: dict[tuple[type, str], object] = {}     # service clients, one per service
        self._demand: tuple[str, float] | None = None
        self.lockstep = lockstep
        self.ticks = 0
        self._last_sent = 0.0
        if lockstep:        # one demand per /clock tick (same QoS as the plant's /clock publisher)
            self.node.create_subscription(Clock, contract.CLOCK, self._on_tick, ri.TELEMETRY_QOS)
            # a loop that has stalled waiting for a demand (the first tick's demand sent before
            # the controller matched, or a pause with set_demand(None)) gets one again
            self.node.create_timer(0.05, self._kick)
        else:
            self.node.create_timer(0.01, self._publish_demand)      # a supervisor at 100 Hz
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop_spin = threading.Event()
        self._thread = spin_in_thread(self.executor, self._stop_spin)

    def _store(self, topic, msg):
        now = time.monotonic()
        with self.lock:
            self.latest[topic] = (now, msg)
            if topic in self.history:
                self.history[topic].append((now, msg))

    def _on_diag(self, msg):
        with self.lock:
            for st in msg.status:
                self.diagnostics[st.name] = st

    # ---------------------------------------------------------------- inputs
    def set_demand(self, value: float | None, topic: str = contract.DEMAND) -> None:
        """Publish ``value`` on ``topic`` from now on, every 10 ms or, in lockstep, once per
        ``/clock`` tick (None: fall silent; in lockstep that stalls the run)."""
        self._demand = None if value is None else (topic, value)

    def _on_tick(self, _msg):
        self.ticks += 1
        self._publish_demand()

    def _kick(self):
        if time.monotonic() - self._last_sent > 0.2:
            self._publish_demand()

    def _publish_demand(self):
        if self._demand is not None:
            topic, value = self._demand
            (self.pub_demand if topic == contract.DEMAND else self.pub_demand_ma).publish(self._float(data=value))
            self._last_sent = time.monotonic()

    def seize_valve(self, valve_rad: float | None, gear_ratio: float = 48.019, rate_hz: float = 1000.0) -> None:
        """Act as a plant whose valve is seized at ``valve_rad``: publish consistent resolver
        readings at ``rate_hz`` from a thread (None: stop)."""
        self._seized = valve_rad
        if valve_rad is None or getattr(self, "_seize_thread", None) is not None:
            return
        from sensor_msgs.msg import JointState
        pub_pressure = self.node.create_publisher(self._float, contract.PRESSURE_DIFFERENTIAL, ri.TELEMETRY_QOS)

        def loop():
            next_t = time.monotonic()
            k = 0
            while self._seized is not None and self.context.ok():
                stamp = self.node.get_clock().now().to_msg()
                self.pub_resolver.publish(JointState(header=__import__("std_msgs.msg").msg.Header(stamp=stamp),
                                                     name=list(contract.JOINT_NAMES),
                                                     position=[self._seized * gear_ratio, self._seized]))
                if k % max(int(rate_hz / 100.0), 1) == 0:        # and its Δp transducer at ~100 Hz
                    pub_pressure.publish(self._float(data=contract.PRESSURE_MAX_KPA))
                k += 1
                next_t += 1.0 / rate_hz
                time.sleep(max(0.0, next_t - time.monotonic()))
            self._seize_thread = None
        self._seize_thread = threading.Thread(target=loop, daemon=True)
        self._seize_thread.start()

    def publish_raw(self, topic: str, value: float) -> None:
        (self.pub_demand if topic == contract.DEMAND else self.pub_demand_ma).publish(self._float(data=value))

    # ---------------------------------------------------------------- reading
    def get(self, topic: str):
        with self.lock:
            item = self.latest.get(topic)
        return None if item is None else item[1]

    def since(self, topic: str, t0: float) -> list:
        with self.lock:
            return [m for t, m in self.history.get(topic, []) if t >= t0]

    def valve_angle(self) -> float | None:
        msg = self.get(contract.JOINT_STATES)
        return None if msg is None else msg.position[1]

    def status(self, suffix: str):
        """This namespace's latest /diagnostics status whose name ends with ``suffix`` (or None)."""
        with self.lock:
            for name, st in self.diagnostics.items():
                # /diagnostics is global: take this namespace's nodes only
                if name.startswith(self.node.get_namespace() + "/") and name.endswith(suffix):
                    return st
        return None

    def driver_status(self):
        """The controller's latest /diagnostics status (or None)."""
        return self.status("valve driver")

    def driver_level(self) -> int | None:
        st = self.driver_status()
        return None if st is None else (st.level[0] if isinstance(st.level, bytes) else int(st.level))

    def driver_values(self) -> dict:
        st = self.driver_status()
        return {} if st is None else {kv.key: kv.value for kv in st.values}

    def wait_for(self, predicate, timeout: float, what: str = "condition"):
        """:func:`wait_for`, the timeout's message carrying the driver's status."""
        return wait_for(predicate, timeout, what,
                        lambda: f"driver status: {getattr(self.driver_status(), 'message', None)!r}")

    # ---------------------------------------------------------------- services
    def _client(self, srv_type, service: str, timeout: float):
        """The probe's client of ``service``, created once and kept: a new client has to be
        discovered by the server before its first request (DDS matching, about a second on a
        loaded machine), so tests that call the same service many times pay that once."""
        client = self._clients.get((srv_type, service))
        if client is None:
            client = self._clients[(srv_type, service)] = self.node.create_client(srv_type, service)
        assert client.wait_for_service(timeout_sec=timeout), f"service {service} not available"
        return client

    def trigger(self, service: str, timeout: float = 15.0):
        from std_srvs.srv import Trigger
        client = self._client(Trigger, service, timeout)
        return self._wait_future(client.call_async(Trigger.Request()), timeout, service)

    def set_params(self, node: str, params: dict, timeout: float = 15.0, atomically: bool = False) -> list:
        """SetParameters on ``node`` (relative to the namespace; each parameter on its own);
        returns the results.  ``atomically``: SetParametersAtomically (all or none), whose one
        result is returned as a one-element list."""
        from rcl_interfaces.srv import SetParameters, SetParametersAtomically
        from rclpy.parameter import Parameter
        srv, name = (SetParametersAtomically, "set_parameters_atomically") if atomically else \
            (SetParameters, "set_parameters")
        client = self._client(srv, f"{node}/{name}", timeout)
        req = srv.Request(parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in params.items()])
        resp = self._wait_future(client.call_async(req), timeout, f"{node}/{name}")
        return [resp.result] if atomically else resp.results

    def get_params(self, node: str, names: list[str], timeout: float = 15.0) -> list:
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python
        client = self._client(GetParameters, f"{node}/get_parameters", timeout)
        resp = self._wait_future(client.call_async(GetParameters.Request(names=names)), timeout,
                                 f"{node}/get_parameters")
        return [parameter_value_to_python(v) for v in resp.values]

    def change_state(self, node: str, transition_id: int, timeout: float = 15.0) -> bool:
        """lifecycle_msgs ChangeState on ``node`` (relative to the namespace): its success."""
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState
        client = self._client(ChangeState, f"{node}/change_state", timeout)
        req = ChangeState.Request(transition=Transition(id=transition_id))
        return self._wait_future(client.call_async(req), timeout, f"{node}/change_state").success

    def lifecycle_state(self, node: str, timeout: float = 15.0) -> str:
        """The label of ``node``'s lifecycle state (lifecycle_msgs GetState)."""
        from lifecycle_msgs.srv import GetState
        client = self._client(GetState, f"{node}/get_state", timeout)
        return self._wait_future(client.call_async(GetState.Request()), timeout,
                                 f"{node}/get_state").current_state.label

    @staticmethod
    def _wait_future(future, timeout, what):
        end = time.monotonic() + timeout
        while not future.done():
            if time.monotonic() > end:
                raise AssertionError(f"no response from {what} within {timeout} s")
            time.sleep(0.005)
        return future.result()

    def close(self):
        self._seized = None
        stop_spinning(self._thread, self._stop_spin, self.executor)
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


@contextlib.contextmanager
def in_process_lockstep(namespace: str, plant: dict, controller: dict, demand: dict, ready, what: str):
    """Plant, controller and demand node in this process, in lockstep (deterministic, robust
    under CPU load) on one executor thread, with a :class:`Probe` in a separate context (as
    ``ros2 param set`` would be).  ``plant`` / ``controller`` / ``demand``: parameter
    overrides (lockstep and the sim-time wiring are added; the controller's
    ``initial_current_a`` defaults to the plant's hold current); waits for
    ``ready(plant, controller)`` up to 60 s, then yields ``(plant, controller, demand, probe)``."""
    from rclpy.parameter import Parameter

    from fuel_valve_control.ros.controller_node import ControllerNode
    from fuel_valve_control.ros.demand_node import DemandNode
    from fuel_valve_plant.ros.plant_node import PlantNode

    def params(values):
        return [Parameter(k, value=v) for k, v in values.items()]

    context = rclpy.context.Context()
    rclpy.init(context=context)
    common = {"context": context, "namespace": namespace}
    plant_node = PlantNode(**common, parameter_overrides=params({"lockstep": True, "lockstep_participants": 2, **plant}))
    controller_node = ControllerNode(**common, parameter_overrides=params(
        {"lockstep": True, "use_sim_time": True, "initial_current_a": plant_node._iq, **controller}))
    demand_node = DemandNode(**common, parameter_overrides=params({"lockstep": True, "use_sim_time": True, **demand}))
    nodes = (plant_node, controller_node, demand_node)
    executor = SingleThreadedExecutor(context=context)
    for node in nodes:
        executor.add_node(node)
    stop = threading.Event()
    thread = spin_in_thread(executor, stop)
    probe = Probe(namespace)
    try:
        probe.wait_for(lambda: ready(plant_node, controller_node), 60.0, what)
        yield plant_node, controller_node, demand_node, probe
    finally:
        probe.close()
        stop_spinning(thread, stop, executor)
        for node in nodes:
            node.destroy_node()
        rclpy.shutdown(context=context)

"""The controller node's valve-test interface (issue 12): services, latched results, baseline.

* ``~/signature_test`` and ``~/partial_stroke_test`` (std_srvs/Trigger): request a test;
  ``success`` says whether it was accepted, ``message`` why not (the refusal rules are the
  core's, :mod:`fuel_valve_control.core.valve_tests`).  The call answers at once; the test
  then runs in the control loop for tens of seconds (signature) or a few (partial stroke).
* ``valve_test`` (std_msgs/String, latched, :data:`~fuel_valve_control.common.contract.VALVE_TEST`):
  one JSON document per finished run (completed or aborted): ``test``, ``status``, ``reason``,
  ``figures`` (name -> number, unit by suffix), ``curve``, ``trace``, ``baseline``,
  ``findings``.  The recorder records it (it is in the contract's topic list) and
  ``fuel_valve_report`` plots it.
* ``/diagnostics``: the node adds :meth:`ValveTests.summary` to its key values.
* parameters: the ``tests.*`` group of the controller's schema (declared with the rest);
  ``tests.baseline_path`` names a stored result to judge runs against.
"""
from __future__ import annotations

import json
import math

from ..common import contract
from ..core.valve_tests import PARTIAL_STROKE, SIGNATURE, ValveTests, load_baselines
from . import interface as ri


def create_valve_test_interface(node, driver, lock) -> ValveTests:
    """Attach a :class:`ValveTests` to ``driver`` and give ``node`` the two services and the
    latched result topic; ``lock`` is the node's driver lock (the services take it).
    Returns the tests object (its ``running`` and ``findings`` feed the node's status)."""
    from std_msgs.msg import String
    from std_srvs.srv import Trigger

    tests = ValveTests(driver)
    path = driver.ps["tests.baseline_path"]
    if path:
        try:
            for result in load_baselines(path):
                tests.set_baseline(result)
            node.get_logger().info(f"valve tests: baseline loaded from {path}")
        except (OSError, ValueError) as exc:
            node.get_logger().error(f"valve tests: baseline {path} not used ({exc}); the first run is the baseline")
    publisher = ri.quiet_publisher(node, String, contract.VALVE_TEST)

    def publish(result: dict) -> None:
        publisher.publish(String(data=json.dumps(result, default=_finite)))
        text = (f"{result['test']} test {result['status']}" + (f": {result['reason']}" if result["reason"] else "")
                + (f"; {'; '.join(result['findings'])}" if result["findings"] else ""))
        # one call site per severity: rclpy refuses a site whose severity changes
        if result["status"] != "completed" or result["findings"]:
            node.get_logger().warn(text)
        else:
            node.get_logger().info(text)

    tests.listeners.append(publish)

    def service(name: str):
        def call(request, response):
            try:
                with lock:
                    response.success, response.message = tests.start(name)
            except Exception as exc:        # noqa: BLE001 - answer the caller; the loop is untouched
                response.success, response.message = False, f"internal error: {exc!r}"
            if response.success:
                node.get_logger().info(response.message)
            else:
                node.get_logger().warn(response.message)
            return response
        return call

    node.create_service(Trigger, "~/signature_test", service(SIGNATURE))
    node.create_service(Trigger, "~/partial_stroke_test", service(PARTIAL_STROKE))
    return tests


def _finite(x):
    """JSON for what ``json`` cannot write itself (numpy scalars); NaN stays as the JSON NaN."""
    value = float(x)
    return value if math.isfinite(value) else None

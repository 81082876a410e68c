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


class ValveTestInterface:
    """The node side of the valve tests.  The services and the latched topic exist for the
    node's whole life; the core's :class:`ValveTests` belongs to one driver, so the managed
    node :meth:`attach` es a new one at every ``configure`` (and :meth:`detach` es it at
    ``cleanup``): unconfigured, a request is refused and the status has no test keys.
    ``lock`` is the node's driver lock (the services take it)."""

    def __init__(self, node, lock):
        from std_msgs.msg import String
        from std_srvs.srv import Trigger
        self._node, self._lock, self._string = node, lock, String
        #: the tests of the configured driver (None while unconfigured)
        self.tests: ValveTests | None = None
        self._publisher = ri.quiet_publisher(node, String, contract.VALVE_TEST)
        node.create_service(Trigger, "~/signature_test", self._service(SIGNATURE))
        node.create_service(Trigger, "~/partial_stroke_test", self._service(PARTIAL_STROKE))

    def attach(self, driver) -> ValveTests:
        """A :class:`ValveTests` on ``driver`` (the node's configure), with the stored baseline
        (``tests.baseline_path``) when there is one."""
        log = self._node.get_logger()
        tests = ValveTests(driver)
        path = driver.ps["tests.baseline_path"]
        if path:
            try:
                for result in load_baselines(path):
                    tests.set_baseline(result)
                log.info(f"valve tests: baseline loaded from {path}")
            except (OSError, ValueError) as exc:
                log.error(f"valve tests: baseline {path} not used ({exc}); the first run is the baseline")
        tests.listeners.append(self._publish)
        self.tests = tests
        return tests

    def detach(self) -> None:
        self.tests = None

    @property
    def running(self) -> str | None:
        return None if self.tests is None else self.tests.running

    @property
    def findings(self) -> list[str]:
        return [] if self.tests is None else self.tests.findings

    def summary(self) -> dict:
        return {} if self.tests is None else self.tests.summary()

    def _publish(self, result: dict) -> None:
        self._publisher.publish(self._string(data=json.dumps(result, default=_finite)))
        text = (f"{result['test']} test {result['status']}" + (f": {result['reason']}" if result["reason"] else "")
                + (f"; {'; '.join(result['findings'])}" if result["findings"] else ""))
        # one call site per severity: rclpy refuses a site whose severity changes
        if result["status"] != "completed" or result["findings"]:
            self._node.get_logger().warn(text)
        else:
            self._node.get_logger().info(text)

    def _service(self, name: str):
        node = self._node

        def call(request, response):
            try:
                with self._lock:
                    if self.tests is None:
                        response.success, response.message = False, "refused: the controller is not configured"
                    else:
                        response.success, response.message = self.tests.start(name)
            except Exception as exc:        # noqa: BLE001 - answer the caller; the loop is untouched
                response.success, response.message = False, f"internal error: {exc!r}"
            if response.success:
                node.get_logger().info(response.message)
            else:
                node.get_logger().warn(response.message)
            return response
        return call


def _finite(x):
    """JSON for what ``json`` cannot write itself (numpy scalars); NaN stays as the JSON NaN."""
    value = float(x)
    return value if math.isfinite(value) else None

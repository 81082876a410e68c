"""The plant node's drive watchdog check against the command callback clearing the awaited
sample meanwhile (``PlantNode._check_watchdog`` on the tick thread, ``on_command`` ->
``_command_arrived`` on the executor thread, not under the tick's lock).

Found in stop 18 (h22t): under load the real-time tick raised ``TypeError: unsupported operand
type(s) for -: 'float' and 'NoneType'`` -- the check read ``_awaiting_since`` twice (``is None``,
then the subtraction) and the callback cleared it in between -- and the plant latched an
internal drive fault (``test_safety_nodes``' stall test failed with "the drive reports an
internal fault").  The interleaving is made deterministic here: the attribute reads as a
sample time once and as cleared on every later read, as the callback would leave it.
"""
from __future__ import annotations

import pytest

pytest.importorskip("rclpy")


class _ClearedAfterFirstRead:
    """Stands in for a node whose command callback clears ``_awaiting_since`` right after the
    tick thread's first read of it."""

    def __init__(self, sample_time: float):
        self._reads = 0
        self._sample_time = sample_time
        self._watchdog_off = False
        self._watchdog_trips = 0
        self._command_timeout = 5e-3
        self.plant = type("P", (), {"time": 1.0})()
        self.reported = 0

    @property
    def _awaiting_since(self):
        self._reads += 1
        return self._sample_time if self._reads == 1 else None

    def get_logger(self):
        class _Log:
            def error(self, *args, **kwargs):
                pass
        return _Log()

    def report_state(self):
        self.reported += 1


@pytest.mark.parametrize("sample_time", [1.0, 0.99])     # answered in time / long overdue at the read
def test_a_command_arriving_during_the_watchdog_check_is_no_drive_fault(sample_time):
    from fuel_valve_plant.ros.plant_node import PlantNode
    node = _ClearedAfterFirstRead(sample_time)
    PlantNode._check_watchdog(node, 1e-3)           # raised TypeError before the fix
    # judged on the one value read: 1 ms unanswered keeps the drive on, 11 ms trips it
    assert node._watchdog_off == (sample_time < 0.995)
    assert node._watchdog_trips == node.reported == (1 if sample_time < 0.995 else 0)

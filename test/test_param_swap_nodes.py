"""Issue 13.6 over DDS: a parameter change through the controller node's parameter service,
during motion, is swapped in at a period boundary without a skipped period, and a refused
change leaves everything as it was.

The three nodes run in this process in lockstep (deterministic: every plant tick is one
control period, robust under CPU load); the changes come from a separate context
(``ros_probe.Probe``), as ``ros2 param set`` would.  The controller's driver is observed by
wrapping its ``step``: the loop time of every period, the law in force before and after it.
No speed is asserted: the wall-time gap between periods around the change is printed.
ROS-free detail (atomicity, the swap policy): test_param_swap.py.
"""
from __future__ import annotations

import time

import pytest

pytestmark = [pytest.mark.ros]

rclpy = pytest.importorskip("rclpy")


from ros_probe import in_process_lockstep  # noqa: E402

NS = "/swap"


@pytest.fixture
def moving():
    """Plant, controller (observer_ff) and demand node in lockstep, the valve following a
    40 ± 10 % sine at 1 Hz (always moving); the probe sets parameters."""
    with in_process_lockstep(
            NS, dict(initial_position_rad=0.4 * 1.0472, start_held=True), dict(mode="observer_ff"),
            dict(profile="sine", offset=40.0, amplitude=10.0, frequency_hz=1.0),
            lambda plant, controller: controller.driver is not None and controller.driver.last.state == "running",
            "the lockstep loop running") as (_, controller, _, probe):
        yield controller, probe


def test_a_parameter_change_during_motion_swaps_at_a_period_boundary_and_a_refused_one_changes_nothing(moving):
    controller, probe = moving
    drv = controller.driver
    periods: list[tuple] = []           # (loop time s, law before, law after, wall time s)
    real_step = drv.step

    def step(t):
        before = drv.controller.law
        out = real_step(t)
        periods.append((t, before, drv.controller.law, time.monotonic(), out.enable))
        return out
    drv.step = step                     # the node calls self.driver.step: observed from now on
    probe.wait_for(lambda: len(periods) > 200, 60.0, "periods before the change")
    old_law, old_ps = drv.controller.law, drv.ps

    # accepted: a law replacement (mode) during motion
    res = probe.set_params("controller", {"mode": "observer_fc"}, timeout=15.0)
    assert res[0].successful, res[0].reason
    requested = len(periods)
    probe.wait_for(lambda: not drv.params_pending, 60.0, "the swap")
    probe.wait_for(lambda: len(periods) > requested + drv.param_swap_max_wait + 100, 120.0, "periods after the swap")
    assert drv.ps["mode"] == "observer_fc" and drv.controller.law is not old_law

    # refused: one invalid value in the request refuses all of it, nothing changes
    swapped_ps, swapped_law, swaps = drv.ps, drv.controller.law, drv.law_swaps
    res = probe.set_params("controller", {"mode": "observer_ff", "limits.continuous_current_a": 39.0}, timeout=15.0,
                           atomically=True)
    assert not res[0].successful and "continuous" in res[0].reason
    n_refused = len(periods)
    probe.wait_for(lambda: len(periods) > n_refused + 200, 60.0, "periods after the refused change")
    drv.step = real_step
    assert drv.ps is swapped_ps and drv.controller.law is swapped_law and drv.law_swaps == swaps
    assert not drv.params_pending
    assert probe.get_params("controller", ["mode", "limits.continuous_current_a"]) == [
        "observer_fc", old_ps["limits.continuous_current_a"]]

    # no period skipped nor run twice: consecutive loop times one period apart, drive on
    times = [p[0] for p in periods]
    gaps = [b - a for a, b in zip(times, times[1:])]
    assert all(abs(g - drv.period) < 1e-6 for g in gaps), sorted(set(round(g, 6) for g in gaps))[:10]
    assert all(p[4] for p in periods)
    # the law changed once, inside one period (at its start: that period ran the new law)
    changes = [i for i, p in enumerate(periods) if p[1] is not p[2]]
    assert len(changes) == 1, changes
    i = changes[0]
    assert periods[i][1] is old_law and all(p[2] is old_law for p in periods[:i])
    assert all(p[1] is periods[i][2] and p[2] is periods[i][2] for p in periods[i + 1:])
    assert i - requested <= drv.param_swap_max_wait + 5
    wall = [b[3] - a[3] for a, b in zip(periods, periods[1:])]
    near = wall[max(requested - 50, 0):requested + 50]
    print(f"{len(periods)} lockstep periods, swap {i - requested} periods after the request; wall-time gap "
          f"between periods: max {1e3 * max(wall):.1f} ms overall, {1e3 * max(near):.1f} ms around the request")

"""The node suite over DDS: plant, controller and demand as real subprocesses started through
their installed executables (SPEC §4), observed and driven from the test through rclpy.

These tests must pass on a loaded 2-core machine.  Tests whose subject is not timing run in
lockstep (simulated time, the plant owns ``/clock`` and advances one period per command; the
test's probe sends one demand per tick): a starved process slows the run down instead of
tripping a real-time timeout.  Only the tests whose subject is real-time behaviour run in real
time, with generous margins: the real-time run itself, the faults raised by *silence* (a
stale demand, a resolver dropout), which a lockstep loop cannot see because it waits, and
foreign messages injected on the loop topics (they could displace a lockstep sample).  The
valve-seized rig also runs in real time: the test's own thread plays the plant there (with a
1 s resolver timeout, so a descheduled thread cannot trip it).  The loop's real-time figures
are measured by benchmarks/ros_loop.py, not here.
"""
from __future__ import annotations

import io
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ros_probe import Probe  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]

from fuel_valve_control.tools import demo as suite, sim  # noqa: E402
from fuel_valve_control.tools.launcher import Launcher, executable  # noqa: E402
from fuel_valve_control.tools.run_plan import LOCKSTEP, REAL_TIME, plan_run  # noqa: E402
from fuel_valve_control.tools.scenarios import load_scenario  # noqa: E402
from fuel_valve_control.common import contract  # noqa: E402
from fuel_valve_plant.physics.friction import friction_levels  # noqa: E402
from fuel_valve_plant.physics.params import PLANT_SPEC  # noqa: E402

STROKE = 1.0471975511965976
BIN = Path(sys.executable).parent
#: the first wait of a rig includes its node processes' start (imports: 30 s was exceeded at
#: load average 17 with two CPU hogs beside the suite)
START_S = 120.0


def test_nodes_are_installed_executables():
    for name in ("plant", "controller", "demand", "recorder", "fuel_valve_sim", "fuel_valve_report"):
        assert (BIN / name).is_file(), f"console script {name} missing in {BIN}"
    assert executable("plant") == [str(BIN / "plant")]


# ------------------------------------------------------------------------------ lockstep
@pytest.fixture(scope="module")
def lockstep_runs():
    """step_small twice in lockstep, with the true valve trajectory recorded."""
    sc = load_scenario("step_small")
    runs = []
    for k in range(2):
        plan = plan_run(sc, LOCKSTEP, duration_s=1.2)
        out = io.StringIO()
        summary = suite.run(plan, f"/lockstep{k}", out=out, record_truth=True)
        assert summary["ok"], out.getvalue()
        runs.append((summary, out.getvalue()))
    return runs


def test_lockstep_runs_are_deterministic(lockstep_runs):
    a, b = (np.array(s["truth"]) for s, _ in lockstep_runs)
    # one sample per period, exactly to stop_after_s; the test's own monitor may lose a few
    # samples when it is descheduled (telemetry keeps 10), so compare on the common stamps
    assert a[-1, 0] == b[-1, 0] == 1.2
    common, ia, ib = np.intersect1d(a[:, 0], b[:, 0], return_indices=True)
    assert len(common) > 0.98 * 1201
    np.testing.assert_array_equal(a[ia], b[ib])
    assert np.ptp(a[:, 1]) > 0.015                # and the valve did move (20 -> 22 % = 0.021 rad)


def test_lockstep_start_handshake_loses_no_first_tick(lockstep_runs):
    # the plant starts once the controller's hello (its first drive_enable, sent when it can
    # answer) has arrived: tick 0 is answered, not re-published after the 1 s resend timeout
    for summary, _ in lockstep_runs:
        log = (Path(summary["run_dir"]) / "plant.log").read_text()
        assert "lockstep: participants connected, starting" in log, log
        assert "no command for t = 0.000 s" not in log, log


def test_lockstep_reproduces_the_offline_simulator(lockstep_runs):
    summary, text = lockstep_runs[0]
    truth = np.array(summary["truth"])
    offline = sim.run("step_small")
    idx = np.round(truth[:, 0] * 1000).astype(int)
    idx = idx[idx < len(offline.log)]
    diff = truth[:len(idx), 1] - offline.column("position_rad")[idx]
    # same core classes, same order of operations: identical to floating-point precision
    assert np.max(np.abs(diff)) < 1e-9
    assert "running" in text and summary["worst_level"] < 2


# ------------------------------------------------------------------------------ real time
def test_demand_step_moves_the_valve_in_real_time():
    # resolver timeout 1 s instead of 20 ms: CI shares 2 cores with other work, and a starved
    # process must not trip this test (measured: a 336 ms gap on the loaded machine; the fault
    # itself is tested below and in test_driver.py)
    plan = plan_run(load_scenario("step_small"), REAL_TIME, duration_s=3.0,
                    controller_overrides={"faults.resolver_timeout_s": 1.0, "pressure.timeout_s": 1.0})
    out = io.StringIO()
    summary = suite.run(plan, "/realtime", out=out)
    text = out.getvalue()
    assert summary["ok"], text
    assert summary["worst_level"] < 2, summary["faults"]
    # the status line reports demand and position; 22 % demanded
    assert "demand  22.00 %" in summary["final_status"]
    # the valve stops near the integrator deadband, whose edge depends on the loop's timing
    # here; under a loaded machine a late period can add a breakaway, so the bound is two
    # stick-slip jumps of the plant (2 x 4.6e-3 rad = 0.88 % at max Δp).  Accuracy itself is
    # asserted in lockstep and offline (measured 0.29-0.30 % here on a quiet machine, 0.44 %
    # in a loaded CI run, 0.24 % offline; plateau accuracy is issue 14's open target)
    ps = PLANT_SPEC.defaults()
    jump_pct = 100.0 * friction_levels(ps).stick_slip_jump_rad(ps["coupling.stiffness_nm_per_rad"]) / STROKE
    assert abs(summary["final_error_pct"]) < 2.0 * jump_pct, text
    loop = summary["loop"]
    assert loop["ticks"] > 2000 and loop["commands"] > 500, (summary["loop_source"], loop)


# ------------------------------------------------------------------------------ faults
def _start_rig(namespace: str, run_dir: Path, lockstep: bool):
    """Plant (closed, drive off) and controller (demand in mA, NE43) as processes; the test's
    probe is the supervisor (and, in lockstep, the demand participant).  Yields (suite, probe)."""
    # real time: a resolver timeout of 1 s instead of 20 ms, so a process starved by a loaded
    # machine (measured: 334 ms gaps with two CPU hogs) does not trip the rig by accident
    # lockstep: the plant runs until the tests are done (stop_after_s 0), and the controller
    # publishes its status more often: simulated time runs at a fraction of wall time on a
    # loaded machine (measured 0.3x with the machine shared)
    plan = plan_run(None, LOCKSTEP if lockstep else REAL_TIME,
                    plant_overrides={"stop_after_s": 0.0} if lockstep else {},
                    controller_overrides={"demand_source": "ma", "faults.tracking_error_time_s": 0.3,
                                          "faults.resolver_timeout_s": 0.1 if lockstep else 1.0,
                                          # real time: a starved plant delays Δp readings too (measured 341 ms)
                                          "pressure.timeout_s": 0.1 if lockstep else 1.0,
                                          **({"diagnostics_rate_hz": 20.0} if lockstep else {})})
    s = Launcher(plan, namespace, run_dir)       # /clock participants: controller and the probe
    s.start(("plant", "controller"))
    probe = Probe(namespace, keep_all=(contract.CURRENT_COMMAND, contract.DRIVE_ENABLE), lockstep=lockstep)
    try:
        probe.set_demand(4.0 + 16.0 * 0.30, contract.DEMAND_MA)      # 30 %
        probe.wait_for(lambda: probe.driver_level() is not None, START_S, "the controller's status")
        _healthy(probe)
        yield s, probe
    finally:
        probe.close()
        codes = s.stop()
        assert all(c in (0, -2) for c in codes.values()), (codes, s.log_tail("plant"), s.log_tail("controller"))


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    """The lockstep rig: fault logic, services, parameters and diagnostics over DDS."""
    yield from _start_rig("/rig", tmp_path_factory.mktemp("rig"), lockstep=True)


@pytest.fixture(scope="module")
def realtime_rig(tmp_path_factory):
    """The real-time rig, for the faults raised by silence."""
    yield from _start_rig("/rtrig", tmp_path_factory.mktemp("rtrig"), lockstep=False)


def _healthy(probe, timeout=20.0):
    """Each fault test starts from a running loop holding 30 %, whatever the previous left
    (a latched fault is reset, as often as it takes: under heavy load the real-time plant can
    integrate several periods between two closely stamped samples while the spring shuts the
    valve, which reads as an implausible jump)."""
    probe.set_demand(4.0 + 16.0 * 0.30, contract.DEMAND_MA)

    def ready():
        if probe.driver_level() == 2:
            probe.trigger("controller/reset")
            time.sleep(0.2)
        return probe.driver_level() == 0 and _near(probe, 0.30, 0.02)
    probe.wait_for(ready, timeout, "healthy at 30 %")


@pytest.fixture
def healthy(rig):
    _healthy(rig[1])
    yield rig
    # pause the lockstep loop between tests (it waits for the next demand): it would otherwise
    # run flat out and take the CPU from the real-time tests after it
    rig[1].set_demand(None)


@pytest.fixture
def realtime_healthy(realtime_rig):
    _healthy(realtime_rig[1])
    return realtime_rig


def _near(probe, frac, tol=0.01):
    angle = probe.valve_angle()
    return angle is not None and abs(angle - frac * STROKE) < tol * STROKE


def _assert_fail_safe(probe, t0, fault_words, timeout=3.0):
    """The fault latched: ERROR naming it, drive disabled, zero current, the spring closes."""
    probe.wait_for(lambda: probe.driver_level() == 2, timeout, f"ERROR ({fault_words})")
    st = probe.driver_status()
    assert any(w in st.message for w in fault_words), st.message
    probe.wait_for(lambda: probe.get(contract.DRIVE_ENABLE) is not None and not probe.get(contract.DRIVE_ENABLE).data,
                   2.0, "drive_enable false")
    probe.wait_for(lambda: probe.valve_angle() < 0.02 * STROKE, 2.0, "valve closed by the spring")
    # the commands since the valve closed (a count, not a 40 ms window: a starved probe can
    # receive none in 40 ms; CI saw that once)
    closed = time.monotonic()
    probe.wait_for(lambda: len(probe.since(contract.CURRENT_COMMAND, closed)) >= 5, 30.0, "commands after the close")
    late = [m.data for m in probe.since(contract.CURRENT_COMMAND, closed)]
    assert late and all(c == 0.0 for c in late), late[-5:]


def _reset_and_recover(probe):
    """The reset is accepted (the cause is gone), then the loop holds 30 % again."""
    probe.wait_for(lambda: probe.trigger("controller/reset").success, 10.0, "a successful reset")
    _healthy(probe)


def test_trip_service_closes_the_valve_and_reset_rearms(healthy):
    _, probe = healthy
    resp = probe.trigger("controller/trip")
    assert resp.success and "spring" in resp.message
    t0 = time.monotonic()
    _assert_fail_safe(probe, t0, ("trip",))
    time.sleep(0.3)
    assert probe.driver_level() == 2                  # latched: stays off without a reset
    _reset_and_recover(probe)


@pytest.mark.parametrize("bad_ma, words", [(3.0, ("NE43",)), (21.5, ("NE43",)), (math.nan, ("finite",))])
def test_ne43_signal_failure_latches(healthy, bad_ma, words):
    _, probe = healthy
    probe.set_demand(bad_ma, contract.DEMAND_MA)
    _assert_fail_safe(probe, time.monotonic(), words)
    probe.set_demand(4.0 + 16.0 * 0.30, contract.DEMAND_MA)
    time.sleep(0.1)
    assert probe.driver_level() == 2                  # a good signal alone does not clear it
    _reset_and_recover(probe)


def _resolver_fault(probe, injection, words):
    results = probe.set_params("plant", {"fault_injection": injection})
    assert results[0].successful, results[0].reason
    _assert_fail_safe(probe, time.monotonic(), words)
    assert probe.set_params("plant", {"fault_injection": "none"})[0].successful


def test_implausible_resolver_latches_and_resets(healthy):
    _resolver_fault(healthy[1], "resolver_noise_burst", ("jumped", "stroke", "disagree"))
    _reset_and_recover(healthy[1])


@pytest.fixture
def seized(tmp_path, request):
    """A controller alone, its plant played by the test: a valve seized at 30 % (resolver
    readings consistent, so only the tracking and current supervision can see it; the test's
    resolver has a rigid coupling, hence the widest twist margin).  ``request.param``: more
    controller overrides (limits only tighten at run time, so they are set at start-up)."""
    plan = plan_run(None, REAL_TIME, controller_overrides={
        "faults.tracking_error_time_s": 0.3, "faults.i2t_fault_time_s": 0.5,
        "faults.resolver_disagreement_margin_rad": 0.2, **getattr(request, "param", {}),
        # the test plays a drive without a command watchdog (and without a drive_status)
        "faults.drive_command_timeout_s": 0.0,
        # the test's Python threads play the resolver and the supervisor: allow them gaps
        # (measured: a 0.62 s demand gap with two CPU hogs on the shared machine)
        "faults.resolver_timeout_s": 1.0, "demand_timeout_s": 3.0,
        # the test's Δp publisher is created after its resolver one: its match can come more
        # than 0.1 s after the loop's first period, and "no pressure differential reading
        # received" then stays latched (a warning, level 1) until a reset, so the rig never
        # reported "running" (the 120 s start-up timeouts of test_tracking_error_latches /
        # test_i2t_budget_latches on a slow machine, stop-13 CI)
        "pressure.timeout_s": 3.0})
    s = Launcher(plan, "/seized", tmp_path)
    s.start(("controller",))
    probe = Probe("/seized", keep_all=(contract.CURRENT_COMMAND,))
    try:
        probe.seize_valve(0.30 * STROKE, rate_hz=250.0)      # a Python thread: a modest rate
        probe.set_demand(30.0)
        probe.wait_for(lambda: probe.driver_level() == 0, START_S, "controller running")
        yield s, probe
    finally:
        probe.close()
        s.stop()


def _assert_latched_off(probe, words, timeout):
    probe.wait_for(lambda: probe.driver_level() == 2, timeout, f"ERROR ({words})")
    st = probe.driver_status()
    assert any(w in st.message for w in words), st.message
    probe.wait_for(lambda: probe.get(contract.DRIVE_ENABLE) is not None and not probe.get(contract.DRIVE_ENABLE).data,
                   2.0, "drive_enable false")
    # the commands since the valve closed (a count, not a 40 ms window: a starved probe can
    # receive none in 40 ms; CI saw that once)
    closed = time.monotonic()
    probe.wait_for(lambda: len(probe.since(contract.CURRENT_COMMAND, closed)) >= 5, 30.0, "commands after the close")
    late = [m.data for m in probe.since(contract.CURRENT_COMMAND, closed)]
    assert late and all(c == 0.0 for c in late), late[-5:]


def test_tracking_error_latches(seized):
    _, probe = seized
    probe.set_demand(60.0)                             # 0.31 rad away, beyond the 0.1 rad limit
    _assert_latched_off(probe, ("tracking",), 5.0)
    probe.set_demand(30.0)
    assert probe.trigger("controller/reset").success
    probe.wait_for(lambda: probe.driver_level() == 0, 3.0, "OK after reset")


@pytest.mark.parametrize("seized", [{"faults.tracking_error_time_s": 30.0}], indirect=True)
def test_i2t_budget_latches(seized):
    _, probe = seized
    t0 = time.monotonic()
    probe.set_demand(60.0)                             # the loop asks for full current, for ever
    # the budget integrates the loop's periods: a starved loop (a seizing probe thread and a
    # controller sharing two loaded cores) takes longer than the quiet machine's ~3 s
    _assert_latched_off(probe, ("I2t",), 30.0)
    peak = [m.data for m in probe.since(contract.CURRENT_COMMAND, t0)]
    assert max(abs(c) for c in peak) <= 37.0 + 1e-9    # never beyond the peak rating meanwhile
    probe.set_demand(30.0)
    probe.wait_for(lambda: probe.trigger("controller/reset").success, 5.0, "reset")


def test_parameters_set_and_reject(healthy):
    _, probe = healthy
    ok = probe.set_params("controller", {"mode": "pi"})
    assert ok[0].successful
    assert probe.get_params("controller", ["mode"]) == ["pi"]
    bad = probe.set_params("controller", {"mode": "bang_bang"})
    assert not bad[0].successful and "mode" in bad[0].reason
    assert probe.get_params("controller", ["mode"]) == ["pi"]             # no state change
    ro = probe.set_params("controller", {"loop_rate_hz": 500.0})
    assert not ro[0].successful                                             # read-only (gains designed for it)
    assert probe.set_params("controller", {"mode": "observer_ff"})[0].successful
    for name, value in (("pressure_differential_kpa", 9000.0), ("friction_scale", -1.0),
                        ("fault_injection", "gremlins")):
        res = probe.set_params("plant", {name: value})
        assert not res[0].successful and res[0].reason, (name, res[0].reason)
    assert probe.get_params("plant", ["pressure_differential_kpa", "friction_scale"]) == [6206.0, 1.0]
    assert probe.set_params("plant", {"pressure_differential_kpa": 3103.0})[0].successful
    assert probe.get_params("plant", ["pressure_differential_kpa"]) == [3103.0]
    assert probe.set_params("plant", {"pressure_differential_kpa": 6206.0})[0].successful
    probe.wait_for(lambda: probe.driver_level() == 0 and _near(probe, 0.30, 0.02), 5.0, "still holding 30 %")


def test_diagnostics_content(healthy):
    _, probe = healthy
    # holding 30 % as reported: run alone, the fixture's valve may still be on its way there
    probe.wait_for(lambda: probe.driver_level() == 0 and _near(probe, 0.30, 0.02)
                   and abs(float(probe.driver_values().get("position_pct", "nan")) - 30.0) < 2.0,
                   15.0, "OK, holding 30 % on /diagnostics")
    values = probe.driver_values()
    for key in ("state", "mode", "demand_pct", "position_pct", "tracking_error_rad", "current_a",
                "limit_cycle_estimate_rad", "friction_valve_estimate_nm", "friction_trend", "i2t_budget_used",
                "faults", "compute_mean_ms"):
        assert key in values, key
    assert values["state"] == "running" and values["faults"] == "none"
    assert abs(float(values["position_pct"]) - 30.0) < 2.0
    plant = probe.wait_for(lambda: probe.status("plant: loop"), 10.0, "the plant's status on /diagnostics")
    pv = {kv.key: kv.value for kv in plant.values}
    assert float(pv["commands"]) > 0 and float(pv["plant_time_s"]) > 0.0 and "rtt_median_ms" in pv


def test_node_rejects_invalid_parameter_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("/**:\n  ros__parameters:\n    pressure_differential_kpa: -5.0\n")
    proc = subprocess.run([str(BIN / "plant"), "--ros-args", "--params-file", str(bad)], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2
    assert "pressure_differential_kpa" in proc.stdout + proc.stderr


# ------------------------------------------------------------------------------ real-time faults
# last in the module, so the real-time rig runs alone (module fixtures live to the module's end)
def test_silent_demand_trips_and_resets(realtime_healthy):
    _, probe = realtime_healthy
    probe.set_demand(None)
    _assert_fail_safe(probe, time.monotonic(), ("demand",))
    probe.set_demand(4.0 + 16.0 * 0.30, contract.DEMAND_MA)
    _reset_and_recover(realtime_healthy[1])


def test_resolver_dropout_latches_and_resets(realtime_healthy):
    _resolver_fault(realtime_healthy[1], "resolver_dropout", ("resolver sample",))
    _reset_and_recover(realtime_healthy[1])


def test_malformed_inputs_never_crash_or_drive_unsafely(realtime_healthy):
    # real time: foreign messages on the loop topics (keep-last 1) can displace the plant's
    # own resolver sample, which would stall a lockstep loop for good (the plant does not
    # re-send); in real time the next sample follows 1 ms later
    s, probe = realtime_healthy
    from sensor_msgs.msg import JointState
    t0 = time.monotonic()
    for value in (math.nan, math.inf, -math.inf, 1e308, -1e308, 0.0, 25.0):
        probe.publish_raw(contract.DEMAND_MA, value)
        probe.publish_raw(contract.DEMAND, value)            # not the selected source: ignored
        time.sleep(0.02)     # loop topics keep only the newest sample: let each one be taken
    for _ in range(2000):                              # a burst
        probe.publish_raw(contract.DEMAND_MA, 12.0)
    bad = JointState(name=["something_else"], position=[1.0])
    probe.pub_resolver.publish(bad)
    probe.pub_resolver.publish(JointState(name=list(contract.JOINT_NAMES), position=[math.nan, math.inf]))
    time.sleep(0.5)
    assert not s.failed(), s.log_tail("controller")
    commands = [m.data for m in probe.since(contract.CURRENT_COMMAND, t0)]
    assert commands and all(math.isfinite(c) and abs(c) <= 37.0 for c in commands)
    probe.wait_for(lambda: probe.driver_level() == 2, 2.0, "fault from the malformed inputs")
    probe.set_demand(4.0 + 16.0 * 0.30, contract.DEMAND_MA)
    _reset_and_recover(probe)

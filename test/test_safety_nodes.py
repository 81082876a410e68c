"""Fail-safe behaviour of the nodes over DDS (issue 13): what only a node can do.

* an exception in the controller node's loop latches a fault, switches the drive off and is
  reported on ``/diagnostics`` while the node keeps running (the controller runs in this test
  process so its law can be broken on purpose; plant as a process);
* the plant's drive watchdog: a killed (SIGKILL) or stalled (SIGSTOP) controller cannot leave
  the last current applied.

Real time: the watchdog is a real-time mechanism (lockstep time stands still without
commands).  Margins are generous for a loaded 2-core machine; the figures are printed.
"""
from __future__ import annotations

import os
import signal
import time

import pytest

from ros_probe import Probe, in_process_controller

from fuel_valve_control.common import contract
from fuel_valve_control.common.contract import STROKE_RAD
from fuel_valve_control.tools.launcher import Launcher
from fuel_valve_control.tools.run_plan import REAL_TIME, plan_run

pytestmark = [pytest.mark.ros, pytest.mark.slow]

#: data sheet close time of the full stroke (SPEC §6), s
CLOSE_TIME_S = 0.120


def _plant_status(probe):
    return probe.status("plant: loop")


def _plant_values(probe) -> dict:
    """The plant's loop diagnostics (watchdog trips, missed periods, ...) as a dict."""
    st = _plant_status(probe)
    return {} if st is None else {kv.key: kv.value for kv in st.values}


def _level(st):
    return None if st is None else (st.level[0] if isinstance(st.level, bytes) else int(st.level))


def _hold(probe, pct, timeout=30.0, settle_s=0.0):
    """Demand ``pct`` % and wait until the valve is within 1 % of stroke of it (and, with
    ``settle_s`` > 0, has also moved less than :data:`SETTLED_RAD` over the last ``settle_s``
    s of ground truth: at rest, not still approaching)."""
    probe.set_demand(pct)

    def ready():
        if probe.driver_level() == 2:
            probe.trigger("controller/reset")
            time.sleep(0.2)
        a = probe.valve_angle()
        near = probe.driver_level() in (0, 1) and a is not None and abs(a - pct / 100 * STROKE_RAD) < 0.01 * STROKE_RAD
        if not near or settle_s <= 0.0:
            return near
        recent = probe.since(contract.JOINT_STATES, time.monotonic() - settle_s)
        if len(recent) < 10:            # the fixture keeps ground truth (keep_all)
            return False
        angles = [m.position[1] for m in recent]
        return max(angles) - min(angles) < SETTLED_RAD
    probe.wait_for(ready, timeout, f"holding {pct} %" + (f" (at rest for {settle_s:g} s)" if settle_s else ""))


#: "at rest" for :func:`_hold`: the valve moved less than this over its settle time, rad
#: (about 10 resolver counts; a valve still approaching its demand moves 0.2-0.3 rad/s)
SETTLED_RAD = 1e-3


#: the first wait of a fixture includes its node processes' start (imports under load)
START_S = 120.0


@pytest.fixture
def realtime(tmp_path):
    """Plant and controller processes in real time (resolver timeout 1 s, demand timeout 5 s:
    a starved process -- the plant, or the probe that sends the demand -- must not trip the
    controller here; seen: "no valid demand for 0.61 s" at load average 16), the probe as the
    demand supervisor."""
    plan = plan_run(None, REAL_TIME, controller_overrides={"faults.resolver_timeout_s": 1.0, "demand_timeout_s": 5.0,
                                                           "diagnostics_rate_hz": 10.0})
    s = Launcher(plan, "/wd", tmp_path)
    s.start(("plant", "controller"))
    probe = Probe("/wd", keep_all=(contract.JOINT_STATES, contract.DRIVE_STATUS))
    try:
        # the processes' start (imports) first, with its own generous wait: the tests' 30 s
        # waits for a hold were used up by it at load average 17 (driver status still None)
        probe.wait_for(lambda: probe.driver_level() is not None, START_S, "the controller's status")
        yield s, probe
    finally:
        probe.close()
        for name in ("controller",):
            proc = s.procs.get(name)
            if proc is not None and proc.poll() is None:
                os.kill(proc.pid, signal.SIGCONT)
        s.stop()


def _truth_since(probe, t0_mono):
    """(stamp s, valve rad) of the plant's ground truth received since ``t0_mono``."""
    return [(m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec, m.position[1])
            for m in probe.since(contract.JOINT_STATES, t0_mono)]


def test_killed_controller_the_plant_watchdog_lets_the_spring_close_the_valve(realtime):
    s, probe = realtime
    _hold(probe, 50.0)
    t_kill, mono = time.time(), time.monotonic()
    os.kill(s.procs["controller"].pid, signal.SIGKILL)
    probe.wait_for(lambda: probe.valve_angle() < 0.02 * STROKE_RAD, 3.0, "the valve closed by the spring")
    closed = [t for t, v in _truth_since(probe, mono) if v < 0.02 * STROKE_RAD]
    took = closed[0] - t_kill
    print(f"valve at 50 % closed {took * 1e3:.0f} ms after SIGKILL of the controller "
          f"(data sheet close time {CLOSE_TIME_S * 1e3:.0f} ms + 5 ms watchdog on a quiet machine)")
    # Without the watchdog the valve stays at 50 % for good (v1: 10 s+).  The bound is wall time
    # on a possibly loaded machine: a CI run whose plant process was starved took 1.06 s (the
    # plant steps at most 10 periods per tick, so a starved plant's physics runs slower than the
    # wall clock).  The spring close time itself is asserted offline (test_plant_physics.py,
    # test_closed_loop.py).
    assert took < 2.5, took
    probe.wait_for(lambda: _level(_plant_status(probe)) == 2, 3.0, "plant drive fault on /diagnostics")
    assert "watchdog" in _plant_status(probe).message


def test_stalled_controller_does_not_run_the_valve_away(realtime):
    s, probe = realtime
    _hold(probe, 30.0)
    pid = s.procs["controller"].pid
    mono = time.monotonic()
    probe.set_demand(40.0)
    # stall the controller while it accelerates the valve (a large command): without a drive
    # watchdog that current stays applied for the whole stall (measured on main: up to 89 %)
    probe.wait_for(lambda: (probe.get(contract.CURRENT_COMMAND) is not None
                            and probe.get(contract.CURRENT_COMMAND).data > 10.0), 5.0, "a large command")
    os.kill(pid, signal.SIGSTOP)
    time.sleep(0.05)
    os.kill(pid, signal.SIGCONT)
    time.sleep(1.0)
    valve = [v for _, v in _truth_since(probe, mono)]
    peak_pct = 100.0 * max(valve) / STROKE_RAD
    print(f"peak {peak_pct:.2f} % for a 30 -> 40 % step with a 50 ms controller stall")
    # the drive coasts after the watchdog (reflected motor inertia: ~6 % of stroke at full
    # slew), it is not driven on: far from the 89 % of a drive that kept the stalled command.
    # Quiet machine: ~44 %.  A starved plant checks the watchdog once per tick but may step up
    # to 10 periods per tick, so up to 5 + 10 ms of the stale command (a load-average-30 run:
    # 49 %); 55 % still fails a drive that kept its command for 20 ms (53 % from a hold at 40 %).
    assert peak_pct < 55.0, peak_pct
    # the loop recovers on its own: the plant reported its watchdog trip, the controller
    # re-armed and re-enabled the drive
    _hold(probe, 40.0, timeout=20.0)


def _states_since(probe, t0_mono) -> list[int]:
    return [int(m.data) for m in probe.since(contract.DRIVE_STATUS, t0_mono)]


def _stall_cycles(probe, pid) -> tuple[int, str | None]:
    """12 ms SIGSTOP stalls of the controller ``pid`` at a hold until three have tripped the
    drive watchdog (at most ten); each trip must be followed by the drive enabled again.
    Returns (trips, None), or (trips so far, the driver's message) once it latched a fault."""
    trips = 0
    for _ in range(10):
        before = time.monotonic()
        os.kill(pid, signal.SIGSTOP)
        time.sleep(0.012)
        os.kill(pid, signal.SIGCONT)
        # the trip is reported, then the drive is enabled again (by the controller: the plant
        # alone no longer does it); generous timeout for a loaded machine
        probe.wait_for(lambda: contract.DRIVE_STATE_ENABLED in _states_since(probe, before)[1:]
                       or (not _states_since(probe, before) and time.monotonic() - before > 1.0)
                       or probe.driver_level() == 2,
                       20.0, "the drive re-enabled after a watchdog trip (or no trip)")
        if probe.driver_level() == 2:
            return trips, probe.driver_status().message
        states = _states_since(probe, before)
        if contract.DRIVE_STATE_WATCHDOG in states:
            trips += 1
            assert states[states.index(contract.DRIVE_STATE_WATCHDOG) + 1:].count(contract.DRIVE_STATE_ENABLED), states
        time.sleep(0.3)
        if trips >= 3:
            break
    return trips, None


def test_short_controller_stalls_at_a_hold_the_drive_reports_and_the_controller_re_enables(realtime):
    # the soak's defect: 5-20 ms loop gaps at a hold; the drive switched itself off and on
    # again while the controller's law went on as if the current had acted, and the valve
    # ran to 82.8 % for a 47.5 % demand.  Now the plant reports its watchdog trip and stays off
    # until the controller, re-armed from the measurement with zero torque, re-enables it.
    s, probe = realtime
    demand = 47.5
    pid = s.procs["controller"].pid
    for attempt in range(2):
        # at rest first: a stall during the approach (the valve still creeping up at 0.2-0.3 rad/s,
        # the law's command still changing) is another test's case (stalled_controller_does_not_run...)
        _hold(probe, demand, settle_s=0.3)          # (also resets a fault latched by the attempt before)
        mono = time.monotonic()
        trips, fault = _stall_cycles(probe, pid)
        if fault is None:
            break
        # Once in a few runs (stop 16 beside hogs, stop 17 in one of four quiet clean-clone CI
        # runs) the controller gets no resolver sample for ~1 s after a SIGCONT and latches the
        # resolver timeout (1 s here): the correct response to that silence, and not the re-arm
        # this test is about.  Suspected, not verified: Fast DDS's shared-memory port health check
        # (healthy_check_timeout_ms, 1000 ms by default) against a process that SIGSTOP keeps from
        # answering.  Tolerated once; any other fault, or the silence twice, fails.
        assert "no resolver sample" in fault, (fault, _plant_values(probe))
    else:
        pytest.fail(f"the controller latched a resolver silence after a SIGSTOP in both attempts: {fault}")
    # a loaded machine also trips the watchdog on its own (and a stall may land between two
    # plant ticks that were late anyway): at least one stall's trip and re-enable seen
    assert trips >= 1, "no stall tripped the drive watchdog"
    time.sleep(0.5)
    valve = [v for _, v in _truth_since(probe, mono)]
    peak_pct = 100.0 * max(valve) / STROKE_RAD
    plant = _plant_values(probe)
    values = probe.driver_values()
    # how late the loop answered (section 54): the longest a command acted, the stale samples
    print(f"{trips} drive watchdog trips from 12 ms controller stalls at a {demand} % hold: peak {peak_pct:.2f} % "
          f"(plant: {plant.get('watchdog_trips')} watchdog trips, missed fraction {plant.get('missed_fraction')}, "
          f"longest command {plant.get('command_held_max_ms')} ms, {plant.get('commands_held_over_2_periods')} held "
          f"> 2 periods; controller: {values.get('stale_samples')} stale samples, up to "
          f"{values.get('sample_late_max_ms')} ms beyond the usual latency)")
    # The tight bound is a claim about a machine that keeps the plant's own periods (quiet, stop 23: the plant's missed
    # fraction 0.08, peak 47.38 %).  Beside two CPU hogs the plant itself misses half of them or more (0.48-0.66; peaks
    # 47.8-48.0 %, and 49.52 / 49.64 % in the stop-22 / stop-23 suite runs): a command then acts longer than the drive's
    # 5 ms watchdog whatever the controller does, and §49's offline table puts the peak of a 9-13 ms command at
    # 49.1-56.4 %.  There (a quarter of the periods missed or more) the test holds the defect's bound instead (the
    # soak's 82.8 %; 55 % still fails a drive that kept its command for 20 ms, as the test above).
    missed = float(plant.get("missed_fraction") or 0.0)
    bound = demand + 2.0 if missed < 0.25 else 55.0
    assert peak_pct <= bound, (peak_pct, bound, missed)
    assert int(values["stall_rearms"]) >= trips, values.get("stall_rearms")
    assert probe.driver_level() in (0, 1), probe.driver_status().message     # running, no fault


# ------------------------------------------------------------------ a defect in the loop
@pytest.fixture
def inprocess(tmp_path):
    """Plant as a process, the controller node in this process (so its law can be broken)."""
    plan = plan_run(None, REAL_TIME)
    s = Launcher(plan, "/inproc", tmp_path)
    s.start(("plant",))
    try:
        with in_process_controller("/inproc", {"faults.resolver_timeout_s": 1.0, "diagnostics_rate_hz": 10.0}) as (
                node, thread):
            probe = Probe("/inproc")
            try:
                yield node, probe, thread
            finally:
                probe.close()
    finally:
        s.stop()


def test_exception_in_the_controller_loop_latches_a_fault_and_the_node_lives_on(inprocess, monkeypatch):
    node, probe, thread = inprocess
    _hold(probe, 30.0)

    def broken(*_args):
        raise ZeroDivisionError("injected defect")
    monkeypatch.setattr(node.driver.controller.law, "update", broken)
    probe.wait_for(lambda: probe.driver_level() == 2, 5.0, "ERROR on /diagnostics")
    assert "internal error" in probe.driver_status().message and "injected defect" in probe.driver_status().message
    probe.wait_for(lambda: probe.get(contract.DRIVE_ENABLE) is not None and not probe.get(contract.DRIVE_ENABLE).data,
                   3.0, "drive_enable false")
    probe.wait_for(lambda: probe.valve_angle() < 0.02 * STROKE_RAD, 3.0, "valve closed by the spring")
    assert thread.is_alive()
    monkeypatch.undo()
    assert probe.trigger("controller/reset").success
    _hold(probe, 30.0)


# ------------------------------------------------------------------ stamps (issue 13.5)
def test_future_stamped_resolver_sample_latches_and_reset_recovers(realtime):
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Header
    _, probe = realtime
    _hold(probe, 30.0)
    stamp = probe.node.get_clock().now().to_msg()
    stamp.sec += 3600                                   # an hour ahead
    valve = 0.30 * STROKE_RAD
    msg = JointState(header=Header(stamp=stamp), name=list(contract.JOINT_NAMES), position=[valve * 48.019, valve])

    def sent_and_latched():      # depth-1 loop topic: the plant's next sample may displace it
        probe.pub_resolver.publish(msg)
        time.sleep(0.005)
        return probe.driver_level() == 2
    probe.wait_for(sent_and_latched, 5.0, "ERROR for the future stamp")
    assert "ahead" in probe.driver_status().message
    # genuine samples were never judged against the future one: a reset is accepted at once
    probe.wait_for(lambda: probe.trigger("controller/reset").success, 5.0, "a successful reset")
    _hold(probe, 30.0)


# ------------------------------------------------------------------ start-up paths (issue 13.8)
@pytest.mark.parametrize("node,args,words", [
    ("controller", ["-p", "diagnostics_rate_hz:=0.0"], "diagnostics_rate_hz"),
    ("controller", ["-p", "diagnostics_rate_hz:=-1.0"], "diagnostics_rate_hz"),
    ("controller", ["-p", "initial_current_a:=nan"], "initial_current_a"),
    ("controller", ["--params-file", "{bad_yaml}"], "params file"),
    ("controller", ["--params-file", "{abc}"], "demand_timeout_s"),
    ("demand", ["--params-file", "{inf}"], "frequency_hz"),
])
def test_bad_start_up_values_exit_2_with_a_message(tmp_path, node, args, words):
    import subprocess
    from fuel_valve_control.tools.launcher import executable
    files = {"bad_yaml": "/**:\n  ros__parameters:\n    demand_timeout_s: [oops\n",
             "abc": "/**:\n  ros__parameters:\n    demand_timeout_s: abc\n",
             "inf": "/**:\n  ros__parameters:\n    frequency_hz: .inf\n"}
    paths = {}
    for key, text in files.items():
        paths[key] = tmp_path / f"{key}.yaml"
        paths[key].write_text(text)
    cmd = executable(node) + ["--ros-args"] + [a.format(**paths) for a in args]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    out = res.stdout + res.stderr
    assert res.returncode == 2, out
    assert words in out and "Traceback" not in out, out

"""OS scheduling of a run's processes (launcher.Scheduling) and the loop thread's timer slack.

* the launcher applies the niceness, CPU affinity and SCHED_FIFO it is given to the process it
  starts (read back from the OS), and what the OS refuses is reported while the process starts
  and runs anyway;
* the command-line form parses, and malformed or privileged values are refused up front;
* an in-process observer lowers the priority of each of its threads (Linux: per thread);
* the timer slack helper sets the calling thread's slack;
* the plant's loop statistics report the tick thread's lateness.

No speed is asserted here: whether a lever helps is measured by benchmarks/ros_loop.py.
"""
from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from fuel_valve_control.tools import launcher as L

pytestmark = [pytest.mark.ros,      # the launcher test starts a ROS process (the gate): a domain of its own
              pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux scheduling interfaces")]


@pytest.fixture
def sleeper():
    """A plain child process to apply scheduling to (killed at the end)."""
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    yield proc
    proc.kill()
    proc.wait()


def test_niceness_is_applied_relative_to_the_launcher(sleeper):
    own = os.getpriority(os.PRIO_PROCESS, 0)
    refused = L.Scheduling(nice={"demand": 3}).apply("demand", sleeper.pid)
    assert refused == []
    assert os.getpriority(os.PRIO_PROCESS, sleeper.pid) == min(own + 3, 19)
    # a process without an entry keeps the launcher's niceness
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        assert L.Scheduling(nice={"demand": 3}).apply("plant", other.pid) == []
        assert os.getpriority(os.PRIO_PROCESS, other.pid) == own
    finally:
        other.kill()
        other.wait()


def test_affinity_is_applied(sleeper):
    cpu = min(os.sched_getaffinity(0))
    assert L.Scheduling(nice={}, affinity={"plant": (cpu,)}).apply("plant", sleeper.pid) == []
    assert os.sched_getaffinity(sleeper.pid) == {cpu}


def test_refused_levers_are_reported_and_the_process_runs(sleeper, monkeypatch):
    def no_fifo(*args):
        raise PermissionError(1, "Operation not permitted")
    monkeypatch.setattr(os, "sched_setscheduler", no_fifo)       # an unprivileged user
    sched = L.Scheduling(nice={}, affinity={"plant": (100000,)}, fifo={"plant": 10})
    refused = sched.apply("plant", sleeper.pid)
    assert len(refused) == 2
    assert "affinity" in refused[0] and "SCHED_FIFO" in refused[1] and "normal priority" in refused[1]
    assert sleeper.poll() is None
    assert os.sched_getscheduler(sleeper.pid) == os.SCHED_OTHER


def test_fifo_is_applied_where_permitted_and_never_in_lockstep(sleeper):
    # lockstep: the processes run flat out one after the other -- no real-time policy
    assert L.Scheduling(nice={}, fifo={"plant": 1}).apply("plant", sleeper.pid, real_time=False) == []
    assert os.sched_getscheduler(sleeper.pid) == os.SCHED_OTHER
    refused = L.Scheduling(nice={}, fifo={"plant": 1}).apply("plant", sleeper.pid)
    if refused:                           # not privileged here: the refusal is the behaviour
        assert "SCHED_FIFO" in refused[0]
        assert os.sched_getscheduler(sleeper.pid) == os.SCHED_OTHER
    else:
        assert os.sched_getscheduler(sleeper.pid) == os.SCHED_FIFO
        assert os.sched_getparam(sleeper.pid).sched_priority == 1


def test_launcher_applies_its_scheduling_to_the_processes_it_starts(tmp_path):
    from fuel_valve_control.tools.run_plan import REAL_TIME, plan_run
    own = os.getpriority(os.PRIO_PROCESS, 0)
    sched = L.Scheduling(nice={"gate": 4}, affinity={"gate": (100000,)})   # a CPU no machine has
    la = L.Launcher(plan_run(None, REAL_TIME), "/sched_test", tmp_path, scheduling=sched)
    try:
        la.start_gate()
        pid = la.procs["gate"].pid
        assert os.getpriority(os.PRIO_PROCESS, pid) == min(own + 4, 19)
        assert len(la.scheduling_refused) == 1 and "affinity" in la.scheduling_refused[0]
        assert la.procs["gate"].poll() is None          # refused: started anyway
    finally:
        la.procs["gate"].kill()
        la.procs["gate"].wait()


def test_launcher_without_scheduling_keeps_its_own_priority(tmp_path):
    from fuel_valve_control.tools.run_plan import REAL_TIME, plan_run
    la = L.Launcher(plan_run(None, REAL_TIME), "/sched_test", tmp_path)
    assert la.scheduling == L.Scheduling.off()


def test_default_scheduling_favours_the_loop_processes():
    sched = L.Scheduling()
    assert sched.nice == L.DEFAULT_NICE
    assert all(sched.nice.get(n, 0) == 0 for n in ("plant", "controller"))
    assert sched.nice.get("monitor", 0) > 0
    # the nodes the loop depends on are never niced (a starved demand node trips the drive)
    assert all(sched.nice.get(n, 0) == 0 for n in ("demand", "recorder"))
    assert sched.fifo == L.DEFAULT_FIFO
    # the loop first, the nodes it depends on below it, all below the kernel's threads (50)
    assert 50 > sched.fifo["plant"] == sched.fifo["controller"] > sched.fifo["demand"] >= sched.fifo["recorder"] >= 1
    assert L.Scheduling.off().describe() == {"nice": {}, "affinity": {}, "fifo": {}}


@pytest.mark.parametrize("nice, affinity, fifo, expect", [
    (None, None, None, L.Scheduling()),
    ("off", None, "off", L.Scheduling.off()),
    ("", None, "", L.Scheduling.off()),
    ("off", None, None, L.Scheduling(nice={})),
    ("demand=7, recorder=2", "plant=0,controller=1+0", "plant,controller=20",
     L.Scheduling(nice={"demand": 7, "recorder": 2}, affinity={"plant": (0,), "controller": (1, 0)},
                  fifo={"plant": L.DEFAULT_FIFO_PRIORITY, "controller": 20})),
])
def test_parse_scheduling(nice, affinity, fifo, expect):
    assert L.parse_scheduling(nice, affinity, fifo) == expect


@pytest.mark.parametrize("nice, affinity, fifo", [
    ("demand=-5", None, None), ("demand=20", None, None), ("demand", None, None), ("demand=x", None, None),
    (None, "plant=a", None), (None, "=1", None), (None, None, "plant=0"), (None, None, "plant=100"),
    (None, None, "=5")])
def test_parse_scheduling_refuses_malformed_text(nice, affinity, fifo):
    with pytest.raises(ValueError):
        L.parse_scheduling(nice, affinity, fifo)


def test_nice_own_threads_lowers_every_thread():
    script = (
        "import os, threading, time\n"
        "from fuel_valve_control.tools.launcher import nice_own_threads\n"
        "ev = threading.Event()\n"
        "t = threading.Thread(target=ev.wait); t.start()\n"
        "before = {int(x): os.getpriority(os.PRIO_PROCESS, int(x)) for x in os.listdir('/proc/self/task')}\n"
        "print(nice_own_threads(2))\n"
        "after = {tid: os.getpriority(os.PRIO_PROCESS, tid) for tid in before}\n"
        "ev.set(); t.join()\n"
        "print(len(before), all(after[k] == min(before[k] + 2, 19) for k in before))\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60,
                         cwd=Path(__file__).resolve().parents[1])
    assert out.returncode == 0, out.stderr
    refused, check = out.stdout.split("\n")[:2]
    assert refused == "[]"
    n, ok = check.split()
    assert int(n) >= 2 and ok == "True"


def test_timer_slack_is_set_for_the_calling_thread():
    from fuel_valve_control.ros.node_runner import set_timer_slack
    result = {}

    def worker():
        result["set"] = set_timer_slack(2000)
        result["zero"] = set_timer_slack(0)           # 0: leave it, report it (prctl GET)
    t = threading.Thread(target=worker)
    t.start()
    t.join()
    assert result == {"set": 2000, "zero": 2000}
    # the main thread's slack is untouched (per thread)
    assert set_timer_slack(0) != 2000


def test_loop_statistics_report_the_tick_lateness():
    from fuel_valve_plant.ros.plant_node import LoopStats
    stats = LoopStats()
    assert "tick_late_p99_ms" not in stats.summary()
    for k in range(100):
        stats.add_late(1e-5 * k + 3e-6)           # 0.003 .. 0.993 ms
    s = stats.summary()
    # quantiles to within one 10 us bin (the upper edge), the maximum exact
    assert s["tick_late_median_ms"] == pytest.approx(0.503, abs=0.01)
    assert s["tick_late_p99_ms"] == pytest.approx(0.993, abs=0.01)
    assert s["tick_late_max_ms"] == pytest.approx(0.993)


def test_duration_histogram_quantiles_match_sorted_samples():
    import random
    from fuel_valve_plant.ros.plant_node import DurationHistogram
    rng = random.Random(4)
    samples = [rng.expovariate(1 / 4e-4) for _ in range(5000)] + [0.5, -1e-6]   # one beyond the range, one early
    h = DurationHistogram()
    for x in samples:
        h.add(x)
    ordered = sorted(samples)
    for q in (0.0, 0.5, 0.9, 0.99, 0.999):
        exact = ordered[min(int(q * len(ordered)), len(ordered) - 1)]
        assert exact - 1e-12 <= h.quantile(q) <= max(exact, 0.0) + h.resolution_s + 1e-12, q
    assert h.max == 0.5 and h.n == len(samples) and h.quantile(1.0) == 0.5


def test_a_starved_plant_tick_starts_a_new_grid_and_slows_its_time_down():
    # the stall test's excursion under load (issue 13): a plant thread starved for 4-6 ms
    # stepped the whole gap on one held command and then fired the missed ticks back to back
    # (samples 40 us apart), and the 1 kHz loop fell into a limit cycle 9 % past its demand
    from fuel_valve_plant.ros.plant_node import MAX_STEP_PERIODS, next_tick_after
    period = 1e-3
    # on time (a little sleep overshoot): the grid is kept, the physics follows the wall clock
    elapsed, nxt, skipped = next_tick_after(now=10.0012, last=10.0002, next_tick=10.001, period=period)
    assert (elapsed, nxt, skipped) == (pytest.approx(1e-3), pytest.approx(10.002), 0)
    # 6 ms late: no catch-up burst (the next tick a whole period later), five ticks skipped,
    # and at most MAX_STEP_PERIODS of simulated time for the 7 ms of wall time
    elapsed, nxt, skipped = next_tick_after(now=10.008, last=10.001, next_tick=10.002, period=period)
    assert nxt == pytest.approx(10.009)
    assert skipped == 6
    assert elapsed == pytest.approx(MAX_STEP_PERIODS * period) and MAX_STEP_PERIODS <= 2.0

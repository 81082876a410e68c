"""Process life cycle of the nodes on the node runner (rclpy's events executor, public API).

* SIGINT, SIGTERM, and two SIGINTs (as under ``ros2 launch``: the terminal's and the one
  launch forwards; the second can land in the clean-up) each end plant, controller and demand
  with exit code 0, without a traceback, well before launch would escalate (5 s);
* the graph holds exactly the design's nodes (no helper nodes), and the loop's
  subscriptions are on the real nodes (what ``ros2 node info`` shows).
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

pytestmark = [pytest.mark.ros]

NS = "/fv_life"
NODES = ("plant", "controller", "demand")
#: launch's SIGINT -> SIGTERM escalation delay, s: a node must be gone well before it
EXIT_WITHIN_S = 5.0


def exe(name: str) -> list[str]:
    here = Path(sys.executable).parent / name
    return [str(here)] if here.exists() else [sys.executable, "-m", {
        "plant": "fuel_valve_plant.ros.plant_node", "controller": "fuel_valve_control.ros.controller_node",
        "demand": "fuel_valve_control.ros.demand_node"}[name]]


def start(tmp_path: Path, tag: str) -> dict[str, tuple[subprocess.Popen, Path]]:
    procs = {}
    for name in NODES:
        log = tmp_path / f"{tag}_{name}.log"
        procs[name] = (subprocess.Popen(exe(name) + ["--ros-args", "-r", f"__ns:={NS}"],
                                        env=dict(os.environ, PYTHONUNBUFFERED="1"), stdin=subprocess.DEVNULL,
                                        stdout=open(log, "w"), stderr=subprocess.STDOUT), log)
    end = time.monotonic() + 40.0
    for name, (proc, log) in procs.items():
        while f"{name} up" not in log.read_text():
            assert proc.poll() is None, log.read_text()
            assert time.monotonic() < end, log.read_text()
            time.sleep(0.05)
    return procs


def stop(procs, signals) -> dict[str, tuple[int, float, str]]:
    """Send ``signals`` (with the given delays, s) to every process; (code, s to exit, log)."""
    t0 = time.monotonic()
    for sig, delay in signals:
        time.sleep(delay)
        for proc, _ in procs.values():
            if proc.poll() is None:
                proc.send_signal(sig)
    out = {}
    for name, (proc, log) in procs.items():
        try:
            proc.wait(timeout=EXIT_WITHIN_S + 10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        out[name] = (proc.returncode, time.monotonic() - t0, log.read_text())
    return out


def graph(context_ns: str):
    """(node names in the namespace, {node: subscribed topics}) seen by a probe node."""
    import rclpy
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        probe = rclpy.create_node("life_probe", context=context)
        end = time.monotonic() + 10.0
        names = set()
        while time.monotonic() < end:
            names = {n for n, ns in probe.get_node_names_and_namespaces() if ns == context_ns}
            if set(NODES) <= names:
                break
            time.sleep(0.1)
        time.sleep(0.5)                       # let the rest of the graph arrive, then read it
        names = [n for n, ns in probe.get_node_names_and_namespaces() if ns == context_ns]
        subs = {n: {t for t, _ in probe.get_subscriber_names_and_types_by_node(n, context_ns)} for n in set(names)}
        probe.destroy_node()
        return names, subs
    finally:
        rclpy.try_shutdown(context=context)


@pytest.mark.parametrize("signals", [
    [(signal.SIGINT, 0.0)],
    [(signal.SIGTERM, 0.0)],
    [(signal.SIGINT, 0.0), (signal.SIGINT, 0.05), (signal.SIGINT, 0.15)],
], ids=["sigint", "sigterm", "sigint_x3"])
def test_signals_end_every_node_with_exit_0(tmp_path, signals):
    procs = start(tmp_path, "run")
    try:
        if signals[0][0] == signal.SIGINT and len(signals) == 1:
            names, subs = graph(NS)
            assert sorted(names) == sorted(NODES)          # no <name>_loop helpers, no duplicates
            assert {f"{NS}/resolver", f"{NS}/demand", f"{NS}/demand_ma"} <= subs["controller"]
            assert {f"{NS}/current_command", f"{NS}/drive_enable"} <= subs["plant"]
    finally:
        results = stop(procs, signals)
    for name, (code, seconds, log) in results.items():
        assert code == 0, (name, code, log)
        assert seconds < EXIT_WITHIN_S, (name, seconds)
        assert "Traceback" not in log and "KeyboardInterrupt" not in log, (name, log)


#: a node whose DDS tear-down never ends, holding the GIL (as a blocked ``publisher.destroy``
#: in C code does): ``tear_down`` must still end the process, with the run's exit code
_HUNG_TEAR_DOWN = """
import ctypes, sys
import rclpy
from fuel_valve_control.ros import node_runner

class Node:
    def destroy_node(self):
        print("destroying", flush=True)
        ctypes.PyDLL(None).sleep(120)          # C code, GIL held: no Python thread runs meanwhile

rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
node_runner.tear_down(Node(), None, code=int(sys.argv[1]), budget_s=1.0)
print("tear-down returned", flush=True)
"""


@pytest.mark.parametrize("code", [0, 2])
def test_a_hung_tear_down_ends_the_process_with_its_exit_code(code):
    """h36r: under ``ros2 launch`` on a loaded machine a node's tear-down (after its exit report)
    hung 15 s, ignored SIGTERM (by design) and was killed (-9, "process has died").  Past
    ``budget_s`` the stacks are printed and the process ends with the code it would have had."""
    proc = subprocess.run([sys.executable, "-c", _HUNG_TEAR_DOWN, str(code)], capture_output=True, text=True,
                          timeout=100)            # (a guard: without the budget it sleeps 120 s)
    out = proc.stdout + proc.stderr
    assert proc.returncode == code, out
    assert "destroying" in out and "tear-down returned" not in out, out
    assert "in destroy_node" in out and "in tear_down" in out, out        # where it hung


#: the node entry points as their console scripts import them (setup.py)
ENTRY_MODULES = ("fuel_valve_plant.ros.plant_node", "fuel_valve_control.ros.controller_node",
                 "fuel_valve_control.ros.demand_node")
BLAS_CHECK = """
import os, sys, importlib
importlib.import_module(sys.argv[1])
import fuel_valve_control.ros as r
import numpy
print(r.BLAS_SPIN_LIMITED, os.environ.get(r.BLAS_TIMEOUT_ENV))
"""


def test_every_node_process_limits_openblas_spin_before_numpy_loads():
    """docs/control_results.md section 107: OpenBLAS's idle workers spun ~0.1 s (its default
    2**28 cycles) after the controller's gain design, at SCHED_FIFO, and starved the plant's tick
    thread: the armed controller latched a resolver timeout in ~half the real-time start-ups.
    Each node's entry module, imported in a fresh interpreter (as its console script does), sets
    OPENBLAS_THREAD_TIMEOUT before numpy is loaded (OpenBLAS reads it then); a value the user set
    is kept.  The three interpreters run side by side (one import's time)."""
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_THREAD_TIMEOUT"}
    procs = [subprocess.Popen([sys.executable, "-c", BLAS_CHECK, m], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for m in ENTRY_MODULES]
    user = subprocess.Popen([sys.executable, "-c", BLAS_CHECK, ENTRY_MODULES[0]],
                            env=dict(env, OPENBLAS_THREAD_TIMEOUT="28"), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    for module, proc in zip(ENTRY_MODULES, procs):
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
        assert out.split() == ["True", "4"], f"{module}: {out} {err}"
    out, err = user.communicate(timeout=120)
    assert out.split() == ["True", "28"], err


FIFO_CHECK = """
import os, threading
import fuel_valve_control.ros as r
from fuel_valve_control.ros import node_runner as nr
fifo = lambda tid: os.sched_getscheduler(tid) == os.SCHED_FIFO
out = [r.STARTUP_FIFO, fifo(0)]
stop = threading.Event()
early = threading.Thread(target=stop.wait)          # started during the imports (OpenBLAS's workers)
early.start()
out += [fifo(early.native_id)]
refused = nr.restore_fifo()
late = threading.Thread(target=stop.wait)           # started after (DDS, the node's threads)
late.start()
out += [fifo(0), fifo(early.native_id), fifo(late.native_id)]
stop.set()
print(out, refused)
"""


def _fifo_child(env: dict) -> str:
    def fifo():
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))      # as the launcher does after exec
    proc = subprocess.run([sys.executable, "-c", FIFO_CHECK], env=env, preexec_fn=fifo, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.strip()


def test_a_fifo_node_can_run_its_imports_at_normal_priority_and_gets_fifo_back():
    """docs/control_results.md section 107: a node started SCHED_FIFO (the launcher's default for
    plant and controller) runs its start-up at normal priority (it was a second of CPU nothing
    could interrupt: the plant's tick thread starved, real-time throttling) -- its imports, that is;
    ``restore_fifo`` (run_node: before rclpy.init) gives the priority back to every thread, and the
    threads started later inherit it.  Only with ``FUEL_VALVE_IMPORTS_NORMAL_PRIORITY=1``; without
    it (the default) FIFO throughout, as before."""
    try:
        os.sched_param(1)
        probe = subprocess.run([sys.executable, "-c", "pass"], preexec_fn=lambda: os.sched_setscheduler(
            0, os.SCHED_FIFO, os.sched_param(1)), capture_output=True, timeout=60)
    except (AttributeError, subprocess.SubprocessError, OSError):
        probe = None
    if probe is None or probe.returncode != 0:
        pytest.skip("SCHED_FIFO not permitted here")
    env = {k: v for k, v in os.environ.items() if k != "FUEL_VALVE_IMPORTS_NORMAL_PRIORITY"}
    # on, started FIFO 1: normal priority at import (a thread started then too); FIFO again for all,
    # and inherited by a thread started after
    assert _fifo_child(dict(env, FUEL_VALVE_IMPORTS_NORMAL_PRIORITY="1")) == "[1, False, False, True, True, True] []"
    # the default: FIFO throughout, nothing to give back (the threads inherit FIFO)
    assert _fifo_child(env) == "[None, True, True, True, True, True] []"

"""Process entry point of the suite's nodes: one node, one executor, public rclpy API only.

Every node of the suite (plant, controller, demand, recorder) runs its ROS work on rclpy's
``EventsExecutor`` (``rclpy.experimental``, C++ event queue): in a 1 kHz plant/controller
ping-pong it cost a third of the CPU per cycle of the ``SingleThreadedExecutor`` and a fifth
of its p99 round trip (benchmarks/ros_loop.py; README).  The loop's subscriptions live on the
node itself, so the graph holds exactly the design's nodes and ``ros2 node info`` shows them.

Two properties of the events executor of rclpy 7.1.x that this module works around (pinned by
``test/test_node_runner.py``):

* ``spin()`` without a timeout never runs timers, busy-waits and ignores SIGINT/SIGTERM: the
  nodes spin with :func:`spin`, a ``spin_once(timeout_sec=...)`` loop that checks the context;
* a callback that asks for the message info (two arguments) fails in the executor
  (``SystemError``): subscriptions here take the message only.

Signals: SIGINT and SIGTERM only set a flag (Python-level handlers; rclpy's own are not
installed); the spin loop sees it within one ``spin_once`` and returns, then the node is
taken off the executor and destroyed, and only then is the context shut down.  So no callback
ever runs on a shut-down context (rclpy's handlers shut it down at once, from the signal, and
a callback running at that moment failed to publish), and no ``KeyboardInterrupt`` is raised
anywhere: under ``ros2 launch`` the terminal's SIGINT and the one launch forwards both
arrive, and the second would otherwise land in the clean-up and end the process with -2.

Exit: once the node is destroyed and the context shut down and destroyed (the DDS participant
leaves the graph at once), the process ends with ``os._exit`` (:func:`end_process`), skipping
the interpreter's own finalization.  That finalization -- garbage collection of the ~10^5
objects numpy/scipy/numba leave behind, module teardown -- cost 0.1-0.35 s of CPU per node
process (measured), and all the nodes of a launch exit at the same moment: on a loaded 2-core
machine a node got ~5 % of a core and took more than launch's 5 s between its SIGINT and its
escalation to SIGTERM (ignored here) and then SIGKILL (exit -9: "process has died").  Nothing
is left for it to do: the bag is closed, the logs are flushed, the participant is gone.

Tear-down budget: the DDS tear-down itself (destroying the node's publishers, the executor,
the context) took 2-3 s per node when the six or eight nodes of a two-valve launch all stopped
at once on the loaded 2-core machine (load 20-40: the ``publisher.destroy`` calls, measured by
a stack dump), and now and then it did not end at all: a demand node, then a plant, printed its
exit report, sat in the tear-down 15 s, ignored launch's SIGTERM (by design, above) and was
killed (exit -9, "process has died"; the real-CLI two-valve tests' flake, h36r).  So
:func:`tear_down` runs under :data:`TEARDOWN_BUDGET_S`: past it, the stacks are printed (where
it hung) and the process ends with its exit code all the same (:func:`arm_exit_timer`: a C
library timer thread, so a main thread blocked in C code holding the GIL cannot stop it).
Nothing is lost: the node's work and its exit report are done before the tear-down starts;
only the participant's goodbye may be missing (the others then drop it at its lease's end).
"""
from __future__ import annotations

import json
import os
import signal
import sys

#: longest time one ``spin_once`` blocks, s: how late a shutdown without a wake-up is seen
SPIN_TIMEOUT_S = 0.1
#: environment variable: a directory; when set, every node's spin loop runs under cProfile and
#: writes ``<dir>/<node name>.prof`` at the end (benchmarks/ros_loop.py --profile reads them)
PROFILE_ENV = "FUEL_VALVE_PROFILE"
#: GIL switch interval, s: a sample arriving while another thread of the process (the plant's
#: tick thread) runs Python waits at most this long (CPython's default is 5 ms, five periods)
SWITCH_INTERVAL_S = 0.0002
#: environment variable: "1" / "0" turns :func:`freeze_heap` on / off (unset: :data:`GC_FREEZE`;
#: benchmarks/ros_loop.py --gc-freeze sets it to compare)
GC_FREEZE_ENV = "FUEL_VALVE_GC_FREEZE"
#: move what a node holds once it is built into the collector's permanent generation: off, no
#: gain measured (benchmarks/ros_loop.py --gc-freeze 1 against 0, interleaved, loaded machine)
GC_FREEZE = False
#: environment variable: timer slack of a real-time loop thread, ns (:func:`set_timer_slack`;
#: unset: :data:`LOOP_TIMER_SLACK_NS`; benchmarks/ros_loop.py --timer-slack sets it to compare)
TIMER_SLACK_ENV = "FUEL_VALVE_TIMER_SLACK_NS"
#: timer slack of the plant's tick thread, ns (0: the kernel default of the thread, 50 us)
LOOP_TIMER_SLACK_NS = 0
#: longest time :func:`tear_down` may take, s, before the process ends anyway (see the module
#: docstring): under launch's SIGINT-to-SIGTERM escalation (5 s) with room for the spin loop to
#: see the signal and the exit report; a tear-down takes 0.1-0.5 s quiet, 2-3 s on the loaded
#: machine
TEARDOWN_BUDGET_S = 3.0


def make_executor(context=None):
    """The executor every node of the suite spins on (see the module docstring)."""
    from rclpy.experimental import EventsExecutor
    return EventsExecutor(context=context)


def spin(executor, context=None, until=None, timeout_s: float = SPIN_TIMEOUT_S) -> None:
    """Spin ``executor`` until ``context`` (default: rclpy's) shuts down or ``until()`` is true.

    ``spin_once`` with a timeout, never ``spin()``: the events executor's untimed spin ignores
    shutdown (see the module docstring).  With :data:`PROFILE_ENV` set, the loop runs under
    cProfile (the executor thread only: the callbacks and the time inside ``spin_once``)."""
    import rclpy
    profile_dir = os.environ.get(PROFILE_ENV)
    profiler = None
    if profile_dir:
        import cProfile
        profiler = cProfile.Profile()
        profiler.enable()
    try:
        while rclpy.ok(context=context) and not (until is not None and until()):
            executor.spin_once(timeout_sec=timeout_s)
    finally:
        if profiler is not None:
            profiler.disable()
            names = "+".join(n.get_name() for n in executor.get_nodes()) or str(os.getpid())
            os.makedirs(profile_dir, exist_ok=True)
            profiler.dump_stats(os.path.join(profile_dir, f"{names}.prof"))


def set_timer_slack(ns: int | None = None) -> int | None:
    """Set the calling thread's timer slack (Linux ``prctl(PR_SET_TIMERSLACK)``, libc via
    ctypes): how much later than asked the kernel may end its sleeps, to batch wake-ups (default
    50 us).  ``ns`` None: :data:`TIMER_SLACK_ENV`, else :data:`LOOP_TIMER_SLACK_NS`; 0 leaves
    the default.  Returns the slack now in force (ns), None where the call is not available."""
    import ctypes
    if ns is None:
        ns = int(os.environ.get(TIMER_SLACK_ENV) or LOOP_TIMER_SLACK_NS)
    pr_set_timerslack, pr_get_timerslack = 29, 30          # <linux/prctl.h>
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if ns > 0 and libc.prctl(pr_set_timerslack, ctypes.c_ulong(ns), 0, 0, 0) != 0:
            return None
        return int(libc.prctl(pr_get_timerslack, 0, 0, 0, 0))
    except (OSError, AttributeError):       # no libc handle / no prctl: not Linux
        return None


def freeze_heap(on: bool | None = None) -> bool:
    """Once a node is built: collect, then ``gc.freeze()`` every object alive (the imports --
    numpy, scipy, numba, rclpy --, the node, its parameter sets), so the cyclic collector's
    full collections scan only what the loop allocates since, not the ~10^5 objects of the
    start-up; a full collection over all of them holds the GIL for tens of ms (the loop thread
    waits meanwhile).  ``on`` None: :data:`GC_FREEZE_ENV`, else :data:`GC_FREEZE`.  Returns
    whether it froze."""
    import gc
    if on is None:
        env = os.environ.get(GC_FREEZE_ENV)
        on = GC_FREEZE if env is None else env.strip() not in ("", "0", "false", "off")
    if on:
        gc.collect()
        gc.freeze()
    return on


def restore_fifo(priority: int | None = None) -> list[str]:
    """Give a node process started SCHED_FIFO its priority back
    (:func:`fuel_valve_control.ros.start_at_normal_priority` took it away for its imports):
    SCHED_FIFO ``priority`` (None: ``fuel_valve_control.ros.STARTUP_FIFO``; None there too:
    nothing to do) for every thread of the process (the main thread, OpenBLAS's workers).
    :func:`run_node` calls it before ``rclpy.init``: the threads started from then on -- DDS,
    the executor, the plant's tick thread, the controller's move-table reader -- inherit it, as
    they did when the whole process ran SCHED_FIFO.  Returns what the OS refused (one sentence)."""
    if priority is None:
        from fuel_valve_control import ros
        priority = ros.STARTUP_FIFO
    if not priority:
        return []
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [os.getpid()]
    for tid in sorted(tids, key=lambda t: t != os.getpid()):      # the main thread first
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
        except (OSError, AttributeError) as exc:   # a thread that ended meanwhile / not permitted
            if tid == os.getpid():
                return [f"SCHED_FIFO {priority} refused ({exc}): normal priority"]
    return []


def quiet_signals(handler=None) -> None:
    """Python-level SIGINT/SIGTERM handlers that never raise; ``handler(signum)`` if given.

    Use with ``rclpy.init(signal_handler_options=SignalHandlerOptions.NO)``: a signal then
    only does what ``handler`` does (e.g. set the flag :func:`spin` watches)."""
    def on_signal(signum, frame):
        if handler is not None:
            handler(signum)
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)


def ignore_signals() -> None:
    """Ignore SIGINT/SIGTERM from here on: for the end of a process whose clean-up is done.

    The interpreter's own shutdown puts Python-level handlers back to the default action, so
    a late signal (the second or third of a launch shutdown) would kill the process with -2 in
    its last milliseconds; an ignored signal stays ignored."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)


def init_or_explain(args=None) -> bool:
    """``rclpy.init`` with SIGINT/SIGTERM left to :func:`quiet_signals`; False (after printing
    why) when the command line is unusable, e.g. a ``--params-file`` that is not valid YAML
    (rcl refuses it inside ``init``: a configuration error, exit 2, not a traceback)."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:                # noqa: BLE001 - rclpy's RCLError is not public API
        print(f"invalid arguments: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}", flush=True)
        return False
    return True


def run_node(factory, args=None, on_exit=None) -> int:
    """Run the node ``factory()`` builds until SIGINT / SIGTERM, clean up, then end the
    process with the exit code (:func:`end_process`; a process entry point, it does not return
    once ``rclpy`` is initialised).

    ``factory()`` raising ``SystemExit`` or a parameter exception is a configuration error:
    message printed, exit code 2.  ``on_exit(node)`` runs before the node is destroyed (the
    context may already be shut down: print or log, do not publish).  0 otherwise, also when
    several signals arrive (see the module docstring).  Returns 2 only when ``rclpy.init``
    refuses the command line.
    """
    import rclpy
    from rclpy.exceptions import InvalidParameterValueException, ParameterException
    from rclpy.executors import ExternalShutdownException

    stop: list[int] = []
    quiet_signals(stop.append)
    sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
    # the imports are done (the node module's, at normal priority: start_at_normal_priority); from
    # here on, and every thread started from here on, at the real-time priority it was started with
    refused = restore_fifo()
    if not init_or_explain(args):
        return 2
    node = executor = None
    code = 0
    try:
        node = factory()
        executor = make_executor()
        executor.add_node(node)
        freeze_heap()
        for why in refused:
            node.get_logger().warn(why)
        spin(executor, until=lambda: bool(stop))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except SystemExit as exc:
        print(exc, flush=True)
        code = 2
    except (ParameterException, InvalidParameterValueException) as exc:
        # a parameter file or -p value outside a declared range: a configuration error
        print(f"invalid parameter: {exc}", flush=True)
        code = 2
    except Exception:                       # noqa: BLE001 - a shutdown race inside spin_once()
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            if on_exit is not None:
                on_exit(node)
            gate = getattr(node, "recorder_gate", None)
            if gate is not None and rclpy.ok():
                gate.drain()                # the recorder (stopped last) has what was published
            if gate is not None:
                # lines a benchmark or test can parse: messages this node published per topic, and
                # how many of them went out before the run's recorder had matched (interface.RecorderGate)
                print(f"[{node.get_name()}] published: {json.dumps(dict(gate.published))}", flush=True)
                print(f"[{node.get_name()}] published before the recorder matched: "
                      f"{json.dumps(dict(gate.before_recorder))}", flush=True)
        tear_down(node, executor, code)
    end_process(code)


def tear_down(node, executor, code: int = 0, budget_s: float | None = TEARDOWN_BUDGET_S) -> None:
    """The end of a node process, in the order that cannot race: the node leaves the executor
    and is destroyed, the executor shuts down, then the context (its logging flushed) and its
    DDS participant; signals arriving after that are ignored (a late one must not turn a clean
    exit into -2).

    ``budget_s`` (None: none): if all that takes longer, the stacks of every thread are printed
    to stderr and the process ends with ``code`` (see the module docstring)."""
    import rclpy
    armed = budget_s is not None and _arm_budget(budget_s, code)
    if node is not None:
        if executor is not None:
            executor.remove_node(node)
        node.destroy_node()
    if executor is not None:
        executor.shutdown()
    rclpy.try_shutdown()
    # the participant leaves now (others drop it at once, not after its lease), not in the
    # interpreter's finalization that end_process skips
    rclpy.get_default_context().destroy()
    if armed:
        import faulthandler
        faulthandler.cancel_dump_traceback_later()
        # (the exit timer stays armed: end_process follows at once and ends the process first)
    ignore_signals()


def _arm_budget(budget_s: float, code: int) -> bool:
    """Arm :func:`tear_down`'s budget: the stack dump a little before it, the exit at it.
    What is printed so far is flushed first (``_exit`` flushes nothing)."""
    import faulthandler
    flush_output()
    faulthandler.dump_traceback_later(max(budget_s - 0.5, 0.5 * budget_s), exit=False)
    return arm_exit_timer(budget_s, code)


def arm_exit_timer(seconds: float, code: int) -> bool:
    """End the process with ``_exit(code)`` ``seconds`` from now, from a thread of the C library
    (a POSIX timer with ``SIGEV_THREAD`` notification calling ``_exit``), never from Python: a
    main thread blocked in C code with the GIL held (a DDS tear-down that hangs) cannot delay
    it.  False where the call is not available (not Linux/glibc): nothing armed."""
    import ctypes

    class _Thread(ctypes.Structure):
        _fields_ = [("function", ctypes.c_void_p), ("attribute", ctypes.c_void_p)]

    class _Union(ctypes.Union):
        _fields_ = [("pad", ctypes.c_int * 12), ("tid", ctypes.c_int), ("thread", _Thread)]

    class _Sigevent(ctypes.Structure):       # <bits/types/sigevent_t.h>, 64 bytes
        _fields_ = [("value", ctypes.c_void_p), ("signo", ctypes.c_int), ("notify", ctypes.c_int),
                    ("un", _Union)]

    class _Timespec(ctypes.Structure):
        _fields_ = [("sec", ctypes.c_long), ("nsec", ctypes.c_long)]

    class _Itimerspec(ctypes.Structure):
        _fields_ = [("interval", _Timespec), ("value", _Timespec)]

    sigev_thread, clock_monotonic = 2, 1
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        event = _Sigevent(value=int(code) or None, notify=sigev_thread)
        # _exit(int) called with the sigval union, whose int sits where an int argument goes
        event.un.thread.function = ctypes.cast(libc._exit, ctypes.c_void_p).value
        timer = ctypes.c_void_p()
        if libc.timer_create(clock_monotonic, ctypes.byref(event), ctypes.byref(timer)) != 0:
            return False
        spec = _Itimerspec(value=_Timespec(int(seconds), int(round((seconds % 1.0) * 1e9))))
        return libc.timer_settime(timer, 0, ctypes.byref(spec), None) == 0
    except (OSError, AttributeError):        # no libc handle / no timer_create: not Linux
        return False


def flush_output() -> None:
    """Flush stdout/stderr, Python's and the C library's (where rcutils' console logging writes)."""
    import ctypes
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:                   # noqa: BLE001 - a closed pipe: nothing to flush to
            pass
    try:
        ctypes.CDLL(None).fflush(None)      # every C stdio stream (rcutils may buffer stdout)
    except Exception:                       # noqa: BLE001 - no C library handle: nothing buffered there
        pass


def end_process(code: int) -> None:
    """End a node process whose :func:`tear_down` is done: flush stdout/stderr (Python's and
    the C library's, where rcutils' console logging writes), then ``os._exit(code)`` without
    the interpreter's finalization (see the module docstring: on a loaded machine it outlasted
    launch's SIGINT-to-SIGTERM escalation)."""
    cov = sys.modules.get("coverage")
    if cov is not None:                     # subprocess coverage saves at exit, which is skipped
        try:
            current = cov.Coverage.current()
            if current is not None:
                current.stop()
                current.save()
        except Exception:                   # noqa: BLE001 - measuring must not change the exit
            pass
    flush_output()
    os._exit(code)

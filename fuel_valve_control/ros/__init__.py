"""Thin ROS 2 adapters over the core: controller and demand nodes, QoS and message helpers, loop I/O.

Importing this package (every node process does, the plant's too, before numpy is loaded) limits
OpenBLAS's idle spin, :func:`limit_blas_spin`, and (optional, off by default) takes a process
that was started SCHED_FIFO back to normal priority for its imports,
:func:`start_at_normal_priority` (the node runner gives the priority back before ``rclpy.init``)."""
import os
import sys

#: OpenBLAS's idle spin of its worker threads, as the exponent it reads from
#: ``OPENBLAS_THREAD_TIMEOUT`` at load time: a worker busy-waits 2**n CPU cycles after each
#: threaded BLAS call before it sleeps.  OpenBLAS's default, 28, is ~0.11 s of a core at 2.4 GHz
#: (each of numpy's and scipy's OpenBLAS has a worker on this 2-core machine); 4, OpenBLAS's
#: least, is 16 cycles.  Why (docs/control_results.md section 107): the controller's gain
#: design at start-up (``ValveDriver(...)``) wakes scipy's worker, which then spun ~0.1 s at
#: the node's SCHED_FIFO priority while the controller's main thread ran on the other core --
#: the plant's tick thread (same priority) got no core for ~110 ms, and the armed controller
#: latched "no resolver sample for 1xx ms".  The spin length changes no result: the same
#: threads split the same products (only how long an idle worker waits before it sleeps).
BLAS_THREAD_TIMEOUT = 4
#: environment variable OpenBLAS reads (a value set by the user is kept)
BLAS_TIMEOUT_ENV = "OPENBLAS_THREAD_TIMEOUT"


def limit_blas_spin() -> bool:
    """Set :data:`BLAS_TIMEOUT_ENV` to :data:`BLAS_THREAD_TIMEOUT` unless already set (in this
    process and the processes it starts).  OpenBLAS reads it when it is loaded, so this must run
    before numpy / scipy are imported: returns whether it did (False: numpy was loaded already,
    this process keeps the spin it has)."""
    os.environ.setdefault(BLAS_TIMEOUT_ENV, str(BLAS_THREAD_TIMEOUT))
    return "numpy" not in sys.modules


#: whether :func:`limit_blas_spin` ran before numpy was loaded in this process (the node
#: processes: yes, test/test_nodes.py checks the three node entry points)
BLAS_SPIN_LIMITED = limit_blas_spin()


#: environment variable: "1" runs a SCHED_FIFO node's imports at normal priority
#: (:func:`start_at_normal_priority`); unset or anything else: SCHED_FIFO throughout, as before
#: section 107 (the default: measured both ways there, the choice is the lead's)
IMPORTS_NORMAL_ENV = "FUEL_VALVE_IMPORTS_NORMAL_PRIORITY"


def start_at_normal_priority() -> int | None:
    """A node process the launcher started SCHED_FIFO (``tools.launcher.Scheduling``: right
    after exec) runs its imports -- numpy, scipy, numba, rclpy, the node's modules: most of its
    start-up's CPU -- at normal priority: this thread (the main thread) goes back to SCHED_OTHER
    and the priority is returned (None: :data:`IMPORTS_NORMAL_ENV` not "1" -- the default --, not
    SCHED_FIFO, or not Linux), for :func:`~fuel_valve_control.ros.node_runner.run_node` to give back before
    ``rclpy.init`` (:func:`~fuel_valve_control.ros.node_runner.restore_fifo`).

    Why (docs/control_results.md section 107): a start-up at SCHED_FIFO is a CPU burst no normal
    thread can interrupt.  Two of them (plant and controller, both priority 10) held both cores
    while the plant's tick thread, at the same priority, waited (SCHED_FIFO does not time-slice
    equals); and a second of it used a CPU's real-time budget (``sched_rt_runtime_us``, 95 % of
    each second), so the kernel throttled every real-time thread on it for up to 50 ms -- the
    plant's tick thread too, while the controller was armed.  (Kept at normal priority through
    the node's construction as well, the first enable came 1-2.5 s after activation instead of
    ~0.5 s on the loaded machine: not traced.)  Off by default: with the BLAS spin limited and
    ``faults.arm_steady_s`` those 36-54 ms stalls latched no fault in 8 start-ups, and imports at
    normal priority made the start-up 1.5-4 s slower at load 14-17 (section 107)."""
    if os.environ.get(IMPORTS_NORMAL_ENV, "").strip() != "1":
        return None
    try:
        if os.sched_getscheduler(0) != os.SCHED_FIFO:
            return None
        priority = os.sched_getparam(0).sched_priority
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        return priority
    except (OSError, AttributeError):       # not Linux / not permitted to read: leave it
        return None


#: the SCHED_FIFO priority this process was started with and runs its start-up without (None:
#: none; :func:`start_at_normal_priority`)
STARTUP_FIFO = start_at_normal_priority()

"""Test-side look-ahead for independent offline simulations: a module's many one-off runs on
both cores while its tests read them in order.

Why: the offline simulations are deterministic and independent of one another (a campaign case
gives the same run first in its process and after another case,
``test_run_determinism.py``), and a serial pytest runs them on one core of the two the suite is
measured on.  A module that knows which runs its selected tests will ask for hands them to
:class:`Ahead`; each test then takes its run (waiting for it if it is not done yet) and asserts
exactly what it asserted before -- the same function, the same arguments, the result pickled
back (floats and arrays, exact).  A run that was not planned is computed in the test's own
process, as before; a planned run no test asks for costs CPU, not correctness.

Off (every run computed where it is asked for, as before) when:

* ``FUEL_VALVE_TEST_JOBS=1`` (or fewer than two CPUs are ours);
* the machine has no free core when the module starts (:func:`idle_cpus` < :data:`FREE_CPU`;
  ``FUEL_VALVE_TEST_JOBS=2`` starts the workers anyway);
* pytest-xdist runs the suite (``-n``): its workers already use the cores;
* ``--sim-repeats`` is given: that report wraps ``sim.simulate_plan`` in this process and would
  not see the runs done in the worker processes.

The workers are forked (Linux): they start with this process's imports and caches (the gain
designs), so a worker costs no start-up; they run plain Python and numpy code only (no DDS).
"""
from __future__ import annotations

import concurrent.futures
import contextlib
import gc
import multiprocessing
import os
import time
from typing import Any, Callable, Hashable, Iterable

#: environment variable: the number of worker processes (default: min(2, CPUs of ours))
JOBS_ENV = "FUEL_VALVE_TEST_JOBS"


def jobs(config=None) -> int:
    """Worker processes to use for look-ahead runs; 1 means none (see the module docstring;
    ``conftest.py`` sets :data:`JOBS_ENV` to 1 for ``--sim-repeats``)."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        return 1
    if config is not None and config.getoption("--sim-repeats", default=False):
        return 1
    if os.environ.get(JOBS_ENV):
        return max(1, int(os.environ[JOBS_ENV]))
    ours = min(2, len(os.sched_getaffinity(0)))
    # only a free core gains: on a busy machine a second process gets little more CPU (autogroup
    # scheduling; measured 1.38x for two loops at load 12) and the workers cost 10-15 % more CPU
    # than one process, so there the runs stay in the test process (test_closed_loop alone at
    # load 10-12: 152 s in the test process, 170 s with two workers)
    if ours > 1 and idle_cpus() < FREE_CPU:
        return 1
    return max(1, ours)


#: idle CPUs (of the machine, over :data:`IDLE_WINDOW_S`) for the look-ahead to start workers
FREE_CPU = 0.8
IDLE_WINDOW_S = 0.2


def idle_cpus(window_s: float = IDLE_WINDOW_S) -> float:
    """CPUs of the machine left idle over the next ``window_s`` seconds (``/proc/stat``: idle +
    iowait ticks over all ticks, times the CPU count); ``inf`` where it cannot be read."""
    def ticks():
        with open("/proc/stat") as f:
            fields = [int(v) for v in f.readline().split()[1:9]]
        return fields[3] + fields[4], sum(fields)
    try:
        idle0, total0 = ticks()
        time.sleep(window_s)
        idle1, total1 = ticks()
    except (OSError, ValueError, IndexError):
        return float("inf")
    return (idle1 - idle0) / max(1, total1 - total0) * (os.cpu_count() or 1)


def selected_items(request) -> list:
    """The test items of the requesting module that this session will run (``-k``/``-m``
    and node-id selection applied), in run order."""
    return [item for item in request.session.items if getattr(item, "module", None) is request.module]


class Ahead:
    """``Ahead(fn, keys, jobs)``: ``fn(*key)`` for every key, started at once on ``jobs``
    worker processes (in the given order: put the longest first); :meth:`result` hands a run
    back (computed here when it was not planned or ``jobs`` is 1).  Use as a context manager:
    leaving it cancels what no test took and ends the workers."""

    def __init__(self, fn: Callable[..., Any], keys: Iterable[Hashable], jobs: int):
        self._fn = fn
        #: keys asked for but not planned (run here), and planned but never asked for: both
        #: should stay empty (a module's plan that drifted from its tests)
        self.unplanned: list[Hashable] = []
        self.unused: list[Hashable] = []
        self._futures: dict[Hashable, concurrent.futures.Future] = {}
        self._pool = None
        keys = list(dict.fromkeys(keys))
        if jobs > 1 and len(keys) > 1:
            # the workers must not run finalizers of objects they inherit: a ROS module just before
            # leaves rclpy objects for the garbage collector, whose finalizers call into DDS,
            # whose threads a forked child does not have -- the worker died ("A process in the
            # process pool was terminated abruptly", test_steady_load after test_sros2_policy,
            # test_heavy_valve after test_fuzz_nodes).  So collect them here, where DDS runs, and
            # freeze what is left out of the children's collections while they are forked.
            gc.collect()
            gc.freeze()
            try:
                self._pool = concurrent.futures.ProcessPoolExecutor(
                    max_workers=jobs, mp_context=multiprocessing.get_context("fork"))
                self._futures = {key: self._pool.submit(fn, *key) for key in keys}
            finally:
                gc.unfreeze()

    def result(self, *key):
        """``fn(*key)``: the worker's run if it was planned, else run here."""
        future = self._futures.pop(key, None)
        if future is None:
            if self._pool is not None:
                self.unplanned.append(key)
            return self._fn(*key)
        return future.result()

    def close(self) -> None:
        self.unused = list(self._futures)
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        self._futures.clear()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class ModuleRuns:
    """A test module's look-ahead slot: :meth:`result` hands back ``fn(*key)`` -- from the workers
    while :meth:`planned` is active (the module fixture), computed here otherwise."""

    def __init__(self, fn: Callable[..., Any]):
        self._fn = fn
        self._ahead = Ahead(fn, (), jobs=1)

    def result(self, *key):
        return self._ahead.result(*key)

    def waiting(self, *key) -> bool:
        """Whether ``key`` is planned on the workers and not taken yet (:meth:`result` would hand back the
        worker's run; else it computes it here)."""
        return key in self._ahead._futures

    @contextlib.contextmanager
    def planned(self, keys: Iterable[Hashable], jobs: int):
        """Start ``keys`` on ``jobs`` workers for the duration of the ``with`` block (see
        :class:`Ahead`); afterwards every run is computed here again."""
        with Ahead(self._fn, keys, jobs) as ahead:
            self._ahead = ahead
            try:
                yield ahead
            finally:
                self._ahead = Ahead(self._fn, (), jobs=1)

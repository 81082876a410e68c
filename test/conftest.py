"""Shared test configuration: markers and one DDS domain per ROS test module.

Markers (``--strict-markers`` is on, see setup.cfg):

* ``ros`` -- the test starts ROS 2 nodes or participants (needs rclpy and DDS);
* ``slow`` -- the test takes more than a few seconds (``-m "not slow"`` for a quick run).

Every module marked ``ros`` runs in a DDS domain of its own, taken from
:func:`allocate_domain`: an exclusive file lock per domain ID, so two test modules, two
pytest processes or a test and a benchmark on the same machine never share a domain.

With pytest-xdist (``-n 2``, opt-in: ``bash scripts/test.sh -n 2``) the tests go to the workers in whole
work units, in collection order (:func:`pytest_xdist_make_scheduler`): every ``ros`` module in
one unit (one DDS module at a time, as in a serial run: the real-time tests never share the
machine with another module's nodes, only with the other worker's offline work), every other
module as a unit of its own (its module fixtures and result caches are built once).

``--cpu-durations=N`` prints the N tests that used the most CPU time (set-up, call and
tear-down; this process's threads and the node processes it waited for), beside their wall
time, then the N with the most wall time, then every module's totals: on a machine shared
with other work, wall time says more about the neighbours than about the test.

Look-ahead (``test/prefetch.py``): the heaviest offline modules (``test_closed_loop``,
``test_fuzz``'s parameter boundaries, ``test_dissertation_modes``, ``test_valve_tests``,
``test_campaign_robustness``, ``test_fine_positioning``'s campaign sample, ``test_breakaway_start``,
``test_heavy_valve``; since stop 23 ``test_pressure_input``, ``test_ramp_tracking``,
``test_move_breakaway_read``, ``test_loop_timing``, ``test_plateau_step_overshoot``,
``test_other_valves``, ``test_steady_load``, ``test_friction_check``'s campaign plants) hand their
independent simulations to two forked worker processes when the module starts; each test still
takes and asserts its own run.  Only when a core is free as the module starts (on a busy machine the
workers cost more than they gain); off with ``FUEL_VALVE_TEST_JOBS=1`` (``=2``: on regardless),
under pytest-xdist and with ``--sim-repeats``.  The DDS modules never run beside it (the pool ends with its module).

``--sim-repeats`` lists the offline simulations (``sim.simulate_plan``, every scenario and
campaign run goes through it) that ran more than once with the same inputs, and the CPU the
repeats cost: the candidates for sharing one run between tests.  Serial runs only (with
pytest-xdist each worker keeps its own list and none is printed).  Loops a test closes itself
(``exchange_period``, ``test/snapshots.py``) are not seen.
"""
from __future__ import annotations

import fcntl
import os
import tempfile
import time
from pathlib import Path

import pytest

#: domain IDs the tests may use (0 is left to whatever a user runs by hand; ≤ 101 keeps the
#: default RTPS port mapping valid for many participants per domain)
DOMAIN_RANGE = range(30, 100)
LOCK_DIR = Path(tempfile.gettempdir()) / "fuel_valve_ros_domains"


def allocate_domain():
    """``(domain_id, lock_file)``: a domain ID no other holder uses; keep the file open while
    the domain is in use, close it to release."""
    LOCK_DIR.mkdir(exist_ok=True)
    start = os.getpid() % len(DOMAIN_RANGE)
    for i in range(len(DOMAIN_RANGE)):
        domain = DOMAIN_RANGE[(start + i) % len(DOMAIN_RANGE)]
        handle = open(LOCK_DIR / f"{domain}.lock", "w")
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        return domain, handle
    raise RuntimeError(f"no free ROS domain ID in {DOMAIN_RANGE}")


#: the pytest-xdist work unit of every module marked ``ros``
ROS_GROUP = "ros"
_ROS_MODULES: dict[str, bool] = {}


def is_ros_module(path) -> bool:
    """Whether the test module at ``path`` marks tests ``ros`` (read from its source: the
    pytest-xdist controller sees test ids, not the collected items and their markers)."""
    key = str(path)
    if key not in _ROS_MODULES:
        try:
            _ROS_MODULES[key] = "pytest.mark.ros" in Path(path).read_text()
        except OSError:
            _ROS_MODULES[key] = False
    return _ROS_MODULES[key]


def work_unit(nodeid: str, rootdir: Path) -> str:
    """The pytest-xdist work unit of a test: :data:`ROS_GROUP` for the ``ros`` modules, else
    its module."""
    module = nodeid.split("::", 1)[0]
    return ROS_GROUP if is_ros_module(rootdir / module) else module


@pytest.hookimpl(tryfirst=True, optionalhook=True)     # a hook of pytest-xdist: without it, unused
def pytest_xdist_make_scheduler(config, log):
    """``-n N``: whole work units (:func:`work_unit`) per worker, in collection order."""
    if config.getvalue("dist") == "each":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class WorkUnitScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return work_unit(nodeid, config.rootpath)

    config.option.loadscopereorder = False     # collection order: the DDS unit starts early
    return WorkUnitScheduling(config, log)


def pytest_collection_modifyitems(config, items):
    # the source check of is_ros_module must agree with the markers pytest collected
    for item in items:
        if item.get_closest_marker("ros") is not None and not is_ros_module(item.path):
            raise pytest.UsageError(f"{item.nodeid} is marked ros but its module's source has no 'pytest.mark.ros' "
                                    "(conftest.work_unit would run it beside other DDS tests)")


def pytest_addoption(parser):
    parser.addoption("--cpu-durations", type=int, default=None, metavar="N",
                     help="print the N tests with the most CPU time (own + waited-for children), with wall time")
    parser.addoption("--sim-repeats", action="store_true", default=False,
                     help="print the offline simulations (sim.simulate_plan) run more than once with the same inputs")


#: --sim-repeats: (inputs key, CPU s, test id, plan name, simulated s) of every simulate_plan call
_SIM_CALLS: list[tuple[str, float, str, str, float]] = []
_SIM_TEST = {"id": ""}


def _plan_key(plan, baselines) -> str:
    """A digest of everything a :func:`~fuel_valve_control.tools.sim.simulate_plan` run depends
    on: two runs with the same key give the same result (the simulator is deterministic)."""
    import hashlib
    import json
    doc = dict(name=plan.name, timing=plan.timing, duration=plan.duration_s, demand=repr(plan.demand_spec),
               plant=sorted((k, repr(v)) for k, v in dict(plan.plant_params).items()),
               controller=sorted((k, repr(v)) for k, v in dict(plan.controller_params).items()),
               initial=plan.initial_percent, events=repr(plan.events), baselines=repr(list(baselines)))
    return hashlib.sha1(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


#: the directory this session's lazily built move tables are shared through (:func:`pytest_configure`)
_LAZY_TABLES: dict[str, str] = {}


def pytest_configure(config):
    # C1's move tables (core/pulse_moves.py, ~0.12 s of CPU each) built lazily by the offline runs: shared through a
    # directory of this session's (FUEL_VALVE_MOVE_TABLES_LAZY), so the look-ahead workers, the node processes and
    # the modules build each table once, not once per process; read back a table is the built one bit for bit.  A
    # directory set by the caller is used as it is (and kept).
    from fuel_valve_control.core.pulse_moves import LAZY_CACHE_ENV
    if os.environ.get(LAZY_CACHE_ENV) is None:
        _LAZY_TABLES["dir"] = os.environ[LAZY_CACHE_ENV] = tempfile.mkdtemp(prefix="fuel_valve_test_tables_")
    if not config.getoption("--sim-repeats"):
        return
    # every run in this process, where the wrapper below sees it: no look-ahead workers (prefetch.py)
    os.environ["FUEL_VALVE_TEST_JOBS"] = "1"
    # wrapped before the test modules import it (``from ... import simulate_plan`` included);
    # the run itself is untouched, only timed and keyed
    from fuel_valve_control.tools import sim
    run = sim.simulate_plan

    def timed(plan, baselines=()):
        key, t0 = _plan_key(plan, baselines), time.process_time()
        result = run(plan, baselines)
        _SIM_CALLS.append((key, time.process_time() - t0, _SIM_TEST["id"], plan.name, plan.duration_s))
        return result
    sim.simulate_plan = timed


def pytest_unconfigure(config):
    if "dir" in _LAZY_TABLES:
        import shutil
        shutil.rmtree(_LAZY_TABLES.pop("dir"), ignore_errors=True)


@pytest.fixture
def own_table_builds(monkeypatch):
    """A test that counts the move tables a PulseMoves builds: no table comes from the session's shared directory."""
    from fuel_valve_control.core.pulse_moves import LAZY_CACHE_ENV
    monkeypatch.delenv(LAZY_CACHE_ENV, raising=False)


_CPU_START: dict[str, os.times_result] = {}     # nodeid -> os.times() at its set-up
_CPU_TIMES: dict[str, tuple[float, float, float]] = {}      # nodeid -> (wall, own CPU, children CPU), s


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    _SIM_TEST["id"] = item.nodeid
    if item.config.getoption("--cpu-durations") is not None:
        _CPU_START[item.nodeid] = os.times()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    t0 = _CPU_START.pop(item.nodeid, None) if call.when == "teardown" else None
    if t0 is not None:
        # on the report, so that it reaches the main process from a pytest-xdist worker too
        t1 = os.times()
        outcome.get_result().user_properties.append(("cpu_times", (
            t1.elapsed - t0.elapsed, t1.user + t1.system - t0.user - t0.system,
            t1.children_user + t1.children_system - t0.children_user - t0.children_system)))


def pytest_runtest_logreport(report):
    for key, value in report.user_properties:
        if key == "cpu_times":
            _CPU_TIMES[report.nodeid] = tuple(value)


def pytest_terminal_summary(terminalreporter, config):
    if config.getoption("--sim-repeats"):
        _report_sim_repeats(terminalreporter)
    n = config.getoption("--cpu-durations")
    if n is None or not _CPU_TIMES:
        return
    rows = sorted(_CPU_TIMES.items(), key=lambda kv: -(kv[1][1] + kv[1][2]))
    wall, own, kids = (sum(v[i] for v in _CPU_TIMES.values()) for i in range(3))
    terminalreporter.write_sep("=", f"cpu durations (top {n}): wall / own CPU / children CPU, s")
    for nodeid, (w, o, c) in rows[:n] if n > 0 else rows:
        terminalreporter.write_line(f"{w:8.2f} {o:8.2f} {c:8.2f}  {nodeid}")
    terminalreporter.write_line(f"{wall:8.2f} {own:8.2f} {kids:8.2f}  total over {len(_CPU_TIMES)} tests")
    # by wall too: the DDS tests wait in real time (start-up, loops that must run), so the tests
    # that hold the suite's clock are not the ones that use the CPU
    if n > 0:
        terminalreporter.write_sep("=", f"wall durations (top {n}): wall / own CPU / children CPU, s")
        for nodeid, (w, o, c) in sorted(_CPU_TIMES.items(), key=lambda kv: -kv[1][0])[:n]:
            terminalreporter.write_line(f"{w:8.2f} {o:8.2f} {c:8.2f}  {nodeid}")
    # per module too: where a module's time goes is the question a trim starts from (one
    # module's many cheap cases can outweigh its one slow test); the DDS modules' wall beyond
    # their CPU is waiting (real time, start-up), not work
    modules: dict[str, list[float]] = {}
    for nodeid, times in _CPU_TIMES.items():
        acc = modules.setdefault(nodeid.split("::", 1)[0], [0.0, 0.0, 0.0, 0])
        for i in range(3):
            acc[i] += times[i]
        acc[3] += 1
    terminalreporter.write_sep("=", "cpu durations per module: wall / own CPU / children CPU, s (tests)")
    for module, (w, o, c, count) in sorted(modules.items(), key=lambda kv: -(kv[1][1] + kv[1][2])):
        ros = " [ros]" if is_ros_module(config.rootpath / module) else ""
        terminalreporter.write_line(f"{w:8.2f} {o:8.2f} {c:8.2f}  {module} ({count}){ros}")


def _report_sim_repeats(terminalreporter):
    by_key: dict[str, list] = {}
    for key, cpu, test, name, duration in _SIM_CALLS:
        by_key.setdefault(key, []).append((cpu, test, name, duration))
    repeats = sorted(((k, v) for k, v in by_key.items() if len(v) > 1), key=lambda kv: -sum(c for c, *_ in kv[1][1:]))
    total = sum(c for _, c, *_ in _SIM_CALLS)
    extra = sum(c for _, v in repeats for c, *_ in v[1:])
    terminalreporter.write_sep("=", f"offline simulations: {len(_SIM_CALLS)} runs, {total:.1f} s CPU; "
                                    f"{len(repeats)} inputs run more than once, {extra:.1f} s CPU in the repeats")
    for _, runs in repeats:
        _, _, name, duration = runs[0]
        terminalreporter.write_line(f"{sum(c for c, *_ in runs[1:]):7.2f} s  {len(runs)} x {name} ({duration:g} s): "
                                    + ", ".join(sorted({t for _, t, _, _ in runs})))


@pytest.fixture(scope="module", autouse=True)
def ros_domain(request):
    """For modules marked ``ros``: set ``ROS_DOMAIN_ID`` to a domain of their own (inherited by
    the node processes they start) for the module's lifetime."""
    if request.node.get_closest_marker("ros") is None:
        yield None
        return
    domain, handle = allocate_domain()
    old = os.environ.get("ROS_DOMAIN_ID")
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    try:
        yield domain
    finally:
        if old is None:
            os.environ.pop("ROS_DOMAIN_ID", None)
        else:
            os.environ["ROS_DOMAIN_ID"] = old
        handle.close()


def load_benchmark(name: str):
    """``benchmarks/<name>.py`` as a module (benchmarks are scripts, not a package)."""
    import importlib.util
    path = Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"{name}_bench", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="session")
def robustness_bench():
    """``benchmarks/robustness.py`` as a module (its case sampling and runner)."""
    return load_benchmark("robustness")


@pytest.fixture(scope="session")
def freezes_bench():
    """``benchmarks/vcpu_freezes.py`` as a module (the closed loop with controller freezes)."""
    return load_benchmark("vcpu_freezes")

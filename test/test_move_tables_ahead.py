"""The doublet's move tables built ahead (task h34t, ``fine.apex_policy``, docs §80.9 / §81).

With ``fine.apex_policy`` the fine stage reads keyed Δp x angle tables of the doublet's move
(:class:`~fuel_valve_control.core.pulse_moves.PulseMoves`); built lazily, each costs ~0.12 s of CPU inside the
period that first needs it.  :meth:`PositionController.prepare` (the fine stage's :meth:`FinePositioner.prepare`)
builds every table the policy can ask for.  Here: after ``prepare()`` no update builds or simulates anything; with
the option off nothing is made.

Task h36b: the ROS node no longer builds them in its configure (C1: 342 tables, ~41 s): the tables are cached on disk
(one ``.npz`` per key under a signature hash) and built by a background process (``TableBuild``); the fine stage runs
main's staircase until they are adopted (``FinePositioner.defer_tables`` / ``release_tables``), and a run-time change
that needs new tables starts such a build instead of being refused (``fine.apex_policy`` itself stays read-only).
Tested here: the cache's round trip (bit-equal), its signature, bad files, the worker (built, failed, cancelled), the
stage's gate (main's commands exactly until released, the policy from the next plateau), and the node.

The tables are built on a 2 x 2 (Δp x angle) grid here (the grid's corners: every Δp and angle still lies inside
it) instead of the default 19 x 3 -- the wiring is what is tested, not the grid (~1 s of CPU instead of ~14 s).
"""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

from fuel_valve_control.core.pulse_moves import PulseMoves
from fuel_valve_control.tools.sim import exchange_period

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import robustness as R  # noqa: E402

#: the small grid (fractions of the max Δp and of the stroke): its corners
SMALL_GRID = {"dp_grid": (0.0, 1.0), "angle_grid": (0.0, 1.0)}
#: the nominal-box run driven (its first apex-policy doublet comes within the first plateaus)
SEED = 1000
#: periods run after the build: past the first doublets the policy plans (nominal box seed 1000: the first
#: choice at period 357)
PERIODS = 800


@pytest.fixture(autouse=True)
def _counted(own_table_builds):
    """This module counts the tables its PulseMoves build (``builds`` / ``runs``): none read from the session's
    shared directory (conftest)."""


@pytest.fixture
def small_grid(monkeypatch):
    """Every move model the fine stage makes uses :data:`SMALL_GRID`."""
    make = PulseMoves.for_positioner.__func__

    def small(cls, fine, ps=None, **kw):
        return make(cls, fine, ps, **{**SMALL_GRID, **kw})

    monkeypatch.setattr(PulseMoves, "for_positioner", classmethod(small))


def _step(plan, plant, driver, k):
    """Period ``k`` of the closed loop (the simulator's exchange); returns the driver's output."""
    per = driver.period
    t = k * per
    out, _ = exchange_period(driver, plant, t, plan.demand.value(t))
    plant.set_command(out.current_a, out.enable)
    plant.advance(per)
    return out


def _run(plan, plant, driver, periods):
    for k in range(periods):
        _step(plan, plant, driver, k)


def test_prepare_builds_every_table_the_apex_policy_reads(small_grid, monkeypatch):
    # the engage gate off (C1's): with C3's (fine.engage_gear_rest 0.1, the default since stop 28) this case's first
    # doublet comes after the periods run; the choice (C2's mixture law) reads the same tables
    plan, plant, driver = R.held_case(R.sample_case(SEED, "nominal"),
                                      controller_sets={"fine.apex_policy": True, "fine.engage_gear_rest": 0.0})
    ctl = driver.controller
    fine = ctl.law.fine
    moves = fine._moves                                # made with the law, on the told model: no table built
    assert moves is not None and moves.builds == 0 and moves.m is fine.m0
    pending, _ = ctl.prepare()
    assert fine._moves is moves and moves.pending(kicks=fine._apex_kicks()) == []
    # directions x Δp x angle points x kicks (some may be shared; C1's default kicks 4 / 8 / 16 A since stop 25, docs §91)
    assert pending <= 2 * 2 * 2 * len(fine._apex_kicks())
    assert ctl.prepare(build=False) == (0, 0.0)        # nothing left
    builds, runs = moves.builds, moves.runs
    choices = []
    choose = fine._choose_apex

    def counted(*a, **kw):
        choices.append(a)
        return choose(*a, **kw)

    monkeypatch.setattr(fine, "_choose_apex", counted)
    _run(plan, plant, driver, PERIODS)
    assert choices, "no doublet was planned in the periods run: the check saw no table read"
    assert fine._moves is moves
    assert (moves.builds, moves.runs) == (builds, runs), "a table was built inside an update after prepare()"


def test_prepare_makes_nothing_with_the_apex_policy_off():
    # off explicitly: C1 (the apex policy with kicks to 16 A) is the default since stop 25 (task h36f, docs §91)
    plan, plant, driver = R.held_case(R.sample_case(SEED, "nominal"), controller_sets={"fine.apex_policy": False})
    ctl = driver.controller
    assert ctl.prepare() == (0, 0.0)
    assert ctl.law.fine._moves is None
    _run(plan, plant, driver, 300)
    assert ctl.law.fine._moves is None


def _settle(node, timeout=120.0):
    """Run the node's table poll (its steady timer's callback) until no build is left."""
    t0 = time.monotonic()
    while node._table_build is not None or node._table_next is not None:
        assert time.monotonic() - t0 < timeout, node._tables_status
        node._poll_tables()
        time.sleep(0.05)


@pytest.mark.ros
def test_node_configure_returns_at_once_and_the_tables_come_from_a_background_build(small_grid, tmp_path,
                                                                                    monkeypatch):
    """(task h36b) The node's configure builds no table: a background process does (the stage on main's staircase
    meanwhile), the poll adopts them and releases the stage; a run-time change that needs new tables starts another
    build instead of being refused; a restart reads the cache; a cleanup ends a build still running."""
    from collections import OrderedDict
    rclpy = pytest.importorskip("rclpy")
    from rclpy.parameter import Parameter
    from fuel_valve_control.ros.controller_node import ControllerNode
    from fuel_valve_control.core import pulse_moves as pmod

    monkeypatch.setenv(pmod.CACHE_ENV, str(tmp_path / "cache"))
    monkeypatch.setattr(pmod, "_SHARED", OrderedDict())
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        node = ControllerNode(context=ctx, namespace="/tables_on", parameter_overrides=[
            Parameter("autostart", value=False), Parameter("fine.apex_policy", value=True),
            Parameter("fine.apex_kick_max_a", value=0.0)])     # main's 4 A kick only (C1's 16 A is the default)
        assert node.driver is None
        node.trigger_configure()
        fine = node.driver.controller.law.fine
        moves = fine.moves
        assert fine.tables_deferred and not fine.cfg.apex_policy and moves.builds == 0     # nothing built here
        assert node._table_build is not None and node._tables_status.startswith(("reading", "building"))
        _settle(node)
        assert node._tables_status.startswith("ready") and "built" in node._tables_status, node._tables_status
        assert fine._tables_gate == "released" and moves.pending(kicks=fine._apex_kicks()) == [] and moves.builds == 0
        # kicks to 16 A: tables for 8 and 16 A -- accepted, built in the background (the new law on the staircase)
        res = node.set_parameters([Parameter("fine.apex_kick_max_a", value=16.0)])[0]
        assert res.successful, res.reason
        assert node._table_build is not None
        new_fine = node._table_waiters[-1]()                # (held weakly, task h37b)
        assert new_fine is not fine and new_fine.tables_deferred and new_fine.cfg.apex_kick_max_a == 16.0
        _settle(node)
        assert new_fine._tables_gate == "released" and node._tables_status.startswith("ready"), node._tables_status
        res = node.set_parameters([Parameter("fine.apex_policy", value=False)])[0]
        assert not res.successful and "read-only" in res.reason, res.reason        # not a run-time parameter
        res = node.set_parameters([Parameter("fine.apex_land_rad", value=3e-4)])[0]   # its tables serve it
        assert res.successful, res.reason
        assert node._table_build is None
        node.destroy_node()

        # a restart in real time: every table in the cache -- read by the build's thread, no worker process
        monkeypatch.setattr(pmod, "_SHARED", OrderedDict())
        node = ControllerNode(context=ctx, namespace="/tables_warm_rt", parameter_overrides=[
            Parameter("autostart", value=False), Parameter("fine.apex_policy", value=True)])
        node.trigger_configure()
        build = node._table_build
        assert build is not None and node.driver.controller.law.fine.tables_deferred
        _settle(node)
        assert build.process is None and "loaded from cache" in node._tables_status, node._tables_status
        assert node.driver.controller.law.fine._tables_gate == "released"
        node.destroy_node()
        # ... in lockstep: what the cache holds read at configure itself, never a gate or a worker (simulated time
        # waits for the controller: the rest would be built lazily, as offline) -- the policy from the first plateau
        monkeypatch.setattr(pmod, "_SHARED", OrderedDict())
        node = ControllerNode(context=ctx, namespace="/tables_warm", parameter_overrides=[
            Parameter("autostart", value=False), Parameter("fine.apex_policy", value=True),
            Parameter("lockstep", value=True)])
        node.trigger_configure()
        fine = node.driver.controller.law.fine
        n = len(fine.moves._tables)
        assert node._table_build is None and f"lockstep: {n} of {n} loaded from cache" in node._tables_status, \
            node._tables_status
        assert fine._tables_gate is None and not fine.tables_deferred and fine.moves.builds == 0
        # ... and in lockstep on another signature (one retreat period, not in the cache): still no gate, no worker
        node.trigger_cleanup()
        assert node.set_parameters([Parameter("fine.apex_retreat_periods", value=1)])[0].successful
        node.trigger_configure()
        fine = node.driver.controller.law.fine
        assert node._table_build is None and node._tables_status.startswith("lockstep: 0 of "), node._tables_status
        assert fine._tables_gate is None and fine.cfg.apex_policy and fine.moves.builds == 0
        node.destroy_node()
        # another signature in real time: a build; cleanup while it runs ends its worker
        monkeypatch.setattr(pmod, "_SHARED", OrderedDict())
        node = ControllerNode(context=ctx, namespace="/tables_cleanup", parameter_overrides=[
            Parameter("autostart", value=False), Parameter("fine.apex_policy", value=True),
            Parameter("fine.apex_retreat_periods", value=1)])
        node.trigger_configure()
        build = node._table_build
        assert build is not None and node.driver.controller.law.fine.tables_deferred
        t0 = time.monotonic()
        while build.state == "reading":
            assert time.monotonic() - t0 < 60.0
            time.sleep(0.02)
        node.trigger_cleanup()
        assert node._table_build is None and build.cancelled
        # (task h37d) the cleanup, under the loop's lock, only signals the worker; the reader reaps it: no orphan
        build._thread.join(30.0)                                                  # (the reader ends by itself)
        assert build.process is None or build.process.poll() is not None
        assert build.state in ("cancelled", "ready"), build.status()
        node.destroy_node()

        node = ControllerNode(context=ctx, namespace="/tables_off", parameter_overrides=[
            Parameter("autostart", value=False), Parameter("fine.apex_policy", value=False)])   # on by default (C1)
        node.trigger_configure()
        assert node.driver.controller.law.fine.moves is None       # off: nothing made at configure
        assert node._tables_status == "off" and node._table_build is None
        assert not node.set_parameters([Parameter("fine.apex_policy", value=True)])[0].successful
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.mark.ros
def test_node_run_time_changes_start_at_most_one_build_and_keep_no_replaced_stage(small_grid, tmp_path, monkeypatch):
    """(task h37b) The node's run-time path is bounded: changes that leave the move model's signature alone start no
    build and no read of their own (they wait for the one in progress, here never polled -- as in test_fuzz_nodes,
    whose boundary values grew the process past 5 GB with C1 on); a replaced waiting law's stage is not kept (weakly
    held, dropped); changes of the signature leave at most one build alive (thread or worker), the newest request
    wins, and the process keeps at most ``SHARED_SIGNATURES`` stores; /diagnostics' line follows."""
    import gc
    import weakref
    from collections import OrderedDict
    rclpy = pytest.importorskip("rclpy")
    from rclpy.parameter import Parameter
    from fuel_valve_control.ros import controller_node as cn
    from fuel_valve_control.core import pulse_moves as pmod

    monkeypatch.setenv(pmod.CACHE_ENV, str(tmp_path / "cache"))
    monkeypatch.setattr(pmod, "_SHARED", OrderedDict())
    made = []

    class Counted(pmod.TableBuild):
        def __init__(self, *args, **kw):
            super().__init__(*args, **kw)
            made.append(self)

    monkeypatch.setattr(cn, "TableBuild", Counted)
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        node = cn.ControllerNode(context=ctx, namespace="/tables_bounded", parameter_overrides=[
            Parameter("autostart", value=False), Parameter("fine.apex_policy", value=True),
            Parameter("fine.apex_kick_max_a", value=0.0), Parameter("fine.apex_retreat_periods", value=1)])
        node.trigger_configure()
        assert len(made) == 1 and node.driver.controller.law.fine.tables_deferred
        waiting = []
        for k in range(4):                   # a law parameter, not the move model's: one signature
            assert node.set_parameters([Parameter("fine.apex_land_rad", value=3.0e-4 + 1e-5 * k)])[0].successful
            waiting.append(weakref.ref(node.driver.waiting_law.fine))
            assert waiting[-1]().tables_deferred and waiting[-1]().moves.signature == made[0].moves.signature
        assert len(made) == 1 and node._table_build is made[0] and node._table_next is None     # no build, no read
        # the line is the build's own (a snapshot taken at the change: the build's thread may have moved on since)
        assert node._tables_status.startswith(("reading", "building", "ready")), node._tables_status
        gc.collect()
        assert [r() is None for r in waiting] == [True, True, True, False]     # the replaced ones: not retained
        assert len(node._table_waiters) == 2                                    # in force + the newest
        _settle(node)
        assert waiting[-1]()._tables_gate == "released" and node._tables_status.startswith("ready")
        assert node.driver.controller.law.fine._tables_gate == "released"       # the one in force too (same store)
        # the move model's signature changed again and again, never polled in between: one build alive at most
        for periods in (2, 3, 2, 1, 3):
            assert node.set_parameters([Parameter("fine.apex_retreat_periods", value=periods)])[0].successful
            assert sum(b.alive() for b in made) <= 1, [b.status() for b in made]
            assert len(pmod._SHARED) <= pmod.SHARED_SIGNATURES
            # (1: the configure's signature, its tables in memory -- no build; the others' builds were cut short)
            assert node._tables_status.startswith(("ready: 8 of 8 in memory",) if periods == 1 else
                                                  ("starting", "reading", "building")), node._tables_status
        assert len(made) <= 1 + 1 + 4
        _settle(node)
        fine = node.driver.waiting_law.fine
        assert fine.cfg.apex_retreat_periods == 3 and fine._tables_gate == "released"     # the newest one's
        assert node._tables_status.startswith("ready"), node._tables_status
        assert not any(b.alive() for b in made)
        # a change back to a signature whose tables are in memory: nothing to build, the line says so
        assert node.set_parameters([Parameter("fine.apex_land_rad", value=3.5e-4)])[0].successful
        built = len(made)
        assert node.set_parameters([Parameter("fine.apex_retreat_periods", value=1)])[0].successful
        assert node._table_build is None and node._table_next is None and len(made) == built
        assert node._tables_status == "ready: 8 of 8 in memory (no build)", node._tables_status
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


# ---------------------------------------------------------------------- task h36b: the disk cache, the background build
import dataclasses  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from fuel_valve_control.core import pulse_moves as pmod  # noqa: E402
from fuel_valve_control.core.model import NominalModel  # noqa: E402
from fuel_valve_control.core.params import CONTROLLER_SPEC  # noqa: E402

#: two keys of a small model (a table each, ~0.1 s): (direction, Δp kPa, kick A, angle rad) at max Δp, angle 0
MODEL = NominalModel.from_params(CONTROLLER_SPEC.defaults())


def _moves(**kw) -> PulseMoves:
    args = dict(kick_current_a=4.0, peak_current_a=29.6, retreat_full_periods=1, servo_kp=50.0, servo_kd=0.3,
                servo_ki=600.0, share=False, **SMALL_GRID)
    args.update(kw)
    return PulseMoves(kw.pop("model", MODEL) if "model" in kw else MODEL, 1e-3,
                      **{k: v for k, v in args.items() if k != "model"})


def _keys(moves, n=2):
    return moves._needed(None, (1, -1), None)[:n]


def test_cache_round_trip_is_bit_equal(tmp_path):
    """A table saved and read back (another PulseMoves of the same settings, as the node's loader thread reads what
    the worker process wrote) equals the one built, bit for bit, and answers the same moves."""
    built = _moves()
    keys = _keys(built)
    assert built.build_and_save(tmp_path, keys) == 2
    other = _moves()
    got = other.read_cached(tmp_path, keys)
    assert sorted(got) == sorted(keys)
    for key in keys:
        tab, rise = got[key]
        ref = built._tables[key]
        for name in pmod._TABLE_FIELDS:
            a, b = np.asarray(tab[name]), np.asarray(ref[name])
            assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=True), name
        assert rise == built._rises[key]
    assert other.adopt(got) == 2 and other.builds == 0
    d, p, kick, th = keys[0]
    x, od, aim = np.meshgrid(np.linspace(0, 2e-3, 7), np.geomspace(1e-5, 1e-3, 5), np.linspace(0, 5e-4, 3))
    np.testing.assert_array_equal(other.move(d, p, x, od, kick_current_a=kick, aim_rad=aim, valve_angle_rad=th),
                                  built.move(d, p, x, od, kick_current_a=kick, aim_rad=aim, valve_angle_rad=th))
    assert other.builds == 0 and other.runs == 0                 # read from the adopted table: nothing simulated
    assert built.build_and_save(tmp_path, keys) == 0              # in the cache: nothing built again
    # (task h37b) a read asked to stop ends before its next file (a cancelled build lets go of it at once)
    asked = []
    assert _moves().read_cached(tmp_path, keys, stop=lambda: asked.append(1) or len(asked) > 1).keys() == {keys[0]}


def test_signature_follows_the_model_the_settings_the_version_and_the_code(monkeypatch):
    base = _moves().signature_hash()
    assert _moves().signature_hash() == base
    assert _moves(servo_kp=50).signature_hash() == base           # 50 and 50.0 are one setting (as in the share)
    assert _moves(model=dataclasses.replace(MODEL, coupling_stiffness_nm_per_rad=MODEL.coupling_stiffness_nm_per_rad
                                            * 1.01)).signature_hash() != base
    assert _moves(retreat_cap=True).signature_hash() != base
    assert _moves(servo_kp=51.0).signature_hash() != base
    monkeypatch.setattr(pmod, "TABLE_VERSION", pmod.TABLE_VERSION + 1)
    assert _moves().signature_hash() != base
    monkeypatch.undo()
    monkeypatch.setattr(pmod, "_SOURCE_DIGEST", "another build of the code")
    assert _moves().signature_hash() != base


def test_corrupt_partial_and_foreign_files_are_rebuilt_not_raised(tmp_path):
    moves = _moves()
    keys = _keys(moves)
    moves.build_and_save(tmp_path, keys)
    good = moves.table_file(tmp_path, keys[0]).read_bytes()
    # a partial write (a crash mid-file without the atomic replace), garbage, another key's file under this name
    moves.table_file(tmp_path, keys[0]).write_bytes(good[: len(good) // 2])
    moves.table_file(tmp_path, keys[1]).write_bytes(b"not a table")
    fresh = _moves()
    assert fresh.read_cached(tmp_path, keys) == {}
    foreign = _moves(retreat_cap=True)                            # another signature's file copied in
    foreign.build_and_save(tmp_path, keys[:1])
    moves.table_file(tmp_path, keys[1]).write_bytes(foreign.table_file(tmp_path, keys[0]).read_bytes())
    assert fresh.read_cached(tmp_path, keys) == {}
    assert fresh.build_and_save(tmp_path, keys) == 2              # rebuilt over them
    assert sorted(_moves().read_cached(tmp_path, keys)) == sorted(keys)
    assert not [p for p in moves.cache_dir(tmp_path).iterdir() if p.name.startswith(".tmp_")]   # no temporaries left


def _wait(build, states, timeout=120.0):
    t0 = time.monotonic()
    while build.state not in states:
        assert time.monotonic() - t0 < timeout, build.status()
        time.sleep(0.05)


def test_background_build_writes_the_cache_and_a_second_one_reads_it(tmp_path):
    """The worker process builds the tables into the cache; the next build (a restart) only reads them."""
    moves = _moves()
    keys = _keys(moves, 3)
    build = pmod.TableBuild(moves, keys, tmp_path, nice=0)
    _wait(build, ("ready", "failed"))
    assert build.state == "ready", build.status()
    assert build.built == 3 and build.from_cache == 0 and build.process.returncode == 0
    assert moves.builds == 0 and moves.adopt(build.tables) == 3 and moves.builds == 0   # built elsewhere
    again = pmod.TableBuild(_moves(), keys, tmp_path)
    _wait(again, ("ready", "failed"))
    assert again.state == "ready" and again.from_cache == 3 and again.process is None    # no worker started
    assert "3 of 3" in again.status() and "loaded from cache" in again.status()


def test_a_failed_worker_is_a_state_not_an_exception(tmp_path, monkeypatch):
    monkeypatch.setattr(pmod, "WORKER_CODE", "import sys; sys.stderr.write('boom\\n'); sys.exit(3)")
    build = pmod.TableBuild(_moves(), _keys(_moves()), tmp_path)
    _wait(build, ("ready", "failed"))
    assert build.state == "failed" and "code 3" in build.reason and "boom" in build.reason, build.reason
    assert build.tables is None


def test_cancel_ends_the_worker_process(tmp_path):
    big = _moves(dp_grid=pmod.DP_GRID, angle_grid=pmod.ANGLE_GRID)
    build = pmod.TableBuild(big, big._needed(None, (1, -1), None), tmp_path)
    _wait(build, ("building", "failed"))
    proc = build.process
    build.cancel()
    assert build.state == "cancelled" and proc.poll() is not None     # ended, not orphaned


#: a worker that ignores SIGTERM: marks that it has (the file named in $H37D_WORKER_MARK), then sleeps
_STUBBORN_WORKER = ("import os, signal, time, pathlib; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
                    "pathlib.Path(os.environ['H37D_WORKER_MARK']).touch(); time.sleep(120)")


def _stubborn_build(tmp_path, monkeypatch):
    """A background build whose worker ignores SIGTERM (grace time 0.2 s), returned once that worker is running."""
    mark = tmp_path / "ignoring_sigterm"
    monkeypatch.setenv("H37D_WORKER_MARK", str(mark))
    monkeypatch.setattr(pmod, "WORKER_CODE", _STUBBORN_WORKER)
    monkeypatch.setattr(pmod, "STOP_GRACE_S", 0.2)
    moves = _moves()
    build = pmod.TableBuild(moves, _keys(moves), tmp_path / "cache")
    t0 = time.monotonic()
    while not mark.exists():
        assert time.monotonic() - t0 < 60.0 and build.state in ("reading", "building"), build.status()
        time.sleep(0.02)
    return build


def test_a_cancel_under_the_loop_lock_never_waits_for_the_worker(tmp_path, monkeypatch):
    """(task h37d) ``cancel(0)`` -- the controller node's call under its 1 kHz loop's lock -- only signals the
    worker: with a worker that ignores SIGTERM it returns while the worker still runs (it used to wait up to
    2 s + 2 s there); the reading thread then kills the worker after the grace time and reaps it (no zombie, no
    orphan), and the build ends cancelled."""
    import os
    import signal
    build = _stubborn_build(tmp_path, monkeypatch)
    proc = build.process
    build.cancel(0.0)
    assert proc.poll() is None, "cancel(0) waited for the worker to end"       # SIGTERM ignored: still running
    assert build.cancelled and build.alive()
    t0 = time.monotonic()
    while build.alive():
        assert time.monotonic() - t0 < 60.0, build.status()
        time.sleep(0.02)
    assert proc.returncode == -signal.SIGKILL                  # killed after the grace time ...
    with pytest.raises(ChildProcessError):                     # ... and reaped: no zombie left
        os.waitpid(proc.pid, os.WNOHANG)
    assert build.state == "cancelled"


def test_the_destroy_cancel_ends_a_stubborn_worker_itself(tmp_path, monkeypatch):
    """``cancel(timeout > 0)`` (the node's destroy) ends and reaps the worker before it returns, SIGTERM ignored."""
    import signal
    build = _stubborn_build(tmp_path, monkeypatch)
    proc = build.process
    build.cancel(5.0)
    assert proc.returncode == -signal.SIGKILL and not build.alive()


def test_the_stage_runs_main_staircase_until_the_tables_are_released(small_grid, monkeypatch):
    """Deferred (the node's path): the stage with ``fine.apex_policy`` runs exactly as with it off -- the same
    commands period for period -- and reads no table; released mid-plateau, the policy takes over at the next
    plateau (not mid-engagement), from the adopted tables (nothing built in an update)."""
    from collections import OrderedDict
    monkeypatch.setattr(pmod, "_SHARED", OrderedDict())  # no table another test built in this process
    sets = {"fine.apex_policy": True}
    plan, plant, driver = R.held_case(R.sample_case(SEED, "nominal"), controller_sets=sets)
    # main's staircase: the policy and the options measured with it as one build off (C1 is the default)
    from fuel_valve_control.core.fine_positioning import APEX_BUILD_OFF
    ref_plan, ref_plant, ref_driver = R.held_case(R.sample_case(SEED, "nominal"), controller_sets={
        f"fine.{f}": False for f in APEX_BUILD_OFF})
    ctl = driver.controller
    fine = ctl.law.fine
    deferred = ctl.defer_tables()
    assert deferred is not None and deferred[0] is fine
    fine_moves, keys = deferred[1], deferred[2]
    assert keys and fine.tables_deferred and not fine.cfg.apex_policy
    assert fine.defer_tables() == keys and fine.tables_deferred          # asked again: the same, still closed
    choices = []
    choose = fine._choose_apex
    monkeypatch.setattr(fine, "_choose_apex", lambda *a, **kw: choices.append(a) or choose(*a, **kw))
    per = driver.period
    # deferred through the periods where the policy would have chosen (period 357): main's commands exactly
    for k in range(PERIODS):
        out, ref = _step(plan, plant, driver, k), _step(ref_plan, ref_plant, ref_driver, k)
        assert out.current_a == ref.current_a, k
    assert not choices and fine_moves.builds == 0 and fine_moves.runs == 0
    assert not fine.release_tables()                       # nothing adopted yet: stays closed
    # "the background build": another model of the same signature builds them, this one adopts them
    other = PulseMoves(*fine_moves.spec()[:2], share=False, **fine_moves.spec()[2])
    other.prepare(kicks=fine._apex_kicks())
    fine_moves.adopt({k: (other._tables[k], other._rises[k]) for k in keys})
    assert fine.release_tables() and fine.tables_deferred
    builds, runs = fine_moves.builds, fine_moves.runs
    plateau = plan.demand.value(PERIODS * per)
    k, switched = PERIODS, None
    while not choices and k < PERIODS + 20000:
        t = k * per
        if switched is None and abs(plan.demand.value(t) - plateau) > 1e-9:
            switched = k
        _step(plan, plant, driver, k)
        if switched is None:
            assert fine.tables_deferred                    # not taken mid-plateau
        k += 1
    assert choices and switched is not None and not fine.tables_deferred and fine.cfg.apex_policy
    assert (fine_moves.builds, fine_moves.runs) == (builds, runs)

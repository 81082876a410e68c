"""``ros2 run fuel_valve controller``: the valve driver (position controller + fault logic).

A thin layer over :class:`~fuel_valve_control.core.driver.ValveDriver`, the same object the
offline simulator runs.  Each ``resolver`` sample triggers one control period (the sample
is the loop's clock, so the command leaves as soon as the measurement arrives); a watchdog
timer keeps the fault logic running when samples stop, so silence trips the drive too.

Topics (SPEC §4): subscribes ``demand`` (percent), ``demand_ma`` (4-20 mA), ``resolver``,
``pressure_differential`` (measured Δp, kPa: schedules the friction terms), ``drive_status``
(the drive's state word: a drive that switched itself off on its command watchdog is re-armed
from the measurement with the torque that holds the valve there and re-enabled,
``ValveDriver.drive_status``) and,
optionally, the plant's ``drive`` telemetry (measured current for the over-current check);
in real time the demand and Δp subscriptions accept writers of any reliability
(``interface.INPUT_QOS``), and ``/diagnostics`` names a second publisher, a publisher of the
wrong type, or a demand on the scaling ``demand_source`` does not read
(:meth:`ControllerNode._input_publishers`);
publishes ``current_command`` (A), ``drive_enable``, ``position`` (percent),
``estimate`` and ``/diagnostics``.  Services ``~/trip`` and ``~/reset`` (std_srvs/Trigger); the
valve tests' ``~/signature_test``, ``~/partial_stroke_test`` and latched ``valve_test``
(:mod:`.valve_test_services`).

With ``lockstep:=true`` (and ``use_sim_time:=true``) each period waits for a fresh demand as
well as the resolver sample, so runs are deterministic: the demand source is part of the
lockstep loop (the ``demand`` node with ``lockstep:=true`` publishes once per ``/clock``).
A resolver sample whose stamp has been answered already (the plant re-publishes a tick whose
command it has not received) is dropped, and the command is never re-sent: the plant steps
once per command, and an unstamped copy could not be told from the next period's.  So the
first command waits until ``current_command`` has matched the plant's subscription (a
command published before that would be lost, and the run would stall).  Start handshake: the
node's first ``drive_enable`` (false, latched) goes out once it can answer a sample, and the
plant starts only after receiving it (:meth:`ControllerNode._say_hello`).

A managed (lifecycle) node (``rclpy.lifecycle``, issue 12): ``configure`` reads and validates
the parameters, designs the law (builds the :class:`ValveDriver`) and loads the learned state
file; ``activate`` arms the drive; ``deactivate`` disables it (enable false, 0 A: the return
spring closes the valve); ``cleanup`` drops the driver (back to unconfigured); ``shutdown``
disables and finalizes.  The drive is never enabled outside ``active``: the driver is inhibited
(:meth:`ValveDriver.set_inhibited`) and a ``~/reset`` does not lift that.  Outside ``active``
every resolver sample is still answered, with 0 A (inactive: the driver's inhibited period,
so faults and counters keep running; unconfigured: a plain 0 A), and ``drive_enable`` false is
published on entering the state.  With ``autostart`` (default) the node configures and
activates itself at start (a configuration error then ends the process, exit 2, as before);
with ``autostart:=false`` a supervisor uses ``~/change_state`` / ``~/get_state``.
"""
from __future__ import annotations

import functools
import math
import os
import threading
import time
import weakref

from rclpy.lifecycle import Node as LifecycleNode, State, TransitionCallbackReturn

from ..common import contract
from ..common.timebase import stamp_seconds, to_stamp
from . import interface as ri
from .node_runner import run_node
from .valve_test_services import ValveTestInterface
from ..common.paramspec import ConfigError

from ..core.params import CONTROLLER_NODE_SPEC, CONTROLLER_SPEC, load_controller_params
from ..core.driver import RESOLVER_SETTLING, Health, ValveDriver
from ..core.period_inputs import PeriodInputs
from ..core.pulse_moves import TableBuild, default_cache_dir
from ..core.health import NE107_DIAGNOSTIC_LEVEL, FUNCTION_CHECK, load_state, save_state, state_owner

LEVEL_NAMES = {0: "OK", 1: "WARN", 2: "ERROR"}


def locked(method):
    """Run a callback under the node's lock (the driver is not thread-safe; callbacks and the
    executor's timers must never interleave inside it).  A callback never raises into the
    executor: an exception latches the driver's internal-error fault and the drive is switched
    off at once (:meth:`ControllerNode.fail_safe`); the node keeps running and reports it."""
    @functools.wraps(method)
    def wrapper(self, *args):
        with self._lock:
            try:
                return method(self, *args)
            except Exception as exc:       # noqa: BLE001 - a defect must fail safe, not end the loop
                self.fail_safe(method.__name__, exc)
                if len(args) == 2 and hasattr(args[1], "success"):     # a service: answer it
                    args[1].success, args[1].message = False, f"internal error: {exc}"
                    return args[1]
                return None
    return wrapper


def drive_off_log(out) -> tuple[str, str]:
    """``(severity, text)`` of the log line for a drive switched off by the loop (``out``: the
    period's :class:`~fuel_valve_control.core.driver.DriverOutput`): the severity says what the
    operator must do.

    * ``error``: a latched fault -- the valve is off until someone clears the cause and calls
      ``~/reset``;
    * ``info``: waiting with a demand and a measurement in hand -- the loop is letting the valve
      come to rest after the drive's own command watchdog tripped (a late loop, §40) and re-arms
      by itself; expected under load, nothing to do (it read "drive DISABLED" at ERROR before);
      or ``inactive`` (deactivated / inhibited: someone asked for it);
    * ``warn``: waiting for a demand or a resolver sample -- check the supervisor / the plant if
      it lasts.
    """
    if out.faults or out.state == "fault":
        return "error", (f"drive DISABLED: state {out.state}, faults: {'; '.join(out.faults.values())}: "
                         "clear the cause, then call ~/reset")
    if out.state == "inactive":
        return "info", "drive off: state inactive (deactivated or inhibited)"
    if out.state == "waiting" and RESOLVER_SETTLING in out.warnings:
        return "info", f"drive off: {out.warnings[RESOLVER_SETTLING]}"
    if out.state == "waiting" and out.demand_pct is not None and out.position_pct is not None:
        return "info", ("drive off: the drive's own watchdog tripped (late loop); waiting for the valve to "
                        "come to rest, then it re-arms by itself")
    missing = " and ".join(name for name, value in (("a valid demand", out.demand_pct),
                                                     ("a resolver sample", out.position_pct)) if value is None)
    return "warn", f"drive off: state {out.state}, waiting for {missing or 'the loop'}"


def transition(method):
    """A lifecycle transition callback under the node's lock; an exception is logged (rclpy
    swallows it) and returns ERROR, so :meth:`ControllerNode.on_error` disables the drive."""
    @functools.wraps(method)
    def wrapper(self, state):
        with self._lock:
            try:
                return method(self, state)
            except Exception as exc:       # noqa: BLE001 - reported, then ROS's error processing
                self.get_logger().error(f"{method.__name__} raised {type(exc).__name__}: {exc}")
                return TransitionCallbackReturn.ERROR
    return wrapper


def guard_change_state(node) -> None:
    """Make ``~/change_state`` answer ``success: false`` to a transition the present state does
    not have.  rclpy 7.1.x raises ``RCLError`` inside the service callback instead, and the
    exception ends the spin loop and with it the process: one wrong ``ros2 service call`` from a
    supervisor (activate while unconfigured) would kill the valve driver (found by
    test_lifecycle_nodes).  Wraps the service's public ``callback``; the state is unchanged."""
    for srv in node.services:
        if srv.service_name.endswith("/change_state"):
            inner, log = srv.callback, node.get_logger()

            def refuse_invalid(request, response, inner=inner, log=log):
                try:
                    return inner(request, response)
                except Exception as exc:     # noqa: BLE001 - rclpy's RCLError is not public API
                    log.warn(f"lifecycle transition id {request.transition.id} "
                             f"{request.transition.label!r} refused: {str(exc).split(', at ')[0]}")
                    response.success = False
                    return response
            srv.callback = refuse_invalid


class ControllerNode(LifecycleNode):
    def __init__(self, **kwargs):
        super().__init__("controller", **kwargs)
        guard_change_state(self)
        ri.declare_spec(self, CONTROLLER_NODE_SPEC)
        #: overrides for parameters this node does not have (typos): logged, and on /diagnostics
        self._unknown_params = ri.unknown_overrides(self)
        try:
            node_ps = CONTROLLER_NODE_SPEC.defaults().replace(ri.read_spec(self, CONTROLLER_NODE_SPEC))
        except ConfigError as exc:
            raise SystemExit(f"controller: invalid parameters: {exc}") from None
        #: the driver exists from ``configure`` to ``cleanup``/``shutdown`` (None: unconfigured)
        self.driver: ValveDriver | None = None
        self.lifecycle_state = "unconfigured"
        self._configure_error = "configure raised (see the log)"
        self.lockstep = node_ps["lockstep"]
        # `~` and $VARS expanded, made absolute: as a shell would take the path a technician
        # writes (`~/fuel_valve/valve1.json` was a relative directory named `~`, h24u), and
        # independent of the directory the launch happened to start in
        self._state_file = (os.path.abspath(os.path.expanduser(os.path.expandvars(node_ps["learned_state_file"])))
                            if node_ps["learned_state_file"] else "")
        self._save_interval = node_ps["learned_state_save_s"]
        #: the learned-state file names another valve (configure): never saved over
        self._state_foreign = False
        #: what configure made of the learned-state file, for /diagnostics (``learned_state``)
        self._state_status = "not persisted" if not self._state_file else "not loaded yet"
        self._last_save = time.monotonic()
        self._reset_loop_state()
        self._bad_messages = 0
        self._prepared = None          # (changes, ParamChange) validated in on-set, queued in post-set
        #: fine.apex_policy's move tables (task h36b): the background build in progress (TableBuild or None), the
        #: fine stages waiting for it, and the line /diagnostics shows (``move_tables``).  Task h37b: at most one
        #: build at a time (one reading thread, one worker process); ``_table_next`` the newest request
        #: ``(moves, keys, root)`` waiting for a cancelled build's thread to end (a newer one replaces it); the
        #: waiters are weak references to the stages of the laws in force or waiting for their swap, nothing else
        self._table_build = None
        self._table_next = None
        self._table_ending = None       # a cancelled build whose thread may still be ending
        self._table_waiters = []
        self._tables_driver = None
        self._table_timer = None
        self._tables_status = "off"
        self._tables_failed = False
        self._last_enable = None
        # level of the last status logged; None so that the first one is always logged (with a
        # recorder in the run /diagnostics waits for its match, and a loop already running OK by
        # then never said "status OK": the CLI tests waited 60 s for it)
        self._level = None
        self._loop_timers = []
        self._sample_seen = False       # a resolver sample has arrived (lockstep: the plant started)
        self._hello_sent = not self.lockstep        # lockstep start handshake (_say_hello)

        from diagnostic_msgs.msg import DiagnosticArray
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Bool, Float64, Float64MultiArray, UInt8
        from std_srvs.srv import Trigger
        from builtin_interfaces.msg import Time
        self._float, self._bool, self._time = Float64, Bool, Time
        # plain publishers, not lifecycle ones: outside ``active`` the node must still say
        # "drive disabled, 0 A" (a lifecycle publisher would be silent)
        recorded = ri.recorded_topics(node_ps["recorded_topics"])
        deep = bool(recorded)                 # a recorder in the run: deep writer histories
        self.pub_current = ri.quiet_publisher(self, Float64, contract.CURRENT_COMMAND, recorded=deep)
        self.pub_enable = ri.quiet_publisher(self, Bool, contract.DRIVE_ENABLE, recorded=deep)
        self.pub_fallback = ri.quiet_publisher(self, Float64MultiArray, contract.CURRENT_FALLBACK, recorded=deep)
        self._float_array = Float64MultiArray
        self._last_fallback: tuple | None = None    # the fallback schedule last published (empty: hold; None: none yet)
        self.pub_position = ri.quiet_publisher(self, Float64, contract.POSITION, recorded=deep)
        self.pub_estimate = ri.quiet_publisher(self, JointState, contract.ESTIMATE, recorded=deep)
        self.pub_diag = ri.quiet_publisher(self, DiagnosticArray, contract.DIAGNOSTICS, recorded=deep)
        # one lock serialises the driver between callbacks: the node runner spins one thread
        # today, and a multi-threaded executor must not change the driver's behaviour
        self._lock = threading.Lock()
        # every input on this node and the one executor (node_runner): no helper node.
        # Δp first: in lockstep it was published before the resolver sample of the same period
        # real time: the external inputs accept publishers of any reliability (ri.INPUT_QOS);
        # lockstep: reliable, each period waits for its demand
        inputs = None if self.lockstep else ri.INPUT_QOS
        #: the input subscriptions by contract name (their resolved, remapped topics are what
        #: :meth:`_input_publishers` counts the publishers of)
        self._inputs_subs = {
            contract.PRESSURE_DIFFERENTIAL: ri.quiet_subscription(self, Float64, contract.PRESSURE_DIFFERENTIAL,
                                                                  self.on_pressure, inputs),
            contract.DEMAND: ri.quiet_subscription(self, Float64, contract.DEMAND, self.on_demand, inputs),
            contract.DEMAND_MA: ri.quiet_subscription(self, Float64, contract.DEMAND_MA, self.on_demand_ma, inputs)}
        ri.quiet_subscription(self, JointState, contract.RESOLVER, self.on_resolver)
        ri.quiet_subscription(self, UInt8, contract.DRIVE_STATUS, self.on_drive_status)
        if node_ps["monitor_drive_telemetry"]:
            ri.quiet_subscription(self, Float64MultiArray, contract.DRIVE, self.on_drive)
        self._decimation = node_ps["telemetry_decimation"]
        self._periods = 0
        #: messages published per topic (printed at exit) and the recorder hold (recorded_topics)
        self.recorder_gate = ri.RecorderGate(self, recorded)
        self._compute = ComputeTime()
        self._after = ComputeTime("after_command")   # the work left for after a period's command, when there was any
        self.create_service(Trigger, "~/trip", self.on_trip)
        self.create_service(Trigger, "~/reset", self.on_reset)
        #: signature / partial-stroke tests: ~/signature_test, ~/partial_stroke_test, latched valve_test
        self.valve_tests = ValveTestInterface(self, self._lock)    # a ValveTests per configure
        ri.handle_parameter_changes(self, CONTROLLER_SPEC, self.check_parameters, self.apply_parameters)
        self.create_timer(1.0 / node_ps["diagnostics_rate_hz"], self.publish_diagnostics)
        if self.lockstep:
            from rclpy.clock import Clock, ClockType
            # wall-clock: simulated time stands still until the plant starts
            self._hello_timer = self.create_timer(0.01, self._say_hello, clock=Clock(clock_type=ClockType.STEADY_TIME))
        if node_ps["autostart"]:
            # one command as before: configure + activate now; a configuration error ends the
            # process (exit 2) instead of leaving an unconfigured node nobody will configure
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                raise SystemExit(f"controller: invalid parameters: {self._configure_error}")
            if self.trigger_activate() != TransitionCallbackReturn.SUCCESS:
                raise SystemExit("controller: activation failed")
        else:
            self._publish_disabled()
            self.get_logger().info("controller unconfigured (autostart false): configure and activate through "
                                   "~/change_state")

    def _reset_loop_state(self) -> None:
        self._fresh_demand = False
        #: lockstep: the demand and Δp that came for the next period, handed to the driver at
        #: that period's time (the offline simulator's exchange: core/period_inputs.py)
        self._inputs = PeriodInputs()
        self._pending_sample = None
        self._last_sample_stamp = None
        self._command_matched = False

    # ------------------------------------------------------------------ lifecycle
    @transition
    def on_configure(self, state: State) -> TransitionCallbackReturn:
        """Read and validate the parameters, design the law (build the driver, inhibited),
        load the learned state; start the watchdog (and the lockstep match timer)."""
        try:
            node_ps = CONTROLLER_NODE_SPEC.defaults().replace(ri.read_spec(self, CONTROLLER_NODE_SPEC))
            ps = load_controller_params(None, CONTROLLER_SPEC.pick(node_ps))
            driver = ValveDriver(ps)
        except Exception as exc:        # noqa: BLE001 - a set the design code cannot use: refuse it
            self._configure_error = f"{exc}" if isinstance(exc, ConfigError) else f"{type(exc).__name__}: {exc}"
            self.get_logger().error(f"configure failed: invalid parameters: {self._configure_error}")
            return TransitionCallbackReturn.FAILURE
        driver.set_inhibited(True)
        initial_a = node_ps["initial_current_a"]
        if initial_a:
            driver.start_from_torque(initial_a * driver.controller.model.torque_constant_nm_per_a)
        if self._state_file:
            me = self.get_fully_qualified_name()
            loaded, message = load_state(self._state_file, driver.valve_health, driver.controller.learner, owner=me)
            # another valve's file (two valves given one path, a file copied across): neither
            # loaded nor overwritten, so that valve's learned state survives this one (h24u)
            owner = None if loaded else state_owner(self._state_file)
            self._state_foreign = owner is not None and owner != me
            if self._state_foreign:
                message += f"; not saved over either (it belongs to {owner}): give this valve a file of its own"
            self._state_status = ("loaded" if loaded else f"foreign ({owner}): not loaded, not saved"
                                  if self._state_foreign else "not loaded: " + message.split(" (")[0].split(": ")[0])
            # one call site per severity: rclpy refuses a site that changes severity
            if loaded:
                self.get_logger().info(message)
            else:
                self.get_logger().warn(message)
        self._prepare_law(driver)
        self.valve_tests.attach(driver)
        self.driver, self.stroke = driver, driver.stroke
        self._reset_loop_state()
        period = driver.period
        if self.lockstep:
            from rclpy.clock import Clock, ClockType
            # wall-clock: simulated time stands still while a period waits for the match
            self._match_timer = self.create_timer(0.01, self._run_when_matched,
                                                  clock=Clock(clock_type=ClockType.STEADY_TIME))
            self._loop_timers.append(self._match_timer)
        # the watchdog runs the fault logic when no samples arrive (silence must trip)
        self._watchdog_period = max(5.0 * period, 0.01)
        self._watchdog_last = time.monotonic()
        self._loop_timers.append(self.create_timer(self._watchdog_period, self.watchdog))
        self._set_lifecycle("inactive")
        self._publish_disabled()
        self.get_logger().info(f"controller up: mode {ps['mode']}, loop {ps['loop_rate_hz']:g} Hz, demand from "
                               f"{ps['demand_source']}{', lockstep' if self.lockstep else ''}")
        return TransitionCallbackReturn.SUCCESS

    def _prepare_law(self, driver: ValveDriver) -> None:
        """Make ready, here at configure and never inside the control callback, what the law would otherwise build
        lazily inside a 1 kHz period: with ``fine.apex_policy`` the doublet's move tables (~0.12 s of CPU each; C1,
        kicks to 16 A: 342 tables, ~41 s).  Read from the disk cache (:func:`~fuel_valve_control.core.pulse_moves.
        default_cache_dir`) in lockstep, the rest built lazily as offline (simulated time waits for the controller);
        in real time read and, what is missing, built in a background process (:meth:`_start_tables`) while the
        fine stage runs main's staircase.  ``fine.apex_policy`` off: nothing is made, nothing logged."""
        self._cancel_tables()
        self._tables_driver = driver
        self._tables_failed = False
        # lockstep: simulated time stands still while the controller computes, so the stage is not gated -- what
        # the cache holds is read here, the rest built lazily in the period that first asks for it, as offline:
        # the run is the offline simulator's from its first plateau, cold cache or warm
        deferred = driver.controller.defer_tables(gate=not self.lockstep)
        if deferred is None:
            self._tables_status = "off" if not driver.ps["fine.apex_policy"] else "ready (nothing to build)"
            return
        fine, moves, keys = deferred
        root = default_cache_dir()
        if self.lockstep:
            t0 = time.monotonic()
            got = moves.read_cached(root, keys) if root is not None else {}
            moves.adopt(got)
            self._tables_status = (f"lockstep: {len(got)} of {len(keys)} loaded from cache, the rest built when "
                                   "first asked for (simulated time waits)")
            self.get_logger().info(f"fine.apex_policy: move tables: {self._tables_status} "
                                   f"({moves.cache_dir(root) if root is not None else 'cache off'}, "
                                   f"{time.monotonic() - t0:.1f} s)")
            return
        self._start_tables(fine, moves, keys, root)

    def _start_tables(self, fine, moves, keys, root) -> None:
        """Make ``keys`` of ``moves`` ready for the fine stage ``fine`` off the control thread: a low-priority process
        writes them to the cache ``root``, a thread reads them back, and :meth:`_poll_tables` (a steady-clock timer,
        not the control callback) adopts them and releases the stage.  Bounded (task h37b):

        * a model of the signature a build already makes (its keys included) starts nothing -- no build, no read:
          ``fine`` waits for that build (a run-time change that leaves the move model alone; the tables already in
          memory never come here: :meth:`_defer_unprepared` finds nothing pending, the shared store serves them);
        * at most one build at a time: another one is cancelled (its worker terminated now, its reading thread
          stops at its next file) and this request started once that thread has ended -- by the poll if not at
          once; a newer request replaces one still waiting;
        * the waiting stages are only those of the laws in force and waiting for their swap (weakly held): a
          replaced law's stage is dropped, never kept waiting."""
        self._keep_waiters(fine)
        build = self._table_build
        if self._table_next is None and build is not None and build.done() and build.state == "ready":
            self._take_build()                   # finished, not polled yet: its tables in, the stages released
            build = None
            keys = moves.missing(keys)
            if not keys:
                fine.release_tables()
                self._tables_status = self._status_in_memory(fine)
                return
        if self._table_next is None and build is not None and build.serves(moves, keys, root):
            self._tables_status = build.status()
            self.get_logger().info(f"fine.apex_policy: move tables: the new law's model has the signature the build in "
                                   f"progress makes ({build.status()}): no build of its own, it waits for that one")
            return
        if build is not None:
            build.cancel(0.0)                    # the worker ended now, the reader at its next file
            self._table_build, self._table_ending = None, build
        self._table_next = (moves, list(keys), root)
        self.get_logger().info(f"fine.apex_policy: move tables: {len(keys)} needed, not all in memory "
                               f"({moves.cache_dir(root) if root is not None else 'no disk cache'}): reading the cache "
                               "and building the missing ones in a background process (nice 19, ~0.12 s of CPU each); "
                               "the fine stage runs main's staircase until they are ready")
        self._launch_next()
        if self._table_timer is None:
            from rclpy.clock import Clock, ClockType
            self._table_timer = self.create_timer(0.25, self._poll_tables,
                                                  clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _launch_next(self) -> None:
        """Start the waiting request once no other build's thread or worker runs (one at a time)."""
        if self._table_next is None:
            return
        old = self._table_ending
        if old is not None and old.alive():
            self._tables_status = (f"starting: {len(self._table_next[1])} tables to make once the replaced build "
                                   "has ended")
            return
        moves, keys, root = self._table_next
        self._table_next, self._table_ending = None, None
        keys = moves.missing(keys)               # (what arrived in its store meanwhile)
        if not keys:
            self._release_waiters()
            self._tables_status = "ready: every table in memory (no build)"
            return
        self._table_build = TableBuild(moves, keys, root)
        self._tables_failed = False
        self._tables_status = self._table_build.status()

    def _laws_fines(self) -> list:
        """The fine stages of the law in force and of the law waiting for its swap (those a build may serve; the
        driver :meth:`_prepare_law` was given -- at configure it is not :attr:`driver` yet)."""
        driver = self._tables_driver
        if driver is None:
            return []
        laws = (driver.controller.law, driver.waiting_law)
        return [law.fine for law in laws if law is not None and getattr(law, "fine", None) is not None]

    def _keep_waiters(self, fine=None) -> list:
        """The waiting stages still alive and in force (plus ``fine``); the others dropped.  Returns them."""
        keep = self._laws_fines()
        out = []
        for ref in [*self._table_waiters, *(() if fine is None else (weakref.ref(fine),))]:
            stage = ref()
            if stage is not None and any(stage is k for k in keep) and not any(stage is o() for o in out):
                out.append(ref)
        self._table_waiters = out
        return [ref() for ref in out]

    def _release_waiters(self, tables: dict | None = None, signature=None) -> list:
        """Each waiting stage in force: ``tables`` adopted into its model (same ``signature`` only; already in its
        store they are not copied) and the stage released.  Returns (stage, released) pairs."""
        out = []
        for stage in self._keep_waiters():
            if tables is not None and stage.moves is not None and stage.moves.signature == signature:
                stage.moves.adopt(tables)
            out.append((stage, stage.release_tables()))
        self._table_waiters = [weakref.ref(s) for s, ok in out if not ok]
        return out

    def _status_in_memory(self, fine) -> str:
        n = len(fine.moves._needed(None, (1, -1), fine._apex_kicks())) if fine.moves is not None else 0
        return f"ready: {n} of {n} in memory (no build)"

    def _take_build(self) -> list:
        """A ready build's tables adopted by the waiting stages' models, the stages released; the build dropped."""
        build, self._table_build = self._table_build, None
        build.moves.adopt(build.tables)
        return self._release_waiters(build.tables, build.moves.signature)

    @locked
    def _poll_tables(self) -> None:
        """The background build's progress; once done, its tables adopted and the waiting fine stages released
        (the policy takes over at each one's next plateau), or -- failed -- a WARN, the stage left on main's
        staircase (not a fault).  A request waiting for a replaced build to end is started here."""
        if self._table_next is not None:
            self._launch_next()
        build = self._table_build
        if build is not None and not build.done():
            self._tables_status = build.status()
            return
        if self._table_next is not None:
            return                               # the replaced build still ending: the next poll starts the new one
        if self._table_timer is not None:
            self.destroy_timer(self._table_timer)
            self._table_timer = None
        if build is None:
            return
        if build.state == "ready":
            self._tables_status = build.status()
            released = dict((id(stage), ok) for stage, ok in self._take_build())
            fines = self._laws_fines()
            newest = fines[-1] if fines else None          # the waiting law's stage, else the one in force
            if newest is None or released.get(id(newest), True):
                self.get_logger().info(f"fine.apex_policy: move tables {self._tables_status}; the policy takes over "
                                       "at the next plateau")
                return
            self._tables_failed = True
            self._tables_status = f"failed: tables still missing after the build ({build.status()})"
        elif build.state == "failed":
            self._table_build = None
            self._tables_failed = True
            self._tables_status = f"failed: {build.reason}"
        else:
            self._table_build = None
            self._tables_status = build.status()
            return
        self.get_logger().warn(f"fine.apex_policy: move tables {self._tables_status}: the fine stage stays on main's "
                               "staircase (a reconfigure retries)")

    def _cancel_tables(self, wait_s: float = 0.0) -> None:
        """End a background build; the cache keeps every table the worker finished.  ``wait_s`` 0 (called under
        the loop's lock: it must not hold the loop up): nothing waited for -- the worker is sent SIGTERM and its
        reading thread reaps it (killed if it has not ended within ``pulse_moves.STOP_GRACE_S``) and ends at its
        next file (task h37d: the worker's end was waited for here, up to 2 s + 2 s of a 1 kHz loop).  ``wait_s``
        > 0 (destroy): the worker ended and reaped here, the thread waited for up to ``wait_s``.  A waiting request
        and the waiting stages are dropped."""
        if self._table_timer is not None:
            self.destroy_timer(self._table_timer)
            self._table_timer = None
        if self._table_build is not None:
            self._table_build.cancel(wait_s)
            # (still ending: the next build starts after it, one reader at a time)
            self._table_build, self._table_ending = None, self._table_build
        self._table_next = None
        self._table_waiters = []

    def destroy_node(self):
        ending = self._table_ending
        self._cancel_tables(wait_s=5.0)
        if ending is not None:
            ending.cancel(5.0)                   # a replaced build still ending (its worker reaped here, not orphaned)
        self._table_ending = None
        return super().destroy_node()

    def _law_needs_no_tables(self, law) -> None:
        """(task h37b) A new law whose move tables are all in memory waits for its swap: a build for a law it
        replaces is of no use any more (the newest request wins) -- ended, its stages dropped.  /diagnostics says
        the new law's tables are in memory (no ``fine.apex_policy``: nothing changes, nothing is built)."""
        fine = getattr(law, "fine", None)
        if fine is None or fine.moves is None:
            return
        if self._table_build is not None or self._table_next is not None:
            self._cancel_tables()
        self._tables_failed = False
        self._tables_status = self._status_in_memory(fine)

    def _defer_unprepared(self, change):
        """A run-time change whose law needs move tables its configure did not make (``fine.apex_policy`` on and,
        e.g., ``fine.apex_kick_max_a`` raised): the new law's fine stage is set to run main's staircase until they
        are built (returned: ``(fine, moves, keys)`` for :meth:`_start_tables` once the change is accepted), never
        a build inside the control callback.  None: nothing to build.  (``fine.apex_policy`` itself is not a
        run-time parameter -- read-only on the node: set it in the parameter file or at start-up.)"""
        if change.law is None:
            return None
        return self.driver.controller.defer_tables(change.law[0])

    @transition
    def on_activate(self, state: State) -> TransitionCallbackReturn:
        """Arm the drive: the next period arms the law from the measurement (zero torque, or
        ``initial_current_a`` the first time), unless a fault is latched."""
        self.driver.set_inhibited(False)
        self._set_lifecycle("active")
        self.get_logger().info("controller active: drive armed")
        return TransitionCallbackReturn.SUCCESS

    @transition
    def on_deactivate(self, state: State) -> TransitionCallbackReturn:
        self._disable("deactivated")
        self._set_lifecycle("inactive")
        self._save_state()
        return TransitionCallbackReturn.SUCCESS

    @transition
    def on_cleanup(self, state: State) -> TransitionCallbackReturn:
        self._save_state()
        self._drop_driver()
        self._set_lifecycle("unconfigured")
        self.get_logger().info("controller cleaned up: unconfigured")
        return TransitionCallbackReturn.SUCCESS

    @transition
    def on_shutdown(self, state: State) -> TransitionCallbackReturn:
        if self.driver is not None:
            self._disable("shut down")
            self._save_state()
        self._drop_driver()
        self._set_lifecycle("finalized")
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: State) -> TransitionCallbackReturn:
        """A transition raised: drive off, driver dropped, back to unconfigured."""
        with self._lock:
            self.get_logger().error(f"lifecycle transition from {state.label} failed: drive disabled, unconfigured")
            self._publish_disabled(force=True)
            self._drop_driver()
            self._set_lifecycle("unconfigured")
            return TransitionCallbackReturn.SUCCESS

    def _set_lifecycle(self, label: str) -> None:
        self.lifecycle_state = label
        if self.driver is not None:
            self.driver.valve_health.set_lifecycle_state(label)

    def _disable(self, why: str) -> None:
        """Inhibit the driver and command the drive off now (not at the next period)."""
        self.driver.set_inhibited(True)
        self.publish_step(self.now_s())
        self.get_logger().warn(f"controller {why}: drive disabled, the return spring closes the valve")

    def _drop_driver(self) -> None:
        self._cancel_tables()
        self._tables_driver = None
        for timer in self._loop_timers:
            self.destroy_timer(timer)
        self._loop_timers = []
        self.driver = None
        self.valve_tests.detach()
        self._reset_loop_state()

    def _publish_disabled(self, force: bool = False) -> None:
        """drive_enable false (when not already said) and 0 A, outside ``active``.  Before the
        recorder gate opens only the latched enable false (the recorder still gets it when it
        matches; the plant's drive starts disabled, so a 0 A command adds nothing then)."""
        if self.lockstep and not self._hello_sent:
            return          # the plant has not started: nothing to answer; the hello says "disabled"
        if force or self._last_enable is not False:
            self.pub_enable.publish(self._bool(data=False))
            self.recorder_gate.count(contract.DRIVE_ENABLE, latched=True)
            self._last_enable = False
        if self._last_fallback is not None:
            self._publish_fallback(())          # whoever commands the drive next: it holds its commands again
        # (lockstep: no command before the plant's first sample but the hello, _say_hello; a
        # command the plant receives after its start steps it)
        if self.recorder_gate.is_open and not (self.lockstep and not self._sample_seen):
            self.pub_current.publish(self._float(data=0.0))
            self.recorder_gate.count(contract.CURRENT_COMMAND)

    def _say_hello(self) -> None:
        """Lockstep start handshake: once this node can answer a sample (its command publisher
        matched to the plant's subscription, its recorder gate open), its first ``drive_enable``
        (false: the drive starts disabled) says so.  The plant does not start before it has
        arrived; the topic is latched (transient local), so it arrives however late the plant's
        side matches (a volatile message would be lost then).  Before it this node publishes
        nothing on the loop's topics.  So tick 0 is neither lost nor held here (it was: the
        plant started when the endpoints matched, tick 0 waited for this node's recorder gate,
        and the plant re-published it after its resend timeout)."""
        with self._lock:
            if self.pub_current.get_subscription_count() >= 1 and self.recorder_gate.is_open:
                self._hello_timer.cancel()
                self._hello_sent = True
                self._publish_disabled(force=True)

    def _save_state(self) -> None:
        """Persist the learned state (``learned_state_file``); a failure is logged, never raised."""
        if not self._state_file or self.driver is None or self._state_foreign:
            return
        self._last_save = time.monotonic()
        try:
            save_state(self._state_file, self.driver.valve_health, self.driver.controller.learner,
                       owner=self.get_fully_qualified_name())
        except OSError as exc:
            self.get_logger().error(f"cannot save the learned state to {self._state_file}: {exc}",
                                    throttle_duration_sec=10.0)

    def save_on_exit(self) -> None:
        """At process exit (:func:`run_node`'s ``on_exit``): persist the learned state."""
        with self._lock:
            self._save_state()

    # ------------------------------------------------------------------ time
    def now_s(self) -> float:
        """The loop's time, s.  In lockstep it is the stamp of the latest resolver sample (the
        plant's clock, exact and deterministic); otherwise the node clock."""
        if self.lockstep:
            return self._last_sample_stamp if self._last_sample_stamp is not None else 0.0
        return self.get_clock().now().nanoseconds * 1e-9

    # ------------------------------------------------------------------ inputs
    @locked
    def on_demand(self, msg) -> None:
        if self.driver is None:
            return
        if self.lockstep:
            self._inputs.demand_percent(msg.data)
        else:
            self.driver.demand_percent(self.now_s(), msg.data)
        self._demand_arrived()

    @locked
    def on_demand_ma(self, msg) -> None:
        if self.driver is None:
            return
        if self.lockstep:
            self._inputs.demand_ma(msg.data)
        else:
            self.driver.demand_ma(self.now_s(), msg.data)
        self._demand_arrived()

    def _demand_arrived(self) -> None:
        self._fresh_demand = True
        if self._pending_sample is not None and self._loop_matched():   # lockstep: the sample was waiting
            sample, self._pending_sample = self._pending_sample, None
            self.run_period(sample)

    def _loop_matched(self) -> bool:
        """Lockstep: the command publisher has matched the plant (checked until it has once) and
        the recorder, when the run has one, has matched this node's topics (``recorder_gate``)."""
        if not self._command_matched:
            self._command_matched = self.pub_current.get_subscription_count() >= 1
        return self._command_matched and self.recorder_gate.is_open

    @locked
    def _run_when_matched(self) -> None:
        """Lockstep: run a period that was ready but held back for the command's match."""
        if self.driver is None:
            return
        if self._command_matched and self.recorder_gate.is_open and self._periods:
            self._match_timer.cancel()               # matched for good: the timer's job is done
        elif self._pending_sample is not None and self._fresh_demand and self._loop_matched():
            sample, self._pending_sample = self._pending_sample, None
            self.run_period(sample)

    @locked
    def on_pressure(self, msg) -> None:
        if self.driver is None:
            return
        if self.lockstep:
            self._inputs.pressure_differential(msg.data)
        else:
            self.driver.pressure_differential(self.now_s(), msg.data)

    @locked
    def on_drive(self, msg) -> None:
        values = ri.array_values(msg)
        if self.driver is not None and "i_d" in values and "i_q" in values:
            self.driver.measured_current(self.now_s(), math.hypot(values["i_d"], values["i_q"]))

    @locked
    def on_drive_status(self, msg) -> None:
        if self.driver is not None:
            self.driver.drive_status(self.now_s(), int(msg.data))

    @locked
    def on_resolver(self, msg) -> None:
        self._sample_seen = True
        if self.driver is None:             # unconfigured / finalized: the drive stays off
            self._publish_disabled()
            return
        values = ri.joint_values(msg)
        motor, valve = values.get(contract.MOTOR_JOINT), values.get(contract.VALVE_JOINT)
        if motor is None or valve is None:
            self._bad_messages += 1
            self.get_logger().warn(f"resolver message without {contract.MOTOR_JOINT}/{contract.VALVE_JOINT} positions ignored",
                                   throttle_duration_sec=1.0)
            return
        # lockstep: the period's time exactly as the offline simulator has it (common/timebase.py)
        stamp = stamp_seconds(msg.header.stamp.sec, msg.header.stamp.nanosec,
                              self.driver.period if self.lockstep else None)
        clock = self.get_clock().now().nanoseconds * 1e-9       # sim time in lockstep (/clock)
        if stamp - clock > self.driver.ps["faults.stamp_future_tolerance_s"]:
            # never the loop's time or the jump reference; the driver latches it as implausible
            self.driver.resolver(stamp, motor, valve, now=clock)
            self._bad_messages += 1
            return
        sample = (stamp, motor, valve, clock)
        if self.lockstep:
            if self._last_sample_stamp is not None and stamp <= self._last_sample_stamp:
                return                              # a re-sent sample of a period already run
            if not self._fresh_demand or not self._loop_matched():
                self._pending_sample = sample       # wait for this period's demand (or the match)
                return
        elif not self.recorder_gate.is_open:
            return                                  # real time: the loop closes once recorded
        self.run_period(sample)

    # ------------------------------------------------------------------ loop
    def run_period(self, sample) -> None:
        t0 = time.perf_counter()
        stamp, motor, valve, clock = sample
        self._fresh_demand = False
        self._last_sample_stamp = stamp
        if self.lockstep:
            self.publish_step(stamp, self._inputs.run(self.driver, stamp, motor, valve, now=clock))
        else:
            self.driver.resolver(stamp, motor, valve, now=clock)
            self.driver.loop_timing(stamp, clock)
            self.publish_step(self.now_s())
        t1 = time.perf_counter()
        self._compute.add(t1 - t0)
        # the law's work left for after the command (the fine stage's apex choice of a try an observe's verdict
        # started, fine.apex_choice_after_command): the command is out, the next sample is a period away
        if self.driver.after_period():
            self._after.add(time.perf_counter() - t1)
            # a retreat planned after the kick's command: the drive's fallback for the next period is the planned one
            self._publish_fallback(self.driver.fallback_currents())

    @locked
    def watchdog(self) -> None:
        if self.driver is None:
            return
        timeout = self.driver.ps["faults.resolver_timeout_s"]
        if self.lockstep:
            return                       # sim time stands still while nobody steps the plant
        now = time.monotonic()
        late = now - self._watchdog_last > 2.0 * self._watchdog_period
        self._watchdog_last = now
        if late:
            # this process itself was not scheduled: a sample that arrived meanwhile may still
            # wait in the executor's queue behind this timer; judge silence on the next run
            return
        last = self.driver.last_resolver_time
        if last is not None and self.now_s() - last > timeout:
            self.publish_step(self.now_s())

    def fail_safe(self, where: str, exc: BaseException) -> None:
        """An exception in the node's own code: latch the driver's internal-error fault and
        command the drive off (enable false, 0 A) now, not at the next period."""
        if self.driver is not None:
            self.driver.internal_fault(where, exc)
        self.get_logger().error(f"internal error in {where}: {type(exc).__name__}: {exc}; drive disabled "
                                "(fault latched, ~/reset to re-arm)", throttle_duration_sec=1.0)
        try:
            self.pub_enable.publish(self._bool(data=False))
            self.pub_current.publish(self._float(data=0.0))
            self.recorder_gate.count(contract.DRIVE_ENABLE, latched=True)
            self.recorder_gate.count(contract.CURRENT_COMMAND)
            self._last_enable = False
        except Exception:                   # noqa: BLE001 - context gone: the plant's watchdog acts
            pass

    def _publish_fallback(self, amps: tuple) -> None:
        """The drive's fallback schedule (``contract.CURRENT_FALLBACK``, latched) when it changed: before the command it
        applies to (empty: hold the last command)."""
        amps = tuple(float(x) for x in amps)
        if amps == self._last_fallback:
            return
        self._last_fallback = amps
        self.pub_fallback.publish(self._float_array(data=list(amps)))
        self.recorder_gate.count(contract.CURRENT_FALLBACK, latched=True)

    def publish_step(self, t: float, out=None) -> None:
        """One driver period at ``t`` (s): the command first (the plant is waiting for it), then
        the rest.  ``out``: the period's ``DriverOutput`` when the driver has stepped already."""
        if out is None:
            out = self.driver.step(t)
        # latched topic: publish changes only, and a re-enable of a drive that switched itself
        # off (out.reenable); before the command it applies to
        if out.enable != self._last_enable or (out.enable and out.reenable):
            self.pub_enable.publish(self._bool(data=bool(out.enable)))
            self.recorder_gate.count(contract.DRIVE_ENABLE, latched=True)
            if out.reenable:
                self.get_logger().warn(f"the drive switched itself off (state "
                                       f"{contract.DRIVE_STATE_NAMES.get(self.driver.drive_state, 'unreported')}): "
                                       "re-armed from the measurement with the holding torque, drive re-enabled",
                                       throttle_duration_sec=1.0)
        self._publish_fallback(out.fallback_currents_a)
        self.pub_current.publish(self._float(data=float(out.current_a)))
        self.recorder_gate.count(contract.CURRENT_COMMAND)
        self._periods += 1
        if self._periods % self._decimation == 0:
            if out.position_pct is not None:
                self.pub_position.publish(self._float(data=float(out.position_pct)))
                self.recorder_gate.count(contract.POSITION)
            est = self.driver.controller.estimate()
            if self.lockstep:
                sec, nanosec = to_stamp(t)
                stamp = self._time(sec=sec, nanosec=nanosec)
            else:
                stamp = self.get_clock().now().to_msg()
            self.pub_estimate.publish(ri.joint_state(
                stamp, (est.motor_angle, est.valve_angle), (est.motor_velocity, est.valve_velocity),
                (est.motor_friction_nm, est.valve_friction_nm)))
            self.recorder_gate.count(contract.ESTIMATE)
        if out.enable != self._last_enable:
            if self._last_enable is not None:
                # one call site per severity: rclpy refuses a site that changes severity
                if out.enable:
                    self.get_logger().info(f"drive enabled: state {out.state}")
                else:
                    severity, text = drive_off_log(out)
                    if severity == "error":
                        self.get_logger().error(text)
                    elif severity == "warn":
                        self.get_logger().warn(text)
                    else:
                        self.get_logger().info(text)
            self._last_enable = out.enable

    # ------------------------------------------------------------------ services
    @locked
    def on_trip(self, request, response):
        if self.driver is None:
            response.success, response.message = False, f"{self.lifecycle_state}: no drive to trip (disabled)"
            return response
        self.driver.trip("trip requested through ~/trip")
        self.publish_step(self.now_s())
        response.success = True
        response.message = "tripped: drive disabled, the return spring closes the valve; call ~/reset to re-arm"
        self.get_logger().warn(response.message)
        return response

    @locked
    def on_reset(self, request, response):
        if self.driver is None:
            response.success, response.message = False, f"{self.lifecycle_state}: configure the node first"
            return response
        ok, message = self.driver.reset()
        if ok and self.driver.inhibited:
            message += f" (lifecycle {self.lifecycle_state}: the drive stays disabled until activated)"
        response.success, response.message = ok, message
        if ok:
            self.get_logger().info(f"reset: {message}")
        else:
            self.get_logger().warn(f"reset refused: {message}")
        return response

    # ------------------------------------------------------------------ parameters
    def check_parameters(self, changes: dict) -> None:
        """Validation (on-set): validate and build the new law (:meth:`ValveDriver.prepare_params`)
        without the loop's lock: nothing the loop uses is touched, so a period is never held up
        behind a build.  Raises ``ValueError`` for a change the driver would refuse (a
        rejection, not a fault: not :func:`locked`'s fail-safe).  Unconfigured (no driver):
        nothing to check here, ``configure`` reads and validates the parameters."""
        if self.driver is None:
            self._prepared = None
            return
        change = self.driver.prepare_params(changes)
        self._prepared = (changes, change, self._defer_unprepared(change))

    def apply_parameters(self, changes: dict) -> None:
        """After acceptance (post-set): queue the prepared change; the loop swaps it in at the
        start of a period (atomic, bumpless, at most one law replacement per
        ``driver.param_swap_periods`` periods, the last request wins)."""
        prepared, self._prepared = self._prepared, None
        if self.driver is None:             # unconfigured: configure reads the new values
            return
        try:
            if prepared is None or prepared[0] != changes:        # not the change validated: redo
                change = self.driver.prepare_params(changes)
                prepared = (changes, change, self._defer_unprepared(change))
            self.driver.request_params(prepared[1])
            with self._lock:
                if prepared[2] is not None:
                    self._start_tables(*prepared[2], default_cache_dir())
                elif prepared[1].law is not None:
                    self._law_needs_no_tables(prepared[1].law[0])
        except Exception as exc:           # noqa: BLE001 - accepted but not applicable: fail safe
            with self._lock:
                self.fail_safe("apply_parameters", exc)

    # ------------------------------------------------------------------ diagnostics
    @locked
    def publish_diagnostics(self) -> None:
        if not self.recorder_gate.is_open:
            return
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        if self.driver is None:
            h = Health(1, f"{self.lifecycle_state} (managed node not configured): drive disabled",
                       {"state": self.lifecycle_state, "lifecycle_state": self.lifecycle_state, "ne107": FUNCTION_CHECK,
                        "ne107_level": NE107_DIAGNOSTIC_LEVEL[FUNCTION_CHECK], "faults": "none", "warnings": "none"})
        elif self._state_file and time.monotonic() - self._last_save > self._save_interval:
            self._save_state()
        try:
            if self.driver is not None:
                h = self.driver.health()
        except Exception as exc:            # noqa: BLE001 - still say something on /diagnostics
            self.fail_safe("health", exc)
            h = Health(2, f"FAULT: internal error while reporting health: {exc}", {"faults": "internal_error"})
        values = dict(h.values, malformed_messages=self._bad_messages, periods=self._periods,
                      **self._compute.take(), **self._after.take(), **self.valve_tests.summary())
        level, message = h.level, h.message
        try:
            conflicts, counts = self._input_publishers()
        except Exception as exc:            # noqa: BLE001 - a graph query is a report, never a reason to trip
            conflicts, counts = [], {}
            self.get_logger().warn(f"input publishers not checked: {type(exc).__name__}: {exc}",
                                   throttle_duration_sec=10.0)
        fine = getattr(self.driver.controller.law, "fine", None) if self.driver is not None else None
        if fine is not None:          # the apex policy's tries chosen by the stage in force, and how many after the command
            values.update(apex_choices=fine.apex_choices, apex_choices_after_command=fine.apex_choices_after_command)
        values.update(counts, learned_state=self._state_status, move_tables=self._tables_status,
                      ignored_parameters=",".join(self._unknown_params) or "none")
        if self._tables_failed and self.driver is not None:
            # not a fault: the fine stage runs main's staircase (the default's behaviour) without its tables
            level = max(level, 1)
            message = f"{message}; fine.apex_policy move tables {self._tables_status} (fine stage on main's staircase)"
        if conflicts:
            # not latched: it lasts as long as the graph shows it (a warning, the loop runs on)
            level = max(level, 1)
            message = f"{message}; {'; '.join(conflicts)}"
        st = DiagnosticStatus(level=bytes([level]), name=f"{self.get_fully_qualified_name()}: valve driver",
                              message=message, hardware_id="fuel_valve_driver",
                              values=[KeyValue(key=k, value=_fmt(v)) for k, v in values.items()])
        msg = DiagnosticArray(status=[st])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(msg)
        self.recorder_gate.count(contract.DIAGNOSTICS)
        if level != self._level:
            self.get_logger().info(f"status {LEVEL_NAMES[level]}: {message}")
            self._level = level

    def _input_publishers(self) -> tuple[list[str], dict]:
        """Publishers on the inputs the driver uses (the configured demand topic and Δp), from
        the ROS graph at the diagnostics rate: ``(conflicts, {diagnostic key: count})``.  Two
        publishers on the demand (two supervisors, a forgotten ``ros2 topic pub``) interleave
        their samples and the valve follows whichever came last: the demand filter took the
        alternation between 30 and 50 % for noise and the valve sat at 38 % with the status OK
        (h24u).  A second Δp source makes the readings jump and the schedule falls back.  Each
        is a conflict the status names while it lasts, and so is a publisher of the wrong type
        (DDS never delivers its samples)."""
        if self.driver is None:
            return [], {}
        topic = contract.DEMAND if self.driver.ps["demand_source"] == "percent" else contract.DEMAND_MA
        conflicts, counts = [], {}
        for key, name in (("demand_publishers", topic), ("pressure_publishers", contract.PRESSURE_DIFFERENTIAL)):
            resolved = self._inputs_subs[name].topic_name
            infos = self.get_publishers_info_by_topic(resolved)
            wanted = contract.TOPIC_TYPES[name]
            # a publisher of another type (std_msgs/Float32 from `ros2 topic pub`) never matches:
            # its samples are dropped by DDS and the demand goes stale with no other hint
            foreign = sorted({i.topic_type for i in infos if i.topic_type != wanted})
            n = counts[key] = len(infos) - sum(1 for i in infos if i.topic_type != wanted)
            if n > 1:
                conflicts.append(f"{n} publishers on {resolved}: conflicting sources, the driver takes whichever "
                                 "sample came last")
            if foreign:
                conflicts.append(f"a publisher of {', '.join(foreign)} on {resolved} is ignored ({wanted} expected)")
        other = contract.DEMAND_MA if topic == contract.DEMAND else contract.DEMAND
        if counts["demand_publishers"] == 0:
            # the supervisor publishes the other scaling: the driver reads only demand_source's
            resolved = self._inputs_subs[other].topic_name
            if self.count_publishers(resolved):
                conflicts.append(f"the demand is published on {resolved}, but demand_source is "
                                 f"{self.driver.ps['demand_source']!r}: ignored")
        return conflicts, counts


class ComputeTime:
    """Time spent per control period (sample in -> command out, plus telemetry), since the
    last report: shows whether the node keeps up with the loop rate.  Besides the mean and the
    worst, how many periods took longer than each of :attr:`OVER_MS` (a period of the 1 kHz loop
    is 1 ms: the count over 1 ms is the periods whose command was late by the node's own work)."""

    #: thresholds (ms) of the ``compute_over_<ms>_ms`` counts
    OVER_MS = (0.5, 1.0, 2.0)

    def __init__(self, name: str = "compute"):
        """``name``: the keys' prefix (``compute``: the periods; ``after_command``: the work after a command)."""
        self.name = name
        self.n, self.total, self.worst = 0, 0.0, 0.0
        self.over = [0] * len(self.OVER_MS)

    def add(self, seconds: float) -> None:
        self.n += 1
        self.total += seconds
        self.worst = max(self.worst, seconds)
        for i, ms in enumerate(self.OVER_MS):
            if seconds > 1e-3 * ms:
                self.over[i] += 1

    def take(self) -> dict:
        name = self.name
        out = {f"{name}_mean_ms": 1e3 * self.total / self.n if self.n else None,
               f"{name}_max_ms": 1e3 * self.worst if self.n else None,
               "samples_since_last_report" if name == "compute" else f"{name}_count": self.n}
        out.update({f"{name}_over_{ms:g}_ms".replace(".", "p"): c for ms, c in zip(self.OVER_MS, self.over)})
        self.n, self.total, self.worst = 0, 0.0, 0.0
        self.over = [0] * len(self.OVER_MS)
        return out


def _fmt(x) -> str:
    if x is None:
        return "n/a"
    if isinstance(x, float):
        return f"{x:.6g}"
    return str(x)


def main(args=None) -> int:
    return run_node(ControllerNode, args, on_exit=ControllerNode.save_on_exit)


if __name__ == "__main__":
    raise SystemExit(main())

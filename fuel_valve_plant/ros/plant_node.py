"""``ros2 run fuel_valve plant``: the actuator simulation as a ROS 2 node (SPEC §4).

Subscribes ``current_command`` (q-current reference, A) and ``drive_enable``; publishes
``resolver`` (measured angles, stamp = sample time), ``joint_states`` (ground truth) and
``drive`` (labelled telemetry) at ``publish_rate_hz``, ``pressure_differential`` (the Δp
transducer, kPa, at ``pressure_sensor.rate_hz`` of plant time, with
``pressure_sensor.noise_kpa`` rms noise), plus loop statistics on ``/diagnostics`` once a
second.

Two timing modes:

* real time (default): a dedicated loop thread ticks at ``publish_rate_hz`` (a precise
  sleep-until schedule; an rclpy timer at 1 kHz costs a large share of a core in executor
  overhead); each tick integrates the time elapsed since the previous tick (whole physics
  steps) with the latest command, then publishes.  A tick more than a period late (the
  simulator starved of CPU) starts a new tick grid and advances at most
  :data:`MAX_STEP_PERIODS`: a starved simulator slows its time down rather than coasting the
  valve over a gap on one held command (skipped ticks count as missed periods).  The
  executor thread only receives commands.  The round trip (resolver published -> command received) and the ticks that
  found no new command (missed control periods) are measured and reported.
* lockstep (``lockstep:=true``): the plant owns ``/clock``.  It waits until the loop's
  participants are connected, then publishes ``/clock`` and a resolver sample, and advances
  exactly one period per received ``current_command``.  Runs are deterministic and as fast
  as the loop allows; every node should run with ``use_sim_time:=true``.

  Start-up and lost samples: "connected" means matched endpoints (each publisher's
  ``get_subscription_count()`` and the command subscription's ``get_publisher_count()``),
  not merely nodes in the graph: discovery shows a participant before its endpoints match,
  and a volatile sample published to an unmatched subscription is gone.  The controller's
  readiness is a handshake: it publishes its first ``drive_enable`` (false, latched) only once
  it can answer a sample (command publisher matched, recorder gate open), and the plant starts
  only after receiving it, so tick 0 is not held in the controller past the resend timeout.  As a safety net a
  tick whose command does not come within :data:`LOCKSTEP_RESEND_S` of wall time is
  re-published unchanged (``/clock`` and ``resolver``: same stamp, same values).  Every
  lockstep participant answers a stamp at most once (the controller ignores a resolver
  sample whose stamp it has answered, the demand node a ``/clock`` tick it has answered), so
  a re-published tick reaches only whoever lost it and the run stays identical to the
  offline simulator.  Commands are never re-sent: an unstamped command cannot be told from
  the next period's, and the plant steps once per command.

A period without a new command (real time: the controller's answer to the last sample had not arrived by the
tick) applies the last command again, or -- where the controller has set a schedule on the latched
``current_fallback`` (``contract.CURRENT_FALLBACK``: it does while its output is a timed pulse) -- that schedule's
current for the first, second, ... such period in a row: a command then acts for one period only.  Counted on ``/diagnostics`` (``periods_on_fallback``).

Malformed commands (NaN, inf) never reach the physics: the drive treats them as zero
current with the drive disabled, like a drive that rejects a corrupt set-point.

Drive faults (the drive's own protection, independent of the controller; reported as ERROR on
``/diagnostics`` while active, counted in its values, and in the drive's state word
``drive_status``: latched std_msgs/UInt8, published on change, ``contract.DRIVE_STATE_*``):

* command watchdog (real time): a resolver sample left unanswered for ``command_timeout_s``
  of plant time (default 5 ms, five periods) disables the drive, so a dead or stalled controller cannot leave
  the last current applied; the spring closes the valve.  Like a real drive it does not
  re-enable by itself when commands resume (the controller's law state is stale by then: its
  observer assumed the commanded current acted, and resuming its command drove a soak's valve
  30 % past the demand): it stays off, state ``watchdog``, until the controller re-enables it
  (a ``drive_enable`` true received after the trip), and then applies only commands received
  after that.  In lockstep time stands still without commands: not used.
* internal error: an exception in a callback or in the physics disables the drive and is
  latched until the controller re-enables the drive (``drive_enable`` false, then true); the
  node keeps running.
"""
from __future__ import annotations

import functools
import json
import threading
import time

from rclpy.node import Node

from fuel_valve_control.common import contract
from fuel_valve_control.common.timebase import to_stamp
from fuel_valve_control.ros import interface as ri
from fuel_valve_control.ros.node_runner import run_node, set_timer_slack
from fuel_valve_control.common.paramspec import ConfigError
from ..physics.plant import Plant
from ..physics.params import PLANT_NODE_SPEC, PLANT_SPEC, check_consistency


#: lockstep: wall time between seeing every participant and starting, s
LOCKSTEP_SETTLE_S = 0.5
#: lockstep: wall time without a command after which the current tick is re-published, s
#: (longer than the worst scheduling gap measured on the loaded 2-core machine, 0.62 s: a
#: re-published tick is harmless, but it costs the loop's participants a duplicate to drop;
#: and longer than the demand node may hold a tick's demand back for its subscribers to match,
#: ``contract.LOCKSTEP_MATCH_WAIT_S`` 2 s: at 1 s, a loaded run whose monitor matched late had
#: tick 0 re-published while the demand node was still allowed to wait -- the start handshake
#: test's flake)
LOCKSTEP_RESEND_S = contract.LOCKSTEP_MATCH_WAIT_S + 0.5
#: real time: most simulated time one tick advances, in periods (see ``realtime_loop``: a
#: starved simulator slows its time down instead of coasting the valve over the gap)
MAX_STEP_PERIODS = 2.0


def next_tick_after(now: float, last: float, next_tick: float, period: float) -> tuple[float, float, int]:
    """Real-time tick schedule: a tick woke at ``now`` (s, monotonic), the previous one at
    ``last``, scheduled for ``next_tick``.  Returns (simulated time to advance, s; the next
    tick's time, s; ticks skipped).

    A tick more than a period late (this thread was not scheduled: a starved or frozen
    simulator) starts a new tick grid at ``now`` instead of firing the missed ticks back to
    back -- samples microseconds apart made the controller run a law period (1 ms of its
    time) for each, then nothing for the next gap -- and reports the missed ones as skipped.

    The physics advances by the wall time since the last tick, but by at most
    :data:`MAX_STEP_PERIODS`: a real valve is sampled every period, and the controller would
    have answered each sample, while a starved simulator's valve would coast the whole gap on
    one held command -- a sample-and-hold of 4-6 ms that the 1 kHz loop was never designed
    for (under CPU load it drove the valve into a limit cycle 9 % past a held demand).  So a
    starved simulator slows its simulated time down (a real-time simulator whose real-time
    factor drops below 1) rather than integrating the valve over a gap the controller could
    not see.  A stalled *controller* (the case the drive watchdog is for) is unaffected: the
    plant keeps ticking every period with the held command."""
    skipped = 0
    if now - next_tick > period:
        skipped = int((now - next_tick) / period + 1e-6)      # grid points passed meanwhile
        next_tick = now
    return min(now - last, MAX_STEP_PERIODS * period), next_tick + period, skipped


def guarded(method):
    """A callback never raises into the executor: an exception disables the drive and is
    reported (:meth:`PlantNode.drive_fault`); the node keeps running."""
    @functools.wraps(method)
    def wrapper(self, *args):
        try:
            return method(self, *args)
        except Exception as exc:            # noqa: BLE001 - fail safe, keep the node alive
            self.drive_fault(method.__name__, exc)
            return None
    return wrapper


class DurationHistogram:
    """Durations (s) counted in bins of ``resolution_s`` up to ``limit_s`` (longer ones in the
    last bin; the largest is kept exactly): quantiles without keeping or sorting the samples.

    Why: the loop statistics are summarised once a second on the executor thread, with the GIL
    held.  Sorting every round trip and tick lateness of the run so far cost milliseconds that
    grew with the run (two lists of 60 000 floats after a minute): the tick thread and the
    command callback waited meanwhile, and the missed periods per second grew along the run.
    Adding is O(1), a summary O(bins)."""

    def __init__(self, resolution_s: float = 1e-5, limit_s: float = 0.1):
        self.resolution_s = resolution_s
        self.counts = [0] * (int(round(limit_s / resolution_s)) + 1)
        self.n = 0
        self.max = 0.0

    def add(self, seconds: float) -> None:
        i = int(seconds / self.resolution_s) if seconds > 0.0 else 0
        self.counts[min(i, len(self.counts) - 1)] += 1
        self.n += 1
        if seconds > self.max:
            self.max = seconds

    def quantile(self, q: float) -> float:
        """The ``q`` quantile (the sample of rank ``int(q n)``, as sorted samples would give it) to
        within one bin: the upper edge of its bin, never above the largest sample (s)."""
        rank = min(int(q * self.n), self.n - 1)
        seen = 0
        for i, c in enumerate(self.counts):
            seen += c
            if seen > rank:            # the last bin holds everything beyond the range: its largest
                return self.max if i == len(self.counts) - 1 else min((i + 1) * self.resolution_s, self.max)
        return self.max


class LoopStats:
    """Round-trip times and missed periods of the control loop, seen from the plant; ticks and
    missed periods count from the first command received (before it the loop is open).

    Also the tick thread's own lateness (wake-up time minus the scheduled tick, s, every tick):
    it tells a late tick (sleep overshoot, the tick thread not scheduled, the GIL held by the
    executor thread) from a late answer (the round trip), the two causes of a missed period.
    Quantiles to 10 us (:class:`DurationHistogram`)."""

    def __init__(self):
        self.rtts = DurationHistogram()
        self.lates = DurationHistogram()
        self.ticks = 0
        self.missed = 0
        self.commands = 0

    def add_rtt(self, seconds: float) -> None:
        self.rtts.add(seconds)

    def add_late(self, seconds: float) -> None:
        self.lates.add(seconds)

    def summary(self) -> dict:
        out = {"ticks": self.ticks, "missed": self.missed, "commands": self.commands,
               "missed_fraction": self.missed / self.ticks if self.ticks else 0.0}
        if self.rtts.n:
            out.update(rtt_median_ms=1e3 * self.rtts.quantile(0.5), rtt_p99_ms=1e3 * self.rtts.quantile(0.99),
                       rtt_max_ms=1e3 * self.rtts.max, rtt_samples=self.rtts.n)
        if self.lates.n:
            out.update(tick_late_median_ms=1e3 * self.lates.quantile(0.5),
                       tick_late_p99_ms=1e3 * self.lates.quantile(0.99), tick_late_max_ms=1e3 * self.lates.max)
        return out


class PlantNode(Node):
    def __init__(self, **kwargs):
        super().__init__("plant", **kwargs)
        ri.declare_spec(self, PLANT_NODE_SPEC)
        ri.unknown_overrides(self)           # typos in a parameter file: logged
        try:
            node_ps = PLANT_NODE_SPEC.defaults().replace(ri.read_spec(self, PLANT_NODE_SPEC))
            self.ps = PLANT_SPEC.pick(node_ps)
            check_consistency(self.ps)
        except ConfigError as exc:
            raise SystemExit(f"plant: invalid parameters: {exc}") from None
        self.plant = Plant(self.ps)
        self.period = 1.0 / node_ps["publish_rate_hz"]
        self.lockstep = node_ps["lockstep"]
        self._iq = 0.0
        self._enable = False
        if node_ps["start_held"]:
            self._iq, self._enable = self.plant.hold_at(self.ps["initial_position_rad"]), True
        self._command_rejected = False
        self._bad_commands = 0
        self.stats = LoopStats()
        self._got_command = False
        self._last_publish_mono = None
        # drive protection (module docstring): watchdog and internal-error latch
        self._command_timeout = node_ps["command_timeout_s"]
        self._awaiting_since: float | None = None   # plant time of the first sample published since the last command
        self._watchdog_off = False
        self._watchdog_trips = 0
        self._fault: str | None = None
        self._state_reported: int | None = None     # the drive state word last published
        self._state_lock = threading.Lock()         # published from the loop thread and callbacks
        # how long one command acted (real time, /diagnostics): commands received (a count the
        # tick compares), the plant time the one in force has been applied with the drive on,
        # the longest such time and the commands applied longer than two periods
        self._commands_received = 0
        self._held_command = 0
        self._held_s = 0.0
        self._held_max_s = 0.0
        self._held_long = 0
        #: the currents applied over consecutive periods without a new command (contract.CURRENT_FALLBACK; empty: hold
        #: the last command), the periods without one in a row so far, and the periods a fallback was applied in
        self._fallback: tuple[float, ...] = ()
        self._missed_run = 0
        self.fallback_periods = 0

        from sensor_msgs.msg import JointState
        from std_msgs.msg import Bool, Float64, Float64MultiArray, UInt8
        from diagnostic_msgs.msg import DiagnosticArray
        recorded = ri.recorded_topics(node_ps["recorded_topics"])
        deep = bool(recorded)                 # a recorder in the run: deep writer histories
        self.pub_resolver = ri.quiet_publisher(self, JointState, contract.RESOLVER, recorded=deep)
        self.pub_truth = ri.quiet_publisher(self, JointState, contract.JOINT_STATES, recorded=deep)
        self.pub_drive = ri.quiet_publisher(self, Float64MultiArray, contract.DRIVE, recorded=deep)
        self._drive_cdr = ri.LabelledArrayCdr(contract.TELEMETRY_LABELS)   # serialized: see its docstring
        self.pub_pressure = ri.quiet_publisher(self, Float64, contract.PRESSURE_DIFFERENTIAL, recorded=deep)
        self._float = Float64
        self.pub_status = ri.quiet_publisher(self, UInt8, contract.DRIVE_STATUS, recorded=deep)
        self._uint8 = UInt8
        self.pub_diag = ri.quiet_publisher(self, DiagnosticArray, contract.DIAGNOSTICS, recorded=deep)
        #: messages published per topic (printed at exit) and the recorder hold (recorded_topics)
        self.recorder_gate = ri.RecorderGate(self, recorded)
        # the loop's inputs, taken by the node runner's executor; drive_enable first: in
        # lockstep a command steps the plant at once, with the enable state it applies to
        ri.quiet_subscription(self, Bool, contract.DRIVE_ENABLE, self.on_enable)
        self.sub_command = ri.quiet_subscription(self, Float64, contract.CURRENT_COMMAND, self.on_command)
        ri.quiet_subscription(self, Float64MultiArray, contract.CURRENT_FALLBACK, self.on_fallback)
        ri.handle_parameter_changes(self, PLANT_SPEC, self.plant.check_params, self.apply_parameters)
        self.create_timer(1.0, self.publish_diagnostics)
        self.report_state()
        if self.lockstep:
            from builtin_interfaces.msg import Time
            from rosgraph_msgs.msg import Clock
            self._clock_msg, self._time_msg = Clock, Time     # built every period: resolve once
            self.pub_clock = ri.quiet_publisher(self, Clock, contract.CLOCK, recorded=deep)
            self._clock_topic = self.pub_clock.topic_name       # as remapped (the valve's own clock)
            self._started = False
            self._waiting_since = time.monotonic()
            self._participants = node_ps["lockstep_participants"]
            self._stop_after = node_ps["stop_after_s"]
            self._finished = False
            self._ready_since = None
            self._hello = False             # the controller's drive_enable received (try_start)
            self._start_timer = self.create_timer(0.05, self.try_start)
            #: the current tick's loop messages, as published (re-published unchanged when lost)
            self._tick_msgs: tuple = ()
            self.republished = 0
            self.create_timer(0.1, self.resend_if_stalled)
        else:
            self._lock = threading.Lock()
            self._running = True
            self.timer_slack_ns: int | None = None      # the tick thread's, once it runs
            self._thread = threading.Thread(target=self.realtime_loop, name="plant-loop", daemon=True)
            self._thread.start()
        self.get_logger().info(
            f"plant up: {'lockstep' if self.lockstep else 'real time'}, publish {1 / self.period:g} Hz, physics "
            f"{self.ps['physics_rate_hz']:g} Hz, dp {self.ps['pressure_differential_kpa']:g} kPa")

    # ------------------------------------------------------------------ drive protection
    def drive_fault(self, where: str, exc: BaseException) -> None:
        """Latch an internal drive fault: drive off at once, ERROR on /diagnostics."""
        self._fault = f"internal error in {where}: {type(exc).__name__}: {exc}"
        self.get_logger().error(f"{self._fault}; drive disabled until re-enabled", throttle_duration_sec=1.0)
        try:
            self.plant.set_command(0.0, False)
        except Exception:                   # noqa: BLE001 - the physics itself failed: nothing to set
            pass
        try:
            self.report_state()
        except Exception:                   # noqa: BLE001 - context gone: /diagnostics says it too
            pass

    def drive_state(self) -> int:
        """The drive's state word (``contract.DRIVE_STATE_*``)."""
        if self._fault is not None:
            return contract.DRIVE_STATE_FAULT
        if self._watchdog_off:
            return contract.DRIVE_STATE_WATCHDOG
        return contract.DRIVE_STATE_ENABLED if self._enable else contract.DRIVE_STATE_DISABLED

    def report_state(self, always: bool = False) -> None:
        """Publish the drive's state word when it has changed (latched: a late joiner learns it),
        or ``always`` (the answer to an enable: a controller that re-sends one after a lost
        report learns the state again)."""
        with self._state_lock:
            state = self.drive_state()
            if always or state != self._state_reported:
                self._state_reported = state
                self.pub_status.publish(self._uint8(data=state))
                self.recorder_gate.count(contract.DRIVE_STATUS, latched=True)

    def _check_watchdog(self, elapsed: float) -> None:
        """Real time, each tick about to advance the physics by ``elapsed`` s: disable the drive
        when a sample stays unanswered too long.  Counted in the plant's own time (sample time
        to the end of this tick's step), not the wall clock: a simulator frozen for a second
        (starved of CPU) advances only :data:`MAX_STEP_PERIODS` over it, and its drive must
        not trip for a silence of the controller that only the frozen simulator caused (the
        controller had answered; the simulator had not published since)."""
        # read once: the command callback (executor thread, not under the tick's lock) clears
        # it at any time; read twice, a clear between the check and the subtraction raised
        # TypeError (float - None) in the tick and latched a drive fault (stop 18, the stall
        # test under load: "the drive reports an internal fault")
        since = self._awaiting_since
        unanswered = None if since is None else self.plant.time + elapsed - since
        if not self._watchdog_off and unanswered is not None and unanswered > self._command_timeout:
            self._watchdog_off = True
            self._watchdog_trips += 1
            self.get_logger().error(f"drive watchdog: no current command for {unanswered * 1e3:.1f} "
                                    f"ms (limit {self._command_timeout * 1e3:g} ms): drive disabled until the "
                                    "controller re-enables it", throttle_duration_sec=1.0)
            self.report_state()

    def _command_arrived(self) -> None:
        # resumed commands do not re-enable a tripped drive: only the controller does (on_enable)
        self._awaiting_since = None

    # ------------------------------------------------------------------ inputs
    @guarded
    def on_command(self, msg) -> None:
        self._command_arrived()
        value = msg.data
        if not ri.finite(value):
            self._bad_commands += 1
            self.get_logger().warn(f"non-finite current command {value!r}: drive held off", throttle_duration_sec=1.0)
            self._iq, self._command_rejected = 0.0, True
        else:
            self._iq, self._command_rejected = float(value), False
        self.stats.commands += 1
        self._commands_received += 1
        if self._last_publish_mono is not None and not self._got_command:
            self.stats.add_rtt(time.monotonic() - self._last_publish_mono)
        self._got_command = True
        if self.lockstep and self._started:
            if 0.0 < self._stop_after <= self.plant.time + 0.5 * self.period:
                if not self._finished:
                    self._finished = True
                    self.get_logger().info(f"lockstep: stop_after_s reached at t = {self.plant.time:.3f} s")
                return
            self.step_and_publish(self.period)

    @guarded
    def on_fallback(self, msg) -> None:
        """``current_fallback`` (contract.CURRENT_FALLBACK): the currents for consecutive periods without a new
        command; empty: hold the last command.  A schedule with a non-finite element is refused (logged; the last
        command is held)."""
        values = tuple(float(x) for x in msg.data)
        if not contract.fallback_valid(values):
            self.get_logger().warn(f"current fallback {list(values)!r} A refused: the last command is held in a "
                                   "period without one", throttle_duration_sec=1.0)
            values = ()
        self._fallback = values

    @guarded
    def on_enable(self, msg) -> None:
        enable = bool(msg.data)
        if self.lockstep and not self._started:
            self._hello = True              # the controller's start-up hello (see try_start)
        if enable and not self._enable and self._fault is not None:
            self.get_logger().info(f"drive re-enabled by the controller: cleared {self._fault}")
            self._fault = None
        if enable and self._watchdog_off:
            # the controller has seen the trip and re-armed (a true sent after the trip): back
            # on, but with zero current until its first command after the re-enable
            self._watchdog_off = False
            self._iq = 0.0
            self.get_logger().info("drive watchdog: re-enabled by the controller")
        self._enable = enable
        self.report_state(always=True)

    def _apply_command(self) -> None:
        enabled = (self._enable and not self._command_rejected and not self._watchdog_off
                   and self._fault is None)
        self.plant.set_command(self._iq if enabled else 0.0, enabled)

    # ------------------------------------------------------------------ timing
    def realtime_loop(self) -> None:
        """Real-time mode: tick every period on a sleep-until schedule (from the moment the
        recorder, if the run has one, has matched: :class:`~fuel_valve_control.ros.interface.RecorderGate`)."""
        self.timer_slack_ns = set_timer_slack()     # this thread's sleeps (node_runner)
        while self._running and not self.recorder_gate.opened.wait(0.05):
            pass
        self._last_tick = time.monotonic()
        self._next_tick = self._last_tick + self.period
        while self._running:
            try:
                self._tick()
            except Exception as exc:                # noqa: BLE001
                # the end: stop() was called (its join may have timed out on a starved machine,
                # and the node been destroyed under this thread since) or the context shut down
                # under us -- a thread traceback in a clean shutdown's log, not a drive fault
                if not self._running or not self.context.ok():
                    return
                self.drive_fault("real-time tick", exc)

    def _tick(self) -> None:
        """One tick of :meth:`realtime_loop`: sleep until ``_next_tick`` (monotonic s), advance
        the physics by the wall time since the last tick (``_last_tick``) and publish."""
        next_tick = self._next_tick
        delay = next_tick - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        now = time.monotonic()
        self.stats.add_late(now - next_tick)
        # the sample instant: the state published this tick is the state at this time, so
        # consecutive stamps differ by the wall time the tick covers even when the thread
        # is pre-empted between here and the publish (a stamp taken at publish time made a
        # starved plant look like a 65 rad/s resolver jump to the controller); a starved
        # tick advances less simulated time than that (next_tick_after), which only makes
        # the valve look slower
        stamp = self.get_clock().now().to_msg()
        elapsed, self._next_tick, skipped = next_tick_after(now, self._last_tick, next_tick, self.period)
        self._last_tick = now
        with self._lock:
            if self.stats.commands:         # the loop is closed (a controller answers): count
                self.stats.ticks += 1 + skipped     # its periods (those skipped: missed); before,
                self.stats.missed += skipped        # every tick would be "missed"
                self._missed_run = 0 if self._got_command else self._missed_run + 1
                if not self._got_command:
                    self.stats.missed += 1
                    # no answer to the last sample: a command is applied for one period only where the controller
                    # set a fallback (its timed pulses: held, a kick is a longer kick), else held
                    if self._fallback and not self._command_rejected:
                        self._iq = contract.current_without_command(self._iq, self._fallback, self._missed_run)
                        self.fallback_periods += 1
                self._check_watchdog(elapsed)
                self._count_held(elapsed)
            if self._awaiting_since is None:
                # the sample about to be published (plant time): marked before the
                # publish, so an answer that arrives at once clears it (marked after
                # the publish, a fast answer was overwritten and the sample counted
                # as unanswered)
                self._awaiting_since = self.plant.time + elapsed
            self.step_and_publish(elapsed, stamp)

    def _count_held(self, elapsed: float) -> None:
        """Real time, each tick about to apply the command in force for ``elapsed`` s of plant
        time: how long one command has acted with the drive on.  A starved loop's command acts
        until its next answer (up to the watchdog's ``command_timeout_s`` plus the tick that
        finds it), whatever sample it answered: the integrator's measure of a loop that keeps
        the drive on but answers late (docs/control_results.md section 54)."""
        if self._commands_received != self._held_command:
            self._held_command, self._held_s = self._commands_received, 0.0
        if not (self._enable and not self._watchdog_off and self._fault is None):
            self._held_s = 0.0
            return
        before, self._held_s = self._held_s, self._held_s + elapsed
        if before <= 2.0 * self.period < self._held_s:
            self._held_long += 1
        self._held_max_s = max(self._held_max_s, self._held_s)

    def stop(self) -> None:
        if not self.lockstep:
            self._running = False
            self._thread.join(timeout=1.0)

    def try_start(self) -> None:
        """Lockstep: start once the controller (and the other participants) are connected."""
        if self._started or not self.recorder_gate.is_open:   # a queued call after the cancel;
            return                                            # the recorder still matching
        clock = self.pub_clock.topic_name           # /clock as remapped: the valve's own clock
        clock_nodes = {(i.node_namespace, i.node_name) for i in self.get_subscriptions_info_by_topic(clock)}
        # the graph (what discovery has seen) and the publishers' matched subscriptions (what a
        # message published now would actually reach) must both be complete
        ready = (self.count_subscribers(contract.RESOLVER) >= 1 and self.count_publishers(contract.CURRENT_COMMAND) >= 1
                 and len(clock_nodes) >= self._participants
                 and self.pub_resolver.get_subscription_count() >= max(1, self.count_subscribers(contract.RESOLVER))
                 # the controller always subscribes to Δp: tick 0's sample must reach it (a
                 # volatile sample to a subscription not matched yet is gone, and period 0
                 # would run on the fallback Δp: 0.026 rad off the offline run)
                 and self.pub_pressure.get_subscription_count() >= max(1, self.count_subscribers(
                     contract.PRESSURE_DIFFERENTIAL))
                 # the command's way back: matched on this side (the controller holds its first
                 # command until its side has matched too)
                 and self.sub_command.get_publisher_count() >= 1
                 # and the controller can answer: its hello (its first drive_enable, false, sent
                 # once its command publisher has matched and its recorder gate is open; latched,
                 # so it arrives however late this side matches) has arrived.  Without it tick 0
                 # waited in the controller for its recorder gate and was re-published after
                 # LOCKSTEP_RESEND_S
                 and self._hello
                 # every discovered /clock subscription, not one per node: the demand node has two
                 # (its time source and its tick handler) and needs the second for the first tick
                 and self.pub_clock.get_subscription_count() >= max(self._participants,
                                                                    self.count_subscribers(clock)))
        if not ready:
            self._ready_since = None
            if time.monotonic() - self._waiting_since > 5.0:
                self.get_logger().info("lockstep: waiting for the controller and clock subscribers",
                                       throttle_duration_sec=5.0)
            return
        # discovery is seen from this side first: give the other side time to match too, or
        # the first messages of the run could be lost
        if self._ready_since is None:
            self._ready_since = time.monotonic()
        if time.monotonic() - self._ready_since < LOCKSTEP_SETTLE_S:
            return
        self._start_timer.cancel()
        self._started = True
        self.get_logger().info("lockstep: participants connected, starting")
        self.publish_outputs()

    def resend_if_stalled(self) -> None:
        """Lockstep safety net: re-publish the current tick (same ``/clock`` stamp, same resolver
        sample) when its command has not come within :data:`LOCKSTEP_RESEND_S` of wall time.
        Whoever already answered that stamp drops the copy; whoever lost it answers now."""
        if (not self._started or self._finished or self._got_command or not self._tick_msgs
                or time.monotonic() - self._last_publish_mono < LOCKSTEP_RESEND_S):
            return
        self._last_publish_mono = time.monotonic()      # next copy after another timeout
        for pub, msg, topic in self._tick_msgs:
            pub.publish(msg)
            self.recorder_gate.count(topic)
        self.republished += 1
        self.get_logger().info(f"lockstep: no command for t = {self.plant.time:.3f} s within "
                               f"{LOCKSTEP_RESEND_S:g} s: tick re-published", throttle_duration_sec=5.0)

    def step_and_publish(self, duration: float, stamp=None) -> None:
        """Advance the plant by ``duration`` s and publish its outputs, stamped ``stamp``
        (real time: the tick's sample instant; lockstep: None, the simulated time)."""
        self._apply_command()
        self.plant.advance(duration)
        self.publish_outputs(stamp)

    def publish_outputs(self, stamp=None) -> None:
        t = self.plant.time
        if self.lockstep:
            sec, nanosec = to_stamp(t)
            stamp = self._time_msg(sec=sec, nanosec=nanosec)
            clock = self._clock_msg(clock=stamp)
            self.pub_clock.publish(clock)
            self.recorder_gate.count(self._clock_topic)
            self._tick_msgs = ((self.pub_clock, clock, self._clock_topic),)
        elif stamp is None:
            stamp = self.get_clock().now().to_msg()
        dp = self.plant.pressure_sample()
        if dp is not None:        # first: in lockstep the controller uses it this very period
            self.pub_pressure.publish(self._float(data=dp))
            self.recorder_gate.count(contract.PRESSURE_DIFFERENTIAL)
        sample = self.plant.resolver()
        self._got_command = False
        self._last_publish_mono = time.monotonic()
        if sample is not None:
            resolver = ri.joint_state(stamp, (sample.motor_rad, sample.valve_rad))
            self.pub_resolver.publish(resolver)
            self.recorder_gate.count(contract.RESOLVER)
            if self.lockstep:
                self._tick_msgs += ((self.pub_resolver, resolver, contract.RESOLVER),)
        truth = self.plant.truth()
        self.pub_truth.publish(ri.joint_state(
            stamp, (truth.motor_angle, truth.valve_angle), (truth.motor_velocity, truth.valve_velocity),
            (truth.electromagnetic_torque, truth.coupling_torque)))
        self.pub_drive.publish(self._drive_cdr(self.plant.telemetry()))
        self.recorder_gate.count(contract.JOINT_STATES)
        self.recorder_gate.count(contract.DRIVE)

    # ------------------------------------------------------------------ parameters
    @guarded
    def apply_parameters(self, changes: dict) -> None:
        """Post-set: the plant swaps in the accepted values (between two loop ticks)."""
        if self.lockstep:
            self.plant.set_params(changes)
        else:
            with self._lock:
                self.plant.set_params(changes)

    @guarded
    def publish_diagnostics(self) -> None:
        if not self.recorder_gate.is_open:
            return
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        s = self.stats.summary()
        st = DiagnosticStatus(name=f"{self.get_fully_qualified_name()}: loop", hardware_id="fuel_valve_plant")
        st.level = DiagnosticStatus.OK
        st.message = "simulating" if (not self.lockstep or self._started) else "waiting for lockstep participants"
        if self._bad_commands:
            st.level = DiagnosticStatus.WARN
            st.message = f"{self._bad_commands} non-finite current commands rejected"
        if self._watchdog_off:
            st.level = DiagnosticStatus.ERROR
            st.message = (f"drive fault: command watchdog ({self._command_timeout * 1e3:g} ms without a current "
                          "command): drive disabled, spring closing the valve")
        if self._fault is not None:
            st.level = DiagnosticStatus.ERROR
            st.message = f"drive fault: {self._fault}: drive disabled"
        values = {"plant_time_s": f"{self.plant.time:.3f}", "valve_angle_rad": f"{self.plant.valve_angle:.5f}",
                  "pressure_differential_kpa": f"{self.plant.params['pressure_differential_kpa']:g}",
                  "fault_injection": self.plant.params["fault_injection"],
                  "drive_enabled": str(bool(self._enable and not self._watchdog_off and self._fault is None)),
                  "watchdog_trips": str(self._watchdog_trips)}
        if self.lockstep:
            values["lockstep_ticks_republished"] = str(self.republished)
        else:
            values["command_held_max_ms"] = f"{self._held_max_s * 1e3:.3f}"
            values["commands_held_over_2_periods"] = str(self._held_long)
            values["current_fallback_a"] = " ".join(f"{x:.3f}" for x in self._fallback) or "hold"
            values["periods_on_fallback"] = str(self.fallback_periods)
        values.update({k: f"{v:.6g}" if isinstance(v, float) else str(v) for k, v in s.items()})
        if not self.lockstep:
            values["timer_slack_ns"] = str(getattr(self, "timer_slack_ns", None))
        st.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        msg = DiagnosticArray(status=[st])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(msg)
        self.recorder_gate.count(contract.DIAGNOSTICS)


def main(args=None) -> int:
    def report(node):
        node.stop()
        # one JSON line (launcher.loop_statistics and the benchmarks parse it)
        node.get_logger().info(f"loop statistics: {json.dumps(node.stats.summary())}")
    return run_node(PlantNode, args, on_exit=report)


if __name__ == "__main__":
    raise SystemExit(main())

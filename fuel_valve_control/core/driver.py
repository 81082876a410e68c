"""The valve driver core: demand handling, fault logic and the position controller (SPEC §4).

This is what the controller node runs and what the offline simulator runs, so fault
reactions are tested without ROS.  Inputs arrive as events (demand, resolver sample, measured
pressure differential, optional measured current, trip/reset); :meth:`ValveDriver.step` is
called once per loop period and returns the current command and drive enable.

The measured pressure differential Δp (kPa) schedules the friction-dependent terms of the
law.  A missing (none received ``pressure.timeout_s`` after the first period), stale (older
than ``pressure.timeout_s``) or implausible (not finite, beyond 0..pressure max by more than
``pressure.range_margin_kpa``, or changing faster than ``pressure.max_rate_kpa_s``) Δp is a
latched *warning*, not a fault: the drive keeps running with the friction terms scheduled for
``pressure.fallback_kpa``.  The default fallback, 0 kPa, is the conservative one: valve friction
grows with Δp, so the Δp = 0 schedule never asks for more friction torque than the valve has
(under-compensation: a slower, stickier valve), whereas a schedule above the real Δp pushes
the valve past breakaway on its own and hunts (measured with ``fuel_valve_sim`` on ``hold``,
observer_fc: told 6206 kPa with the real Δp 0 -> a 4.4e-3 rad limit cycle; told 0 with the
real Δp 6206 kPa -> no limit cycle).  Valid samples are used again as soon as they arrive; the
warning stays latched until :meth:`ValveDriver.reset` (SPEC §4), and each gap (missing or stale
readings) is counted on /diagnostics (``pressure_gap_episodes``).  Two refinements: in real time
the first arm's wait for a steady resolver stream (``faults.arm_steady_s``) also waits out Δp gaps
-- a node process's start-up stall (0.27 s under ``ros2 launch`` on a loaded machine) is no
failed transducer, and latched the node at WARN for good -- and the missing-Δp watch starts at
the end of that wait; ``pressure.recover_s`` > 0 lets a gap's warning clear itself after that
long of timely readings (a deployment's choice; an *implausible* reading's warning -- not
finite, out of range, too fast: the transducer -- stays latched regardless).

A reading can be plausible as a signal and still wrong (a biased transducer, a gain error):
:class:`~.friction_check.FrictionCheck` (``pressure.friction_check``) compares the static
friction the valve shows at its confirmed breakaways with the friction the Δp schedule
predicts.  Where no friction scale within ``pressure.friction_scale_min..max`` (widened by
``pressure.friction_check_margin``) explains it, the :data:`PRESSURE_FRICTION` warning latches
and the friction terms are scheduled for the Δp the friction met says instead (until the
reading agrees with the friction again): measured with ``fuel_valve_sim``, told Δp max on a
valve at Δp 0 hunted; see test_pressure_input.py for the figures.

Faults latch until :meth:`reset` and all react the same way: drive enable false and zero
current, so the return spring closes the valve (fail safe).  A stale demand with
``demand_timeout_action: hold`` is the one exception: the valve holds the last good demand
and a latched warning is raised instead.

Malformed input never raises: NaN/inf/out-of-range values become faults or warnings.  Nor
does a defect: an exception anywhere in an input handler or in :meth:`ValveDriver.step` (the
law, the limits, a numerical overflow) and a non-finite command are caught and latched as the
:data:`INTERNAL` fault, so the loop keeps running with the drive disabled and says why, instead
of dying with the last command still applied.
"""
from __future__ import annotations

import json
import math
import threading
from collections import deque
from dataclasses import dataclass, field, replace

from ..common.contract import (DRIVE_STATE_ENABLED, DRIVE_STATE_FAULT, DRIVE_STATE_NAMES, DRIVE_STATE_WATCHDOG, NE43_FAIL_HIGH_MA, NE43_FAIL_LOW_MA, NE43_USABLE_HIGH_MA, NE43_USABLE_LOW_MA,
                                PERCENT_FAIL_MARGIN, PRESSURE_MAX_KPA, RESOLVER_COUNT_RAD, ma_to_percent)
from ..common.paramspec import ParamSet

from .demand_filter import DemandFilter, DemandFilterConfig
from .friction_check import FrictionCheck
from .health import ValveHealth
from .params import CONTROLLER_SPEC, check_consistency, check_tighten_only
from .position_controller import PositionController
from .signals import Measurement

DEMAND_SIGNAL = "demand_signal_failure"
DEMAND_STALE = "demand_stale"
RESOLVER_STALE = "resolver_stale"
RESOLVER_IMPLAUSIBLE = "resolver_implausible"
TRACKING = "tracking_error"
OVERCURRENT = "overcurrent_i2t"
TRIPPED = "commanded_trip"
#: an exception in the driver's own code (law, limits, arithmetic) or a non-finite command
INTERNAL = "internal_error"
#: the drive reports an internal fault of its own (:data:`~..common.contract.DRIVE_STATE_FAULT`)
DRIVE_FAULT = "drive_fault"
FAULT_CODES = (DEMAND_SIGNAL, DEMAND_STALE, RESOLVER_STALE, RESOLVER_IMPLAUSIBLE, TRACKING, OVERCURRENT, TRIPPED,
               INTERNAL, DRIVE_FAULT)
#: the longest loop gap counted as time by the duty counters (NE107 inputs), periods: a stalled
#: loop's gap is not operating time
STALL_REARM_PERIODS = 20
#: the least sample age (:meth:`ValveDriver.loop_timing`) creeps up by this fraction of a period
#: per sample (1 ms per second at 1 kHz): an offset between the two clocks that grows (a clock
#: step, a drift) is absorbed within seconds, while a burst of late samples stands out
AGE_FLOOR_CREEP = 1e-3
#: resolver samples over which a drive-off re-arm judges the valve's speed (about the observer's
#: settling: the re-armed observer starts at rest and learns the real speed within a few periods)
REST_WINDOW_SAMPLES = 10
#: a reset is refused until the inputs have been plausible for this long, s: an intermittent
#: cause (a resolver noise burst, a flickering demand) must not be reset between two bad samples
RESET_QUIET_S = 0.1
#: a law replaced at run time (mode, a law parameter) mid-move hands a half-finished move to a
#: law whose reference and estimators start afresh: alternating laws every 0.1 s during a
#: 20-60 % sweep drove the valve 29-40 % past the demand in the offline simulator.  So a law
#: replacement waits until the loop holds -- a steady demand and the valve within this of it,
#: rad (0.5 % of stroke), for ``param_swap_periods`` periods in a row -- but at most
#: :data:`PARAM_SWAP_MAX_WAIT_S` after it was first requested
PARAM_SWAP_SETTLED_RAD = 5e-3
PARAM_SWAP_MAX_WAIT_S = 1.0
#: longest wait, s, for a drive re-enabled after its watchdog trip to report it is on again (the
#: law is held at its re-arm meanwhile); then the re-enable is sent again (a drive answers
#: every enable with its state word, so a lost report is not mistaken for a drive that stays
#: off).  Beyond the 44 ms a starved plant took in the soak
DRIVE_BACK_TIMEOUT_S = 0.1
#: re-enables sent after one watchdog trip before the loop gives up and latches
#: :data:`DRIVE_FAULT` (the drive does not take them).  Until this rule the law ran on after
#: the first timeout against a drive that still reported itself off: under CPU load (load
#: average 10) it commanded 15 A into a switched-off drive while the spring closed the valve,
#: and the twist check then latched "a resolver has failed" -- safe, but a false diagnosis
DRIVE_BACK_ATTEMPTS = 5
#: warning code of a missing, stale or implausible measured pressure differential
PRESSURE_INPUT = "pressure_differential"
#: key in a "waiting" output's warnings while the first arm waits for a steady resolver stream
#: (``faults.arm_steady_s``, real time)
RESOLVER_SETTLING = "resolver_settling"
#: warning code of a measured Δp that disagrees with the valve friction met (friction_check.py)
PRESSURE_FRICTION = "pressure_differential_implausible"


def _guarded(method):
    """Input handlers never raise: an exception becomes the latched :data:`INTERNAL` fault."""
    import functools

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        try:
            return method(self, *args, **kwargs)
        except Exception as exc:           # noqa: BLE001 - any defect must fail safe, not kill the loop
            self.internal_fault(method.__name__, exc)
            return None
    return wrapper


#: late-loop episodes the driver keeps (``fine.late_loop_repeats`` counts among them)
LATE_EPISODES_KEPT = 16


@dataclass
class DriverOutput:
    current_a: float
    enable: bool
    state: str                           # waiting | running | holding | inactive | fault
    demand_pct: float | None
    position_pct: float | None
    faults: dict = field(default_factory=dict)      # code -> message (latched)
    warnings: dict = field(default_factory=dict)    # code -> message
    #: the drive switched itself off under the running law (its command watchdog) and the loop
    #: has re-armed: send drive_enable true again (an explicit re-enable) with this command
    reenable: bool = False
    #: the currents (A) the drive is to apply over the first, second, ... period in a row for which no new command
    #: arrives (contract.CURRENT_FALLBACK; empty: hold the last command): set while the law's output is a timed
    #: sequence (``fine.pulse_fallback``)
    fallback_currents_a: tuple = ()


class ValveDriver:
    def __init__(self, params: ParamSet | None = None):
        self.ps = params if params is not None else CONTROLLER_SPEC.defaults()
        #: the start-up set: the widest rating/supervision limits this driver accepts at run time
        self.startup_ps = self.ps
        self.controller = PositionController(self.ps)
        self.stroke = self.controller.model.stroke_rad
        self.n = self.controller.model.gear_ratio
        self.period = self.controller.period
        self._twist_kept: tuple | None = None      # (ps, model, constants) of _twist_constants
        self.faults: dict[str, str] = {}
        self.warnings: dict[str, str] = {}
        self._demand_pct: float | None = None      # last good demand (selected source)
        self._demand_t: float | None = None
        self._demand_bad: str | None = None        # why the latest demand message was rejected
        #: conditioning of the (analog) demand; runs on every accepted sample so a mode switch
        #: finds it settled; the pi baselines take the raw demand
        self.demand_filter = DemandFilter(demand_filter_config(self.ps))
        self._demand_cond_rad: float | None = None
        self._meas: Measurement | None = None
        self._meas_t: float | None = None
        self._meas_bad: str | None = None
        self._bad_input_t: float | None = None     # loop time of the latest implausible input
        self._armed = False
        self._arm_torque = 0.0
        self._t: float | None = None               # time of the latest step
        self.stall_rearms = 0                      # re-arms after the drive went off (diagnostics)
        #: real-time loop timing (:meth:`loop_timing`): the previous sample's (stamp, arrival), s;
        #: loop time of the latest late period and why (None: never late); late periods counted
        self._timing_prev: tuple[float, float] | None = None
        self._late_t: float | None = None
        #: the start times (s) of the last late episodes (fine.late_loop_holdoff_first_s apart or more)
        self._late_episodes: deque = deque(maxlen=LATE_EPISODES_KEPT)
        self._late_why = ""
        self.late_loop_events = 0
        #: ``faults.arm_steady_s`` (real time only: :meth:`loop_timing` seen): the first arm after
        #: construction or activation waits for the resolver stream to run on time that long; the
        #: stamp that began its current on-time run (None: none yet)
        self._real_time = False
        self._awaiting_steady = True
        self._steady_since: float | None = None
        #: age of the latest resolver sample when it arrived (arrival minus stamp, s; None: not
        #: known, offline) and the loop time the drive last reported itself enabled (diagnostics)
        self._sample_age: float | None = None
        self._enabled_since: float | None = None
        #: stale samples (:meth:`loop_timing`, ``faults.stale_sample_periods``): the least age seen
        #: lately (s; creeps up by :data:`AGE_FLOOR_CREEP` of a period per sample), the latest
        #: sample's age beyond it (s), whether this period's sample is stale, how many were, and
        #: the largest excess age seen (diagnostics)
        self._age_floor: float | None = None
        self.sample_late_s = 0.0
        self._stale_sample = False
        self.stale_samples = 0
        self.sample_late_max_s = 0.0
        self._stalled = False
        #: the drive's state word (:meth:`drive_status`): None until a drive reports one (then
        #: the reports, not the loop gap, say when the drive switched itself off)
        self.drive_state: int | None = None
        self._drive_tripped = False                # the drive reported its watchdog off while armed
        #: re-armed and re-enabled after a watchdog trip, the drive not yet reporting it is back on
        #: (:meth:`_step`: the law is held at its re-arm meanwhile)
        self._drive_coming_back = False
        self._coming_back_since = 0.0
        self._reenables = 0                         # re-enables sent since the last trip
        #: after the drive went off the loop re-arms only once the valve is slow enough for a
        #: law whose observer starts at rest, or closing (:meth:`_valve_at_rest`): re-arming a
        #: valve in full swing (a starved loop tripping the drive every few periods mid-move)
        #: drove it 25 % past its demand.  "Slow enough" (:attr:`rearm_speed_rad_s`) is a valve
        #: that moves less than the holding band :data:`PARAM_SWAP_SETTLED_RAD` over the
        #: :data:`REST_WINDOW_SAMPLES` periods the re-armed observer takes to learn its speed: to
        #: that observer it is a held valve, so the take-over is bumpless.  (At 1 kHz 0.5 rad/s:
        #: a valve following any demand the suite plays -- the soak's 0.1 Hz ±20 % sine peaks at
        #: 0.13 rad/s -- re-arms at once.)  The earlier rule, "at rest" = below 0.03 rad/s either
        #: way, was below a moving demand's speed: every watchdog trip during a move (a 6-9 ms
        #: freeze of the controller's vCPU on this VM is enough) left the drive off until the
        #: spring had closed the valve -- 59 % under a 60 % demand, offline and in the soak --
        #: and then re-acquired the demand from the stop
        self._rearm_at_rest = False
        self.rearm_speed_rad_s = PARAM_SWAP_SETTLED_RAD / (REST_WINDOW_SAMPLES * self.period)
        self._recent: deque = deque(maxlen=REST_WINDOW_SAMPLES)   # (t, valve rad) of the latest samples
        self._tracking_time = 0.0                  # leaky time beyond the tracking limit, s
        self._twist_time = 0.0                     # leaky time the twist disagreed with the torque, s
        self._positions: deque = deque(maxlen=int(2.0 / self.period))
        #: start of the missing-Δp watch (s): the first step, or in real time the end of the first arm's wait
        self._t_first: float | None = None
        self._dp: float | None = None              # last valid measured Δp, kPa (None: use the fallback)
        self._dp_t: float | None = None
        self._dp_prev: tuple[float, float] | None = None   # (t, kPa) of the last finite reading
        #: start (s) of the present run of valid readings without a gap (None: no such run), whether
        #: the latched Δp warning saw an implausible reading (then only a reset clears it), and how
        #: many Δp warnings for a gap were raised since the start (/diagnostics)
        self._dp_fresh_since: float | None = None
        self._dp_implausible = False
        self.pressure_gap_episodes = 0
        self.pressure_kpa = self.ps["pressure.fallback_kpa"]   # Δp the law is scheduled for now
        self._scheduled_kpa = self.pressure_kpa                  # Δp of the reading (or fallback)
        #: static friction met at breakaways vs the Δp schedule (None: check off)
        self.friction_check = self._make_friction_check(self.ps)
        #: Δp (kPa) the law is scheduled for from the friction met instead of the reading (None: the reading)
        self._friction_override: float | None = None
        self.last = DriverOutput(0.0, False, "waiting", None, None)
        #: drive inhibited (the managed node outside ``active``): enable false, 0 A; a reset
        #: does not lift it, only :meth:`set_inhibited` does (the node's ``activate``)
        self.inhibited = False
        #: NE107 status and duty counters (:mod:`.health`), updated every period
        self.valve_health = ValveHealth(self.ps)
        #: run-time parameter changes (:meth:`prepare_params`/:meth:`request_params`): the one
        #: waiting for its swap, and a lock held only while a change is prepared or swapped
        self._pending: ParamChange | None = None
        self._last_committed: ParamChange | None = None
        self._param_lock = threading.Lock()
        #: at least this many periods between two law replacements requested at run time:
        #: the bumpless transfer's time constant, so a transfer has mostly settled before the
        #: next starts (mode-switch spam cannot stack transients)
        self.param_swap_periods = max(int(round(PositionController.TRANSFER_TIME_S / self.period)), 1)
        #: ... and a law replacement waits for the loop to hold (:data:`PARAM_SWAP_SETTLED_RAD`,
        #: that many periods in a row) but at most this many periods
        self.param_swap_max_wait = max(int(round(PARAM_SWAP_MAX_WAIT_S / self.period)), 1)
        self._periods = 0                          # loop periods run (step calls)
        self._pending_since = 0                    # period the waiting change was first requested
        self._settled_periods = 0                  # periods in a row holding a steady demand
        self._settled_demand: float | None = None
        self._last_swap = -self.param_swap_periods
        self.law_swaps = 0                         # laws replaced at run time (diagnostics)
        #: a :class:`~.valve_tests.ValveTests` attaches itself here: while a test runs it owns the demand
        self.valve_test = None

    def __getstate__(self):
        """Copyable (``copy.deepcopy``, pickle): the parameter lock is not state."""
        state = self.__dict__.copy()
        del state["_param_lock"]
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._param_lock = threading.Lock()

    # ------------------------------------------------------------------ parameters
    def check_params(self, changes: dict) -> ParamSet:
        """The parameter set ``changes`` would give, with the law it would need built as a trial;
        raises (``ConfigError``/``ValueError``) if a value is invalid or not changeable at run
        time.  Changes nothing (the controller node's validation step)."""
        return self.prepare_params(changes).ps

    def prepare_params(self, changes: dict) -> ParamChange:
        """Validate ``changes`` and build everything they need (the new law, if the mode or a
        parameter the law in force was built from changes) without touching the running loop:
        for the parameter callback (or any thread but the loop's).  Raises
        (``ConfigError``/``ValueError``, or whatever the design code raises for a value it
        cannot use) if the set is invalid; then nothing changes.

        Changes are relative to the latest *requested* set (:meth:`request_params`) when one is
        still waiting for its swap, so requests compose and the last one wins."""
        with self._param_lock:
            base = self._pending
            base_ps = base.ps if base is not None else self.ps
            new = base_ps.replace(changes)
            fixed = [k for k in changes if not CONTROLLER_SPEC.params[k].runtime and new[k] != base_ps[k]]
            if fixed:
                raise ValueError(f"{', '.join(fixed)} cannot change at run time")
            check_tighten_only(self.startup_ps, changes)
            check_consistency(new)
            names = base.law_names if base is not None else self.controller.law_params
            if new["mode"] == base_ps["mode"] and all(new[k] == base_ps[k] for k in names):
                law = base.law if base is not None else None      # the law in force (or waiting) stays
            else:
                law = self.controller.build_law(new)
                names = law[1]
            return ParamChange(new, demand_filter_config(new), law, names, base)

    def request_params(self, change: ParamChange) -> None:
        """Queue a prepared change for the loop: :meth:`step` swaps it in at the start of a
        period (cheap: no law is built there), at most one law replacement per
        :attr:`param_swap_periods` periods; a later request replaces a waiting one (it was
        prepared on top of it, so it includes its changes: the last request wins).  A change
        prepared on another base than the one waiting now is refused (``ValueError``), unless
        that base has been swapped in meanwhile (then the change applies on top of it)."""
        with self._param_lock:
            if change.base is not self._pending:
                if change.base is None or change.base is not self._last_committed or self._pending is not None:
                    raise ValueError("parameter change prepared on a stale base; prepare it again")
                if change.law is change.base.law:          # that law is in force already: keep it
                    change = replace(change, law=None, base=None)
            if self._pending is None:             # spam cannot postpone the swap: the first request's time
                self._pending_since = self._periods
            # queued without its base (task h37b): the change it was prepared on is replaced (its values are in this
            # one) -- kept, a run of requests while the loop does not swap (a stalled or not yet running loop) held
            # every replaced change and its law alive, a chain as long as the requests
            self._pending = replace(change, base=None) if change.base is not None else change

    def set_params(self, changes: dict) -> None:
        """Apply run-time parameter changes at once, atomically: everything is validated and
        the new law (if one is needed) built first (:meth:`prepare_params`); only then is
        anything swapped.  On error nothing changes.  Every run-time parameter takes effect:
        the driver reads its own (demand, fault, pressure) from the new set every period, the
        current limits are reconfigured, and the law is rebuilt -- bumplessly, from the last
        applied torque -- whenever a parameter it was built from (or the mode) changes.  (The
        offline simulator's events; the node queues changes for the loop with
        :meth:`prepare_params` + :meth:`request_params` instead.)"""
        self.request_params(self.prepare_params(changes))
        self._commit_params(force=True)

    @property
    def waiting_law(self):
        """The law a waiting change will install at its swap (None: no change waits, or it keeps the law in force)."""
        change = self._pending
        return None if change is None or change.law is None else change.law[0]

    @property
    def params_pending(self) -> bool:
        """A requested change is waiting for its swap."""
        return self._pending is not None

    def _commit_params(self, force: bool = False) -> bool:
        """Swap a waiting change in (loop thread, start of a period): a few assignments and the
        new law's bumpless reset; a law replacement waits until :attr:`param_swap_periods`
        periods have passed since the last one (``force``: the synchronous :meth:`set_params`).
        Never blocks: while another thread is preparing a change the swap waits a period."""
        if self._pending is None or not self._param_lock.acquire(blocking=False):
            return False
        try:
            change = self._pending
            if change is None:
                return False
            if change.law is not None and not force and self._armed:
                if self._periods - self._last_swap < self.param_swap_periods:
                    return False
                settled = self._settled_periods >= self.param_swap_periods
                if not settled and self._periods - self._pending_since < self.param_swap_max_wait:
                    return False                  # mid-move: wait for the hold (or the longest wait)
            self._pending, self._last_committed = None, change
            self.ps = change.ps
            self.demand_filter.cfg = change.demand_cfg
            self.valve_health.configure(change.ps)
            self.controller.reconfigure(change.ps, self._meas if self._armed else None, self.pressure_kpa,
                                        change.law)
            if change.law is not None:
                self._last_swap = self._periods
                self.law_swaps += 1
            return True
        finally:
            self._param_lock.release()

    # ------------------------------------------------------------------ inputs
    @_guarded
    def demand_percent(self, t: float, value: float) -> None:
        if self.ps["demand_source"] == "percent":
            self._accept_demand(t, value, *self._check_percent(value))

    @_guarded
    def demand_ma(self, t: float, value: float) -> None:
        if self.ps["demand_source"] == "ma":
            self._accept_demand(t, value, *self._check_ma(value))

    @staticmethod
    def _check_percent(value):
        if not isinstance(value, (int, float)) or not math.isfinite(value):
            return None, f"demand {value!r} is not a finite number"
        if value < -PERCENT_FAIL_MARGIN or value > 100.0 + PERCENT_FAIL_MARGIN:
            return None, f"demand {value:g} % is far outside 0..100 %"
        warn = None if 0.0 <= value <= 100.0 else f"demand {value:g} % clamped to 0..100 %"
        return min(max(value, 0.0), 100.0), warn

    @staticmethod
    def _check_ma(value):
        if not isinstance(value, (int, float)) or not math.isfinite(value):
            return None, f"demand current {value!r} is not a finite number"
        if value <= NE43_FAIL_LOW_MA or value >= NE43_FAIL_HIGH_MA:
            return None, f"demand current {value:.2f} mA signals a failure (NAMUR NE43: <= 3.6 or >= 21.0 mA)"
        warn = None
        if not NE43_USABLE_LOW_MA <= value <= NE43_USABLE_HIGH_MA:
            warn = f"demand current {value:.2f} mA outside the NE43 usable range 3.8..20.5 mA"
        return min(max(ma_to_percent(value), 0.0), 100.0), warn

    def _accept_demand(self, t, raw, pct, note):
        if pct is None:
            self._demand_bad, self._bad_input_t = note, t
            self._latch(DEMAND_SIGNAL, note)
            return
        self._demand_bad = None
        if note:
            self.warnings["demand_range"] = note
        else:
            self.warnings.pop("demand_range", None)
        self._demand_pct, self._demand_t = pct, t
        self._demand_cond_rad = self.demand_filter.update(t, pct / 100.0 * self.stroke)

    @_guarded
    def resolver(self, t: float, motor_rad: float, valve_rad: float, now: float | None = None) -> None:
        """A resolver sample taken at ``t`` (its stamp, s), received at ``now`` on the loop's
        clock (None: not checked; the offline simulator's samples are its own); implausible
        samples latch a fault and are dropped.  A stamp more than
        ``faults.stamp_future_tolerance_s`` after ``now`` is implausible: trusted, it would
        become the reference every genuine sample is judged by."""
        if (isinstance(t, (int, float)) and now is not None
                and not t - now <= self.ps["faults.stamp_future_tolerance_s"]):
            why = f"resolver sample stamped {t - now:+.3f} s ahead of the loop's clock"
        elif (isinstance(t, (int, float)) and now is not None and self._meas_t is not None
              and t < self._meas_t and now - t > self.ps["faults.resolver_timeout_s"]):
            # one drive's samples arrive in order (DDS keeps a writer's order, the stamps
            # increase): one older than the previous and than the resolver timeout is a second
            # source on the topic, e.g. a bag replayed into a live valve.  Trusted, it became the
            # measurement and the next period latched "no resolver sample for 3600000 ms" while
            # samples kept arriving (h24u).  (A system clock stepped back moves the stamps and
            # the loop's clock together: now - t stays small, not flagged.)
            why = (f"resolver sample stamped {self._meas_t - t:.3f} s before the previous one and "
                   f"{now - t:.3f} s before the loop's clock: a second source on the resolver topic "
                   "(a replayed bag?)")
        else:
            why = self._implausible(t, motor_rad, valve_rad)
        if why:
            self._meas_bad, self._bad_input_t = why, (self._t if now is None else now)
            self._latch(RESOLVER_IMPLAUSIBLE, why)
            return
        self._meas_bad = None
        self._meas = Measurement(float(motor_rad), float(valve_rad))
        self._meas_t = t
        self._sample_age = None if now is None else now - t
        self._recent.append((t, float(valve_rad)))

    def loop_timing(self, stamp: float, now: float) -> None:
        """Real time only (the node calls it for each resolver sample it runs a period on;
        offline and in lockstep the loop's timing is exact by construction): the sample
        stamped ``stamp`` (s, the drive's clock) arrived at ``now`` (s, the loop's clock).  The
        loop is *late* when a sample arrives, or is stamped, more than ``fine.late_loop_s``
        beyond one period after the previous one: intervals, not the age ``now - stamp``, so
        an offset between the two clocks does not count.  A late loop stretches whatever
        current it last commanded; the fine stage's pulses are timed open-loop torques (a
        29 A kick held ~7 ms instead of ~4 ms moved a held valve 6.5e-2 rad, beside two CPU
        hogs), so the stage stands aside for ``fine.late_loop_holdoff_s`` after
        (:meth:`_stage_aside`)."""
        # the sample's age beyond the loop's usual latency: age minus the least age seen lately,
        # so an offset between the drive's clock and the loop's does not count (the floor
        # creeps up slowly, so a clock step is absorbed within seconds)
        age = now - stamp
        floor = self._age_floor
        floor = age if floor is None else min(age, floor + AGE_FLOOR_CREEP * self.period)
        self._age_floor = floor
        self.sample_late_s = age - floor
        self.sample_late_max_s = max(self.sample_late_max_s, self.sample_late_s)
        stale = self.ps["faults.stale_sample_periods"]
        self._stale_sample = stale > 0.0 and self.sample_late_s > stale * self.period
        prev, self._timing_prev = self._timing_prev, (stamp, now)
        self._real_time = True
        gap = self.ps["faults.resolver_timeout_s"]
        if (self._steady_since is None or prev is None or stamp - prev[0] > gap or now - prev[1] > gap):
            self._steady_since = stamp      # faults.arm_steady_s: a new on-time run starts here
        if prev is None:
            return
        late = self.ps["fine.late_loop_s"] + self.period
        stamped, arrived = stamp - prev[0], now - prev[1]
        if stamped > late:
            self._loop_late(now, f"{stamped * 1e3:.1f} ms between resolver samples")
        elif arrived > late:
            self._loop_late(now, f"a resolver sample {arrived * 1e3:.1f} ms after the previous one")

    def _settling(self) -> bool:
        """The first arm since construction or activation still waits for a steady resolver
        stream (``faults.arm_steady_s`` > 0, real time: offline and in lockstep samples come every
        period by construction and the driver arms on the first, as before).  Meanwhile a resolver
        silence is no fault: the drive is off, the spring holds the valve; the on-time run starts
        over."""
        return self._real_time and self._awaiting_steady and self.ps["faults.arm_steady_s"] > 0.0

    def _loop_late(self, t: float, why: str) -> None:
        if self._late_t is None or t - self._late_t > self.ps["fine.late_loop_holdoff_first_s"]:
            self._late_episodes.append(t)           # a new episode (a late period after the short hold-off)
        self._late_t, self._late_why = t, why
        self.late_loop_events += 1

    def _late_recently(self, t: float) -> bool:
        """The loop was late within the hold-off before ``t``: ``fine.late_loop_holdoff_s``, or
        ``fine.late_loop_holdoff_first_s`` (shorter) after a late episode with none in the
        ``fine.late_loop_holdoff_s`` before it.  Why two (docs §113): an isolated late loop
        costs the stage a try; keeping it aside 2 s leaves the plateau to the main law, whose
        steps overshoot (start-up profile, late answers emulated: 23 of 192 steps over 10 % at
        2 s, 6 at 0.2 s); a loop that keeps being late stops every try the stage re-engages for
        (late every 0.25 s: valves thrown up to 1.4e-2 rad at 0.2 s, 2.7e-3 at 2 s)."""
        if self._late_t is None:
            return False
        hold = self.ps["fine.late_loop_holdoff_s"]
        earlier = sum(1 for e in list(self._late_episodes)[:-1] if self._late_t - e <= hold)
        if earlier < self.ps["fine.late_loop_repeats"]:
            hold = min(hold, self.ps["fine.late_loop_holdoff_first_s"])
        return t - self._late_t < hold

    def _stage_aside(self, t: float) -> str:
        """Why the fine stage stands aside this period ('' = it may act): a valve test is
        measuring, or the loop was late within ``fine.late_loop_holdoff_s``."""
        if self.valve_test is not None and self.valve_test.running is not None:
            return "valve test"
        if self._late_recently(t):
            return "late loop: " + self._late_why
        return ""

    def _implausible(self, t, motor, valve) -> str | None:
        if not (isinstance(motor, (int, float)) and math.isfinite(motor)
                and isinstance(valve, (int, float)) and math.isfinite(valve)):
            return f"resolver reading not finite (motor {motor!r}, valve {valve!r})"
        margin = 0.05
        if not -margin <= valve <= self.stroke + margin:
            return f"valve angle {valve:.4f} rad outside the stroke 0..{self.stroke:.4f} rad"
        if abs(motor / self.n - valve) > self._twist_constants()[4]:
            return (f"motor resolver ({motor / self.n:.4f} rad at the valve) and valve resolver ({valve:.4f} rad) "
                    f"disagree beyond any coupling twist")
        if self._meas is not None and self._meas_t is not None:
            periods = max((t - self._meas_t) / self.period, 1.0)
            jump = abs(valve - self._meas.valve_rad)
            if jump > self.ps["faults.resolver_max_step_rad"] * periods:
                return f"valve angle jumped {jump:.4f} rad in {max(t - self._meas_t, 0.0) * 1e3:.1f} ms"
        return None

    def twist_limits(self, current_a: float) -> tuple[float, float, float]:
        """(low, high, largest |twist|) of the coupling twist θm/N − θv, rad, that a q-current
        ``current_a`` (A) applied at the motor can explain at rest: the valve-side torque
        N·Kt·i over a coupling between ``faults.coupling_stiffness_min_fraction`` times the
        nominal stiffness and the nominal one, widened by
        ``faults.resolver_disagreement_margin_rad``.  The third value is the bound for any
        current up to the peak: an instantaneous implausibility limit."""
        n_kt, k, fk, margin, peak = self._twist_constants()
        torque = n_kt * current_a
        a, b = torque / k, torque / fk
        return min(a, b) - margin, max(a, b) + margin, peak

    def _twist_constants(self) -> tuple[float, float, float, float, float]:
        """``(N Kt, K, f K, margin, peak bound)`` of :meth:`twist_limits` for the present
        parameters and model, kept per parameter set (the loop reads them twice a period; the
        same expressions in the same order, so the same values as computing them each time)."""
        ps, m = self.ps, self.controller.model
        kept = self._twist_kept
        if kept is not None and kept[0] is ps and kept[1] is m:
            return kept[2]
        k = m.coupling_stiffness_nm_per_rad
        f = ps["faults.coupling_stiffness_min_fraction"]
        margin = ps["faults.resolver_disagreement_margin_rad"]
        n_kt = self.n * m.torque_constant_nm_per_a
        fk = f * k
        values = (n_kt, k, fk, margin, n_kt * ps["limits.peak_current_a"] / fk + margin)
        self._twist_kept = (ps, m, values)
        return values

    @_guarded
    def pressure_differential(self, t: float, kpa: float) -> None:
        """A measured pressure differential across the valve, kPa, read at ``t``.  Implausible
        readings latch the :data:`PRESSURE_INPUT` warning and put the schedule on the fallback
        until a plausible one arrives; plausible ones are clamped to 0..pressure max."""
        ps = self.ps
        why = None
        if isinstance(kpa, bool) or not isinstance(kpa, (int, float)) or not math.isfinite(kpa):
            why = f"pressure differential reading {kpa!r} is not a finite number"
        else:
            kpa = float(kpa)
            margin = ps["pressure.range_margin_kpa"]
            if not -margin <= kpa <= PRESSURE_MAX_KPA + margin:
                why = f"pressure differential {kpa:.0f} kPa outside 0..{PRESSURE_MAX_KPA:.0f} kPa"
            elif self._dp_prev is not None:
                t0, kpa0 = self._dp_prev
                dt = max(t - t0, self.period)
                if abs(kpa - kpa0) > ps["pressure.max_rate_kpa_s"] * dt:
                    why = (f"pressure differential changed {kpa - kpa0:+.0f} kPa in {max(t - t0, 0.0) * 1e3:.1f} ms "
                           f"(faster than {ps['pressure.max_rate_kpa_s']:g} kPa/s)")
            self._dp_prev = (t, kpa)
        if why:
            self._dp = self._dp_fresh_since = None
            self._warn_pressure(why, gap=False)
            return
        if self._dp is None:
            self._dp_fresh_since = t
        self._dp, self._dp_t = min(max(kpa, 0.0), PRESSURE_MAX_KPA), t

    def _make_friction_check(self, ps: ParamSet) -> FrictionCheck | None:
        if not ps["pressure.friction_check"]:
            return None
        return FrictionCheck(self.controller.model, self.period, RESOLVER_COUNT_RAD, self._friction_scale_range(ps),
                             ps["pressure.friction_check_margin"])

    @staticmethod
    def _friction_scale_range(ps: ParamSet) -> tuple[float, float]:
        return ps["pressure.friction_scale_min"], ps["pressure.friction_scale_max"]

    def _friction_checked(self, scheduled_kpa: float) -> float:
        """The Δp for the law after the cross-check with the friction met this period (kPa):
        ``scheduled_kpa`` while the friction met allows it, else the Δp the friction met says
        (and the :data:`PRESSURE_FRICTION` warning latched)."""
        if not self.ps["pressure.friction_check"]:              # run time: read every period
            self.friction_check = None
            if self._friction_override is not None:
                self._friction_override = None
                self.controller.law.friction_rescheduled(scheduled_kpa)
            return scheduled_kpa
        check = self.friction_check
        if check is None:
            check = self.friction_check = self._make_friction_check(self.ps)
        check.scale_range = self._friction_scale_range(self.ps)    # what was met so far stays
        check.margin = self.ps["pressure.friction_check_margin"]
        check.update(self._meas, self.controller.last_torque, scheduled_kpa)
        kpa = check.schedule(scheduled_kpa)
        override = check.override_kpa
        if override != self._friction_override:
            self._friction_override = override
            self.controller.law.friction_rescheduled(kpa)
        if override is None:
            return scheduled_kpa
        source = "measured" if self._dp is not None else "fallback"
        lo, hi = check.scale_range
        self.warnings.setdefault(PRESSURE_FRICTION, (
            f"{source} pressure differential {scheduled_kpa:.0f} kPa implausible: the valve broke away at "
            f"{check.met_static_nm:.2f} N*m static friction, {check.ratio(scheduled_kpa):.2f} x what that Δp "
            f"predicts (x{lo:g}..{hi:g} allowed); friction scheduled for {kpa:.0f} kPa from the friction met"))
        return kpa

    def _warn_pressure(self, why: str, gap: bool) -> None:
        """Raise the :data:`PRESSURE_INPUT` warning for a gap in the readings (``gap``: latched, or with
        ``pressure.recover_s`` > 0 cleared after that long of timely readings) or an implausible reading
        (latched until :meth:`reset`)."""
        if PRESSURE_INPUT not in self.warnings:
            self.warnings[PRESSURE_INPUT] = why + (f"; friction scheduled for the fallback "
                                                   f"{self.ps['pressure.fallback_kpa']:g} kPa")
            if gap:
                self.pressure_gap_episodes += 1
        self._dp_implausible |= not gap

    def _scheduled_pressure(self, t: float) -> float:
        """Δp for the law this period: the measured one while valid, else the fallback."""
        ps = self.ps
        timeout = ps["pressure.timeout_s"]
        if self._settling():
            # the first arm still waits for a steady resolver stream (drive off): a start-up stall silences the
            # transducer's stream too; the watch for a missing Δp starts when the wait ends
            self._t_first = t
        elif self._dp is not None and t - self._dp_t > timeout:
            self._dp = self._dp_fresh_since = None
            self._warn_pressure(f"no pressure differential reading for {(t - self._dp_t) * 1e3:.0f} ms", gap=True)
        elif self._dp_t is None and t - self._t_first > timeout:
            self._warn_pressure("no pressure differential reading received", gap=True)
        elif (self._dp_fresh_since is not None and not self._dp_implausible and PRESSURE_INPUT in self.warnings
              and 0.0 < ps["pressure.recover_s"] <= t - self._dp_fresh_since):
            del self.warnings[PRESSURE_INPUT]   # a gap, and timely readings since: the transport recovered
        return ps["pressure.fallback_kpa"] if self._dp is None else self._dp

    @_guarded
    def drive_status(self, t: float, state: int) -> None:
        """The drive's state word at ``t`` (a ``DRIVE_STATE_*`` code of the contract, like a CiA
        402 status word).  Off by its own command watchdog while the loop runs the drive
        (:data:`~..common.contract.DRIVE_STATE_WATCHDOG`): the law's state is stale (its
        observer assumed the commanded current acted), so the next period re-arms from the
        measurement with the torque that holds the valve there and re-enables the drive (a
        valve opening fast is left to slow down first: :meth:`_valve_at_rest`); the drive stays
        off until then.
        An internal drive fault latches :data:`DRIVE_FAULT`.  Other codes are the echo of the
        loop's own enable.  Once a drive has reported, the loop gap rule
        (``faults.drive_command_timeout_s``) is not used."""
        if state not in DRIVE_STATE_NAMES:
            self._latch(DRIVE_FAULT, f"drive reports an unknown state {state!r}")
            return
        if state == DRIVE_STATE_ENABLED and self.drive_state != DRIVE_STATE_ENABLED:
            self._enabled_since = t
        self.drive_state = state
        if state == DRIVE_STATE_WATCHDOG and self._armed:
            self._drive_tripped = True
        elif state == DRIVE_STATE_FAULT and self._armed:
            self._latch(DRIVE_FAULT, "the drive reports an internal fault (drive off); reset re-enables it")

    @_guarded
    def measured_current(self, t: float, amps: float) -> None:
        """Optional drive telemetry: a current beyond the hardware rating is an over-current."""
        limit = 1.1 * self.ps["limits.peak_current_a"]
        if not math.isfinite(amps) or abs(amps) > limit:
            self._latch(OVERCURRENT, f"measured motor current {amps!r} A beyond {limit:.1f} A")

    def start_from_torque(self, torque_nm: float) -> None:
        """Arm (first time) with the loop continuing from ``torque_nm`` instead of zero: for a
        simulation that starts with the valve already held by the drive."""
        self._arm_torque = torque_nm

    def set_inhibited(self, inhibited: bool) -> None:
        """Inhibit the drive (True: every period commands enable false and 0 A, so the return
        spring closes the valve) or allow it again (it re-arms from the measurement with zero
        torque at the next period without a fault).  The managed node's (de)activate."""
        if inhibited:
            self._armed = False
        elif self.inhibited:
            self._awaiting_steady = True       # activated: the first arm proves the stream again
        self.inhibited = bool(inhibited)

    def trip(self, reason: str = "trip requested") -> None:
        self._latch(TRIPPED, reason)

    def reset(self) -> tuple[bool, str]:
        """Clear latched faults and re-arm, unless a fault cause is still present."""
        if self._demand_bad:
            return False, f"cannot reset: {self._demand_bad}"
        if self._meas_bad:
            return False, f"cannot reset: {self._meas_bad}"
        ps, t = self.ps, self._t
        if t is not None and self._bad_input_t is not None and t - self._bad_input_t < RESET_QUIET_S:
            return False, (f"cannot reset: an implausible input {t - self._bad_input_t:.2f} s ago (inputs must be "
                           f"plausible for {RESET_QUIET_S:g} s)")
        if t is not None:       # a cause that is still present would latch again at once
            if ps["demand_timeout_action"] == "trip" and (
                    self._demand_t is None or t - self._demand_t > ps["demand_timeout_s"]):
                return False, "cannot reset: no valid demand"
            if self._meas_t is None or t - self._meas_t > ps["faults.resolver_timeout_s"]:
                return False, "cannot reset: no resolver samples"
        cleared = sorted(self.faults) + sorted(k for k in self.warnings
                                               if k in (DEMAND_STALE, PRESSURE_INPUT, PRESSURE_FRICTION))
        self.faults.clear()
        self.warnings.pop(DEMAND_STALE, None)
        self.warnings.pop(PRESSURE_INPUT, None)     # latches again next period if still invalid
        self._dp_implausible = False
        self.warnings.pop(PRESSURE_FRICTION, None)  # latches again after two breakaways if still wrong
        if self.friction_check is not None:
            self.friction_check.reset()
        self._tracking_time = self._twist_time = 0.0
        self.controller.reset_limits()
        self.controller.reset_learning()        # nothing learned before the fault outlives it
        return True, ("cleared: " + ", ".join(cleared)) if cleared else "nothing to clear"

    def _latch(self, code: str, message: str) -> None:
        if code not in self.faults:
            self.faults[code] = message

    def internal_fault(self, where: str, exc: BaseException | str) -> None:
        """Latch the :data:`INTERNAL` fault for an exception (or a message) raised in ``where``;
        the next :meth:`step` disables the drive.  Also for the node's own code around the
        driver (publishing, parameters)."""
        what = exc if isinstance(exc, str) else f"{type(exc).__name__}: {exc}"
        self._armed = False
        self._latch(INTERNAL, f"internal error in {where}: {what}")

    def _fail_safe_output(self, position_pct) -> DriverOutput:
        self._armed = False
        self.last = DriverOutput(0.0, False, "fault", self._demand_pct, position_pct,
                                 dict(self.faults), dict(self.warnings))
        return self.last

    # ------------------------------------------------------------------ loop
    def after_period(self) -> bool:
        """Work the law left for after this period's command (the fine stage's apex choice of a try an observe's
        verdict started, ``fine.apex_choice_after_command``): the ROS node calls it once the command is published,
        off the sample -> command path; not calling it is the same (the next :meth:`step` does it first).  Never
        raises (an exception latches :data:`INTERNAL`, as in :meth:`step`).  Returns whether there was any."""
        try:
            return self.controller.after_period()
        except Exception as exc:           # noqa: BLE001 - see the module docstring
            self.internal_fault("after_period", exc)
            return False

    def step(self, t: float) -> DriverOutput:
        """One loop period at time ``t`` (s): the command and drive enable.  Never raises: an
        exception inside latches :data:`INTERNAL` and returns the fail-safe output."""
        try:
            t_prev = self._t
            out = self._step(t)
            if not math.isfinite(out.current_a):
                raise ArithmeticError(f"non-finite current command {out.current_a!r} A")
            if self._meas is not None:
                # counters and NE107 inputs; dt bounded so a stalled loop does not count as time
                dt = min(max(t - t_prev, 0.0), STALL_REARM_PERIODS * self.period) if t_prev is not None else 0.0
                self.valve_health.update(t, dt, self._meas.valve_rad, self.demand_rad(),
                                         None if self._dp is None else self.pressure_kpa, out.enable,
                                         self.controller.law.friction_trend)
            if self.valve_test is not None:
                self.valve_test.observe(t, out)       # records; aborts on faults (never raises)
                self.valve_test.report_health(self.valve_health)
            return out
        except Exception as exc:           # noqa: BLE001 - see the module docstring
            self.internal_fault("step", exc)
            position = None if self._meas is None else 100.0 * self._meas.valve_rad / self.stroke
            return self._fail_safe_output(position)

    def _step(self, t: float) -> DriverOutput:
        self._periods += 1
        self._commit_params()                     # a waiting parameter change: swap at the boundary
        ps = self.ps
        reenable = False
        if self._armed and self._drive_went_off(t, ps):
            self._armed = False                   # re-arm below from the measurement, holding torque
            self._stalled = reenable = self._rearm_at_rest = True
            self._drive_coming_back = self.drive_state is not None
            self._coming_back_since = t
            self._reenables = 1
            self.stall_rearms += 1
            self._loop_late(t, "the drive switched itself off (its command watchdog)")
            # the twist check compared the coupling with a current the drive did not apply
            # while it was off: that time is no evidence of a failed resolver
            self._twist_time = 0.0
        self._drive_tripped = False
        self._t = t
        if self._t_first is None:
            self._t_first = t
        pressure = self._scheduled_kpa = self.pressure_kpa = self._scheduled_pressure(t)
        # --- staleness checks
        if self._meas_t is not None and t - self._meas_t > ps["faults.resolver_timeout_s"]:
            if self._settling():
                self._steady_since = None   # not armed yet: the stream's on-time run starts over
            else:
                self._latch(RESOLVER_STALE, f"no resolver sample for {(t - self._meas_t) * 1e3:.0f} ms")
        holding = False
        if self._demand_t is not None and t - self._demand_t > ps["demand_timeout_s"]:
            msg = f"no valid demand for {t - self._demand_t:.2f} s"
            if ps["demand_timeout_action"] == "trip":
                self._latch(DEMAND_STALE, msg)
            else:
                self.warnings.setdefault(DEMAND_STALE, msg + " (holding the last demand)")
                holding = True
        position_pct = None if self._meas is None else 100.0 * self._meas.valve_rad / self.stroke
        if self.faults or self._meas is None or self._demand_pct is None or self.inhibited:
            self._armed = False
            state = "fault" if self.faults else "inactive" if self.inhibited else "waiting"
            self.last = DriverOutput(0.0, False, state, self._demand_pct, position_pct,
                                     dict(self.faults), dict(self.warnings))
            return self.last
        if not self._armed and self._settling() and (
                self._steady_since is None or self._meas_t - self._steady_since < ps["faults.arm_steady_s"]):
            # the first arm (faults.arm_steady_s): drive off until the resolver stream has run on time
            run = 0.0 if self._steady_since is None else self._meas_t - self._steady_since
            why = (f"arming once the resolver stream has run on time for {ps['faults.arm_steady_s']:g} s "
                   f"({run:.3f} s so far)")
            self.last = DriverOutput(0.0, False, "waiting", self._demand_pct, position_pct, {},
                                     {**self.warnings, RESOLVER_SETTLING: why})
            return self.last
        demand_rad = self.demand_rad()
        if self.valve_test is not None:           # a running valve test owns the demand
            demand_rad = self.valve_test.demand(t, demand_rad)
        # a valve test measures friction from the drive torque, a late loop stretches a pulse:
        # the fine stage stands aside (the other laws ignore it)
        self.controller.law.stand_aside(bool(self._stage_aside(t)))
        if self._late_recently(t):
            self.controller.law.loop_late()       # nothing the valve does now is learned as its own (§111.5b)
        if not self._armed and self._rearm_at_rest and not self._valve_at_rest():
            # the drive is off (it switched itself off): wait, drive off, until the valve is slow
            self.last = DriverOutput(0.0, False, "waiting", self._demand_pct, position_pct, {}, dict(self.warnings))
            return self.last
        self._rearm_at_rest = False
        if self._drive_coming_back:
            if self.drive_state == DRIVE_STATE_WATCHDOG and self._armed:
                # re-enabled, but the drive still reports itself off (it has not taken the
                # re-enable yet): it applies nothing, so a law running on would wind up against
                # a valve the spring is moving -- in the soak a plant that took the re-enable
                # 44 ms late met a law asking 37 A, and the valve shot from the stop to 4.4 %
                # past its demand.  Held at its re-arm instead: again from the measurement,
                # commanding the torque that holds the valve where it is, until the drive
                # reports it is on (the supervision checks compare with an applied current:
                # not run meanwhile).  No report within DRIVE_BACK_TIMEOUT_S: the re-enable
                # is sent again, at most DRIVE_BACK_ATTEMPTS times, then a drive fault
                again = t - self._coming_back_since > DRIVE_BACK_TIMEOUT_S
                if again and self._reenables >= DRIVE_BACK_ATTEMPTS:
                    self._latch(DRIVE_FAULT, f"the drive still reports its command watchdog trip after {self._reenables} "
                                             f"re-enables {DRIVE_BACK_TIMEOUT_S * 1e3:.0f} ms apart")
                    return self._fail_safe_output(position_pct)
                if again:
                    self._coming_back_since = t
                    self._reenables += 1
                self.controller.reset(self._meas, pressure, self._holding_torque(pressure), keep_limits=True)
                self.last = DriverOutput(self.controller.last_current, True, "running", self._demand_pct,
                                         position_pct, {}, dict(self.warnings), reenable=again)
                return self.last
            elif self.drive_state != DRIVE_STATE_WATCHDOG:
                self._drive_coming_back = False
        if not self._armed:
            if self._stalled:
                # after the drive switched itself off: from the torque that holds the valve where
                # it is now (spring and Δp load at the measured angle, the model's equilibrium),
                # not from the old request (resuming it drove the valve on: 49 % for a 40 % step)
                # nor from zero torque (the law then had to wind its integrator up to the holding
                # torque first while the spring pulled the valve down: 58.6 -> 50.8 % for a 58 %
                # demand after a 2 ms drive-off, offline).  The I2t budget spent is kept, so a
                # stall cannot refill it
                self._arm_torque = self._holding_torque(pressure)
            self.controller.reset(self._meas, pressure, self._arm_torque, keep_limits=self._stalled)
            self._stalled = False
            self._arm_torque = 0.0        # re-arming after a fault starts from zero torque
            self._armed = True
            self._awaiting_steady = False
            if self.friction_check is not None:
                self.friction_check.reset()   # the valve moved with the drive off: not friction
            self._friction_override = None   # the law was reset for the reading's Δp
        if self._stale_sample:
            # a sample that reached the loop late (faults.stale_sample_periods): a law period
            # computed from it is a command for a valve that has moved on, and a starved loop
            # holds it until its next answer (offline, answers every 3-4 ms to samples 2-3 ms old:
            # 50-56 % for a 45.8 -> 47.5 % step, section 54).  This period commands the torque
            # that holds the valve where it was measured (spring and Δp load, no friction): it
            # injects nothing, friction brakes a moving valve.  The law does not run on the
            # stale sample and is not re-armed: its next period, on a fresh sample, continues
            # (re-arming at every stale sample kept a loop with a third of its samples stale
            # from ever breaking the valve loose: 42.6 % after 1.5 s for 47.5 %, offline)
            self._stale_sample = False
            self.stale_samples += 1
            self._loop_late(t, f"a resolver sample {self.sample_late_s * 1e3:.1f} ms late")
            self.last = DriverOutput(self._holding_torque(pressure) / self.controller.model.torque_constant_nm_per_a,
                                     True, "running", self._demand_pct, position_pct, {}, dict(self.warnings))
            return self.last
        pressure = self.pressure_kpa = self._friction_checked(pressure)
        applied = self.controller.last_current     # what the drive applied since the sample before
        current = self.controller.update(t, demand_rad, self._meas, pressure)
        # --- faults that the loop itself detects; leaky counts: a dip below the limit takes time
        # off, it does not restart the count (a failed sensor swinging the valve dips often)
        dt = self.period
        beyond = abs(demand_rad - self._meas.valve_rad) > ps["faults.tracking_error_rad"]
        self._tracking_time = max(self._tracking_time + (dt if beyond else -dt), 0.0)
        if self._tracking_time > ps["faults.tracking_error_time_s"]:
            self._latch(TRACKING, f"tracking error above {ps['faults.tracking_error_rad']:g} rad "
                                  f"for {self._tracking_time:.2f} s (net)")
        low, high, _ = self.twist_limits(applied)
        twist = self._meas.motor_rad / self.n - self._meas.valve_rad
        off = not low <= twist <= high
        if self.drive_state is None or self.drive_state == DRIVE_STATE_ENABLED:
            self._twist_time = max(self._twist_time + (dt if off else -dt), 0.0)
        # else: the drive reports itself off, so the commanded current is not the applied one
        # and the twist is no evidence about the resolvers (the count is held)
        if self._twist_time > ps["faults.resolver_disagreement_time_s"]:
            self._latch(RESOLVER_IMPLAUSIBLE, f"motor/valve resolver disagreement {twist:.4f} rad not explained by "
                                              f"the applied {applied:.1f} A ({low:.4f}..{high:.4f} rad) for "
                                              f"{self._twist_time:.2f} s (net): a resolver has failed"
                                              f" [{self._twist_context(t)}]")
        if self.controller.overload_time > ps["faults.i2t_fault_time_s"]:
            self._latch(OVERCURRENT, f"I2t budget exhausted and more than "
                                     f"{ps['limits.continuous_current_a']:g} A requested for "
                                     f"{self.controller.overload_time:.2f} s (jam or overload)")
        if self.faults:                       # latched this very period: fail safe now
            self._armed = False
            self.last = DriverOutput(0.0, False, "fault", self._demand_pct, position_pct,
                                     dict(self.faults), dict(self.warnings))
            return self.last
        self._positions.append(self._meas.valve_rad)
        steady = self._settled_demand is not None and abs(demand_rad - self._settled_demand) <= RESOLVER_COUNT_RAD
        holding_now = steady and abs(demand_rad - self._meas.valve_rad) <= PARAM_SWAP_SETTLED_RAD
        self._settled_periods = self._settled_periods + 1 if holding_now else 0
        self._settled_demand = demand_rad
        self.last = DriverOutput(current, True, "holding" if holding else "running", self._demand_pct,
                                 position_pct, {}, dict(self.warnings), reenable=reenable,
                                 fallback_currents_a=self.fallback_currents())
        return self.last

    def fallback_currents(self) -> tuple[float, ...]:
        """The currents (A) the drive is to apply in the first, second, ... period in a row whose command is late
        (``DriverOutput.fallback_currents_a``, ``contract.CURRENT_FALLBACK``), ``()``: hold this period's command.  The
        law's next planned steps where its output is a timed sequence (:meth:`.laws.base.ControlLaw.fallback_torques`;
        ``fine.pulse_fallback``), within the peak current.  After :meth:`after_period` they may have changed (a
        retreat planned after the kick's command): the node publishes them again."""
        if not self.ps["fine.pulse_fallback"] or not self._armed:
            return ()
        torques = self.controller.law.fallback_torques()
        if not all(math.isfinite(x) for x in torques):
            return ()
        cap, kt = self.ps["limits.peak_current_a"], self.controller.model.torque_constant_nm_per_a
        return tuple(min(max(x / kt, -cap), cap) for x in torques)

    def _twist_context(self, t: float) -> str:
        """What the loop knew when the twist check latched (diagnostics in its message): the
        drive's reported state and since when, the sample's age, the loop's lateness, re-arms."""
        state = DRIVE_STATE_NAMES.get(self.drive_state, "unreported")
        parts = [f"drive {state}"]
        if self._enabled_since is not None:
            parts.append(f"enabled for {(t - self._enabled_since) * 1e3:.0f} ms")
        if self._sample_age is not None:
            parts.append(f"sample age {self._sample_age * 1e3:.1f} ms")
        if self._late_t is not None:
            parts.append(f"late {(t - self._late_t) * 1e3:.0f} ms ago ({self._late_why}; {self.late_loop_events} late)")
        parts.append(f"{self.stall_rearms} re-arms")
        return ", ".join(parts)

    def _valve_at_rest(self) -> bool:
        """The valve may be re-armed: over the latest :data:`REST_WINDOW_SAMPLES` resolver
        samples it moved slower than :attr:`rearm_speed_rad_s` on average (slow enough for a
        law whose observer starts at rest to take it over; the window also averages the
        resolver's one-count noise, 1e-4 rad, far below that speed), or it is closing.

        A closing valve is re-armed at any speed: with the drive off the spring closes it, so
        it comes to rest only on the closed stop -- waiting for that turned a stick-slip slip
        caught by a watchdog trip (9 rad/s for a millisecond) into a full closure at a 52 %
        demand in the soak.  Re-armed, the law brakes it and moves it back up like any step;
        the overshoot a re-armed observer that believes the valve at rest can cause is upward,
        past the demand, on a valve that was *opening* fast: that one waits."""
        if len(self._recent) < self._recent.maxlen:
            return False
        (t0, v0), (t1, v1) = self._recent[0], self._recent[-1]
        return t1 > t0 and (v1 - v0) / (t1 - t0) <= self.rearm_speed_rad_s

    def _holding_torque(self, pressure_kpa: float) -> float:
        """Motor torque (N*m) that holds the valve at its measured angle against the spring and
        the Δp load (the nominal model's equilibrium, no friction): where a re-armed law starts."""
        return self.controller.model.equilibrium(self._meas.valve_rad, pressure_kpa)[1]

    def _drive_went_off(self, t: float, ps: ParamSet) -> bool:
        """The drive switched itself off since the last period (the loop ran it): it reported
        its watchdog trip, or -- a drive that does not report its state -- the loop's gap
        exceeded the drive's command timeout ``faults.drive_command_timeout_s`` (0: none)."""
        if self.drive_state is not None:
            return self._drive_tripped
        timeout = ps["faults.drive_command_timeout_s"]
        return timeout > 0.0 and self._t is not None and t - self._t > timeout

    def demand_rad(self) -> float | None:
        """The demand the loop follows (rad): conditioned (:mod:`.demand_filter`) unless the
        mode is a ``pi`` baseline or ``demand.conditioning`` is off."""
        if self._demand_pct is None:
            return None
        if self.ps["demand.conditioning"] and self.ps["mode"] not in RAW_DEMAND_MODES and \
                self._demand_cond_rad is not None:
            return self._demand_cond_rad
        return self._demand_pct / 100.0 * self.stroke

    # ------------------------------------------------------------------ diagnostics
    def ne107(self):
        """The NAMUR NE107 status now (:class:`~.health.Ne107Status`)."""
        return self.valve_health.assess(self._t, self.faults, self.warnings)

    @property
    def last_resolver_time(self) -> float | None:
        """Time stamp (s) of the latest plausible resolver sample; None before the first."""
        return self._meas_t

    def recent_position_spread(self) -> float:
        """Half peak-to-peak of the valve angle over the last 2 s (a live limit-cycle estimate)."""
        if len(self._positions) < 2:
            return 0.0
        return 0.5 * (max(self._positions) - min(self._positions))

    def health(self) -> Health:
        """Level (0 OK, 1 WARN, 2 ERROR), a readable message and key values for /diagnostics."""
        out = self.last
        if out.faults:
            level, message = 2, "FAULT (latched; drive disabled, spring closing the valve): " + "; ".join(
                out.faults.values())
        elif out.state == "inactive":
            level, message = 1, "inactive (managed node not active): drive disabled, spring closing the valve"
        elif out.state == "waiting" and RESOLVER_SETTLING in out.warnings:
            level, message = 1, "drive off, " + out.warnings[RESOLVER_SETTLING]
        elif out.state == "waiting":
            missing = [what for what, absent in (("a valid demand", out.demand_pct is None),
                                                 ("resolver samples", out.position_pct is None)) if absent]
            level, message = 1, "waiting for " + (" and ".join(missing) or "arming")
        elif out.warnings:
            level, message = 1, "running with warnings: " + "; ".join(out.warnings.values())
        else:
            level, message = 0, f"{out.state}, mode {self.controller.mode}"
        est = self.controller.estimate()
        law = self.controller.law
        tracking = None
        if out.demand_pct is not None and out.position_pct is not None:
            tracking = (out.demand_pct - out.position_pct) / 100.0 * self.stroke
        values = {
            "state": out.state, "mode": self.controller.mode,
            "demand_pct": out.demand_pct, "position_pct": out.position_pct, "tracking_error_rad": tracking,
            "current_a": out.current_a, "limit_cycle_estimate_rad": self.recent_position_spread(),
            "friction_valve_estimate_nm": est.valve_friction_nm, "friction_motor_estimate_nm": est.motor_friction_nm,
            "friction_trend": law.friction_trend(),
            "deadband_rad": law.deadband_rad(),
            "pressure_differential_kpa": self.pressure_kpa,
            "pressure_source": ("friction_met" if self._friction_override is not None else
                                "fallback" if self._dp is None else "measured"),
            "pressure_gap_episodes": self.pressure_gap_episodes,
            "friction_met_ratio": (None if self.friction_check is None
                                   else self.friction_check.ratio(self._scheduled_kpa)),
            "i2t_budget_used": self.controller.i2t_budget_fraction,
            "stall_rearms": self.stall_rearms,
            "late_loop_events": self.late_loop_events,
            "stale_samples": self.stale_samples,
            "sample_late_max_ms": 1e3 * self.sample_late_max_s,
            "fine_stage_aside": self._stage_aside(self._t) if self._t is not None else "",
            "drive_state": "unreported" if self.drive_state is None else DRIVE_STATE_NAMES[self.drive_state],
            "law_swaps": self.law_swaps, "params_pending": self.params_pending,
            "faults": ",".join(out.faults) or "none", "warnings": ",".join(out.warnings) or "none",
        }
        values.update(self.demand_filter.state())
        values.update(self.valve_health.values(self.ne107()))
        # what the law learned about this valve (fine positioning: twists per direction/Δp band)
        for key, value in (law.learned_state() or {}).items():
            values[key] = json.dumps(value) if isinstance(value, (dict, list)) else value
        return Health(level, message, values)


@dataclass(frozen=True)
class ParamChange:
    """A validated run-time parameter change, built off the loop and waiting for its swap
    (:meth:`ValveDriver.prepare_params`)."""

    ps: ParamSet                       # the whole parameter set after the change
    demand_cfg: DemandFilterConfig     # its demand conditioning
    law: tuple | None                  # (law, names it read) to install; None: the law stays
    law_names: frozenset               # parameters the law in force after the swap was built from
    base: "ParamChange | None" = field(default=None, repr=False)   # the waiting change it builds on


#: the baselines stay honest: the existing analog driver has no demand conditioning
RAW_DEMAND_MODES = ("pi", "pi_dither")


def demand_filter_config(ps: ParamSet) -> DemandFilterConfig:
    """The demand conditioning of parameter set ``ps`` (bands in rad at the valve)."""
    return DemandFilterConfig(ps["demand.band_sigmas"], ps["demand.min_band_counts"] * RESOLVER_COUNT_RAD,
                              RESOLVER_COUNT_RAD, ps["demand.confirm_samples"], ps["demand.quiet_time_s"],
                              ps["demand.noise_time_s"], ps["demand.hold_window_s"])


@dataclass
class Health:
    level: int          # 0 OK, 1 WARN, 2 ERROR (diagnostic_msgs levels)
    message: str
    values: dict

"""Valve health (issue 12): NAMUR NE107 status, duty counters and their persistence.  ROS-free.

**NE107 status.**  :class:`ValveHealth` condenses the driver's state into one of the five
NAMUR NE107 categories, in NE107's own priority order (highest first):

=====================  ==========  ==========================================================
category               level       raised by (cause key)
=====================  ==========  ==========================================================
``failure``            ERROR (2)   any latched fault except the manual trip (``fault:<code>``)
``function_check``     WARN (1)    lifecycle not ``active`` (``lifecycle``), a valve test
                                   running (``test``: :meth:`ValveHealth.set_test_running`),
                                   the manual trip ``~/trip`` (``fault:commanded_trip``)
``out_of_specification`` WARN (1)  tracking error beyond ``health.tracking_error_rad`` for
                                   ``health.tracking_error_time_s`` (leaky, ``tracking``); any
                                   driver warning -- Δp input, demand range, stale demand held
                                   (``warning:<code>``); hunting: ``health.hunting_reversals``
                                   reversals within ``health.hunting_window_s`` at a steady
                                   demand (``hunting``)
``maintenance_required`` WARN (1)  friction trend off its learned baseline by more than
                                   ``health.friction_band`` (``friction``); breakaway torque
                                   above its baseline by ``health.breakaway_rise_nm``
                                   (``breakaway``); total travel beyond
                                   ``health.travel_limit_rad`` (``travel``); reversals beyond
                                   ``health.reversal_limit`` (``reversals``); any key raised
                                   with :meth:`ValveHealth.raise_maintenance`
``good``               OK (0)      none of the above
=====================  ==========  ==========================================================

Inputs are explicit, so other parts (the valve signature and partial-stroke tests) feed it:
:meth:`~ValveHealth.set_lifecycle_state`, :meth:`~ValveHealth.set_test_running`,
:meth:`~ValveHealth.raise_maintenance` / :meth:`~ValveHealth.clear_maintenance`,
:meth:`~ValveHealth.observe_breakaway` (a measured breakaway torque, N*m at the valve) and
:meth:`~ValveHealth.set_friction_baseline`; :meth:`~ValveHealth.update` once per loop period.

**Counters** (:class:`ValveCounters`): total travel (rad of valve), reversals and the time at
high Δp (s, Δp >= ``health.high_dp_kpa``).  Travel and reversals are counted with a
hysteresis ``health.reversal_hysteresis_rad`` so resolver noise at rest neither adds travel
without bound nor counts reversals: travel accumulates as the valve passes its latest extreme
and a reversal is a move back from that extreme by more than the hysteresis (the travel back is
then counted too).  So a trajectory 0 -> a -> b (b < a - h) counts ``a + (a - b)`` rad and one
reversal.  O(1) per period.

**Persistence** (:func:`save_state` / :func:`load_state`): one JSON file, format
``fuel_valve.learned_state`` version :data:`STATE_VERSION`, with the counters, the learned
baselines and the controller's learned fine-positioning twists (:class:`FineLearner`).  A
missing or unusable file is a clear message and a start from zero, never an exception.
"""
from __future__ import annotations

import json
import math
import os
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

FAILURE = "failure"
FUNCTION_CHECK = "function_check"
OUT_OF_SPEC = "out_of_specification"
MAINTENANCE = "maintenance_required"
GOOD = "good"
#: NE107 categories, highest priority first (NE107's default order F > C > S > M)
NE107_PRIORITY = (FAILURE, FUNCTION_CHECK, OUT_OF_SPEC, MAINTENANCE, GOOD)
#: NE107 symbol letter of each category (N: normal / good)
NE107_LETTER = {FAILURE: "F", FUNCTION_CHECK: "C", OUT_OF_SPEC: "S", MAINTENANCE: "M", GOOD: "N"}
#: diagnostic_msgs/DiagnosticStatus level of each category (0 OK, 1 WARN, 2 ERROR)
NE107_DIAGNOSTIC_LEVEL = {FAILURE: 2, FUNCTION_CHECK: 1, OUT_OF_SPEC: 1, MAINTENANCE: 1, GOOD: 0}

#: fault code of the manual trip (driver.TRIPPED): a function check, not a failure
MANUAL_TRIP = "commanded_trip"

#: the friction trend is read at most this often, s: it costs more than the rest of the
#: update together, and it is smoothed over ``health.trend_time_constant_s`` (seconds) anyway
TREND_INTERVAL_S = 0.01

STATE_FORMAT = "fuel_valve.learned_state"
STATE_VERSION = 1


@dataclass
class Ne107Status:
    category: str
    causes: dict = field(default_factory=dict)     # category -> {cause key: text}

    @property
    def level(self) -> int:
        return NE107_DIAGNOSTIC_LEVEL[self.category]

    @property
    def letter(self) -> str:
        return NE107_LETTER[self.category]

    def summary(self) -> str:
        """The causes of the reported category, e.g. ``"friction: trend 1.6 x ..."``."""
        return "; ".join(f"{k}: {v}" for k, v in self.causes.get(self.category, {}).items()) or "none"


def ne107_category(causes: dict) -> str:
    """The category to report for ``causes`` (category -> non-empty mapping): the highest in
    :data:`NE107_PRIORITY` that has a cause, else ``good``."""
    for cat in NE107_PRIORITY[:-1]:
        if causes.get(cat):
            return cat
    return GOOD


class ValveCounters:
    """Total travel (rad), reversals and time at high Δp (s); see the module docstring."""

    def __init__(self, hysteresis_rad: float, high_dp_kpa: float):
        self.hysteresis = hysteresis_rad
        self.high_dp_kpa = high_dp_kpa
        self.travel_rad = 0.0
        self.reversals = 0
        self.high_dp_s = 0.0
        self._ext: float | None = None      # latest extreme of the present direction, rad
        self._dir = 0                       # +1 opening, -1 closing, 0 not yet moved
        #: loop times of recent reversals (hunting window; not persisted)
        self.recent: deque = deque(maxlen=64)

    def update(self, t: float, valve_rad: float, dp_kpa: float | None, dt: float) -> bool:
        """One period: valve angle (rad), Δp (kPa; None: unknown) over ``dt`` s.  True when a
        reversal was counted."""
        if dp_kpa is not None and dp_kpa >= self.high_dp_kpa:
            self.high_dp_s += dt
        x = valve_rad
        if self._ext is None:
            self._ext = x
            return False
        d = x - self._ext
        if self._dir == 0:
            if abs(d) > self.hysteresis:
                self._dir = 1 if d > 0 else -1
                self.travel_rad += abs(d)
                self._ext = x
            return False
        if d * self._dir > 0:                       # further in the present direction
            self.travel_rad += abs(d)
            self._ext = x
            return False
        if abs(d) > self.hysteresis:                # back from the extreme: a reversal
            self._dir = -self._dir
            self.travel_rad += abs(d)
            self._ext = x
            self.reversals += 1
            self.recent.append(t)
            return True
        return False

    def to_dict(self) -> dict:
        return {"travel_rad": self.travel_rad, "reversals": self.reversals, "high_dp_time_s": self.high_dp_s}

    def from_dict(self, doc: dict) -> None:
        """Counters from a saved dict (validated: finite, not negative; raises ValueError)."""
        travel, rev, high = float(doc["travel_rad"]), int(doc["reversals"]), float(doc["high_dp_time_s"])
        if not all(math.isfinite(v) and v >= 0 for v in (travel, rev, high)):
            raise ValueError(f"counters must be finite and not negative: {doc!r}")
        self.travel_rad, self.reversals, self.high_dp_s = travel, rev, high


class ValveHealth:
    """NE107 assessment and counters of one valve (see the module docstring).

    ``ps``: the controller parameter set (its ``health.*`` group)."""

    def __init__(self, ps):
        self.counters = ValveCounters(ps["health.reversal_hysteresis_rad"], ps["health.high_dp_kpa"])
        self.configure(ps)
        self.lifecycle = "active"           # the core alone (simulator) is always active
        self.test_running: str | None = None
        self.maintenance: dict[str, str] = {}       # externally raised: key -> text
        self.friction_baseline: float | None = None     # learned/nominal friction ratio
        self.breakaway_baseline_nm: float | None = None
        self.breakaway_nm: float | None = None
        self.friction_smoothed: float | None = None
        self._running_s = 0.0               # time driven with a friction trend available, s
        self._trend_t: float | None = None  # loop time the trend was last read
        self._tracking_time = 0.0
        self._demand: float | None = None
        self._demand_t: float | None = None     # loop time of the latest demand change

    def configure(self, ps) -> None:
        """Take the ``health.*`` parameters of ``ps`` (run-time changes too)."""
        self.ps = ps
        self.counters.hysteresis = ps["health.reversal_hysteresis_rad"]
        self.counters.high_dp_kpa = ps["health.high_dp_kpa"]

    # ---- explicit inputs ---------------------------------------------------------------
    def set_lifecycle_state(self, label: str) -> None:
        """The node's lifecycle state label (``unconfigured``, ``inactive``, ``active``, ...)."""
        self.lifecycle = label

    def set_test_running(self, running: bool, what: str = "valve test") -> None:
        """A valve test (signature, partial stroke) moves the valve on its own: function check."""
        self.test_running = what if running else None

    def raise_maintenance(self, key: str, text: str) -> None:
        """Raise (or update) a maintenance-required cause ``key`` until :meth:`clear_maintenance`."""
        self.maintenance[key] = text

    def clear_maintenance(self, key: str) -> None:
        self.maintenance.pop(key, None)

    def set_friction_baseline(self, ratio: float | None) -> None:
        """The valve's friction baseline, learned/nominal ratio (None: learn it again)."""
        self.friction_baseline = ratio

    def observe_breakaway(self, torque_nm: float) -> None:
        """A measured breakaway torque, N*m at the valve; the first one is the baseline."""
        if math.isfinite(torque_nm):
            self.breakaway_nm = torque_nm
            if self.breakaway_baseline_nm is None:
                self.breakaway_baseline_nm = torque_nm

    # ---- per period --------------------------------------------------------------------
    def update(self, t: float, dt: float, valve_rad: float, demand_rad: float | None, dp_kpa: float | None,
               driving: bool, friction_trend=None) -> None:
        """One loop period at ``t`` (s) lasting ``dt`` (s): counters, tracking, hunting window,
        friction trend.  ``driving``: the drive is enabled this period; ``friction_trend``: a
        callable giving learned/nominal valve friction (None: the law does not learn it), read
        at most every :data:`TREND_INTERVAL_S` while driving."""
        ps = self.ps
        self.counters.update(t, valve_rad, dp_kpa, dt)
        if demand_rad is not None and (self._demand is None
                                       or abs(demand_rad - self._demand) > self.counters.hysteresis):
            self._demand, self._demand_t = demand_rad, t
        limit = ps["health.tracking_error_time_s"]
        if driving and demand_rad is not None:
            beyond = abs(demand_rad - valve_rad) > ps["health.tracking_error_rad"]
            self._tracking_time = min(max(self._tracking_time + (dt if beyond else -dt), 0.0), 2.0 * limit)
        else:
            self._tracking_time = 0.0
        if not driving or friction_trend is None:
            self._trend_t = None
            return
        if self._trend_t is None:
            self._trend_t = t - dt
        span = t - self._trend_t
        if span < TREND_INTERVAL_S - 1e-9:
            return
        self._trend_t = t
        trend = friction_trend()
        if trend is None or not math.isfinite(trend):
            return
        tau = ps["health.trend_time_constant_s"]
        if self.friction_smoothed is None:
            self.friction_smoothed = trend
        else:
            self.friction_smoothed += min(span / tau, 1.0) * (trend - self.friction_smoothed)
        self._running_s += span
        if self.friction_baseline is None and self._running_s >= ps["health.baseline_after_s"] - 1e-9:
            self.friction_baseline = self.friction_smoothed

    def hunting(self, t: float) -> int:
        """Reversals within the hunting window since the demand last changed (0 if none)."""
        since = t - self.ps["health.hunting_window_s"]
        if self._demand_t is not None:
            since = max(since, self._demand_t)
        return sum(1 for r in self.counters.recent if r > since)

    # ---- assessment ----------------------------------------------------------------------
    def assess(self, t: float | None, faults: dict, warnings: dict) -> Ne107Status:
        """The NE107 status now: ``faults``/``warnings`` are the driver's latched ones."""
        ps = self.ps
        # every limit read up front (cheap, at the diagnostics rate): a run-time parameter that
        # nothing reads is caught by test_runtime_params
        track_time, track_rad = ps["health.tracking_error_time_s"], ps["health.tracking_error_rad"]
        hunt_n, hunt_window = ps["health.hunting_reversals"], ps["health.hunting_window_s"]
        band, rise = ps["health.friction_band"], ps["health.breakaway_rise_nm"]
        travel_limit, reversal_limit = ps["health.travel_limit_rad"], ps["health.reversal_limit"]
        causes = {cat: {} for cat in NE107_PRIORITY[:-1]}
        for code, text in faults.items():
            causes[FUNCTION_CHECK if code == MANUAL_TRIP else FAILURE][f"fault:{code}"] = text
        if self.lifecycle != "active":
            causes[FUNCTION_CHECK]["lifecycle"] = f"lifecycle state {self.lifecycle}: drive disabled"
        if self.test_running:
            causes[FUNCTION_CHECK]["test"] = f"{self.test_running} running"
        for code, text in warnings.items():
            causes[OUT_OF_SPEC][f"warning:{code}"] = text
        if self._tracking_time >= track_time:
            causes[OUT_OF_SPEC]["tracking"] = f"tracking error above {track_rad:g} rad for {track_time:g} s (net)"
        n = self.hunting(t) if t is not None else 0
        if n >= hunt_n:
            causes[OUT_OF_SPEC]["hunting"] = f"{n} reversals within {hunt_window:g} s at a steady demand"
        m = causes[MAINTENANCE]
        base, now = self.friction_baseline, self.friction_smoothed
        if base is not None and now is not None and base > 0 and abs(now / base - 1.0) > band:
            m["friction"] = f"friction trend {now:.3g} x nominal, baseline {base:.3g} (band ±{100 * band:g} %)"
        if self.breakaway_nm is not None and self.breakaway_baseline_nm is not None and \
                self.breakaway_nm - self.breakaway_baseline_nm > rise:
            m["breakaway"] = (f"breakaway torque {self.breakaway_nm:.3g} N*m, baseline "
                              f"{self.breakaway_baseline_nm:.3g} N*m (rise limit {rise:g})")
        c = self.counters
        if c.travel_rad > travel_limit:
            m["travel"] = f"total travel {c.travel_rad:.0f} rad beyond {travel_limit:g} rad"
        if c.reversals > reversal_limit:
            m["reversals"] = f"{c.reversals} reversals beyond {reversal_limit}"
        m.update(self.maintenance)
        causes = {cat: v for cat, v in causes.items() if v}
        return Ne107Status(ne107_category(causes), causes)

    def values(self, status: Ne107Status) -> dict:
        """Key values for /diagnostics."""
        c = self.counters
        return {"ne107": status.category, "ne107_letter": status.letter, "ne107_level": status.level,
                "ne107_causes": json.dumps(status.causes) if status.causes else "none",
                "lifecycle_state": self.lifecycle,
                "travel_total_rad": c.travel_rad, "reversals_total": c.reversals, "high_dp_time_s": c.high_dp_s,
                "friction_trend_smoothed": self.friction_smoothed, "friction_baseline": self.friction_baseline,
                "breakaway_nm": self.breakaway_nm, "breakaway_baseline_nm": self.breakaway_baseline_nm}

    # ---- persistence ---------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {"counters": self.counters.to_dict(),
                "baselines": {"friction_trend": self.friction_baseline, "breakaway_nm": self.breakaway_baseline_nm}}

    def from_dict(self, doc: dict) -> None:
        """Counters and baselines from a saved dict (raises ValueError/KeyError/TypeError)."""
        base = doc["baselines"]
        values = []
        for key in ("friction_trend", "breakaway_nm"):
            v = base.get(key)
            if v is not None and not math.isfinite(float(v)):
                raise ValueError(f"baseline {key} {v!r} is not finite")
            values.append(None if v is None else float(v))
        self.counters.from_dict(doc["counters"])
        self.friction_baseline, self.breakaway_baseline_nm = values


class ForeignStateError(ValueError):
    """A learned-state file that belongs to another valve (:func:`load_state`)."""


def state_owner(path: str | Path) -> str | None:
    """The ``owner`` a learned-state file names (None: no file, no owner, or unreadable)."""
    try:
        doc = json.loads(Path(path).read_text())
        owner = doc.get("owner") if isinstance(doc, dict) else None
        return owner if isinstance(owner, str) else None
    except Exception:                        # noqa: BLE001 - no usable file: no owner
        return None


def save_state(path: str | Path, health: ValveHealth, learner=None, owner: str | None = None) -> None:
    """Write the learned state (counters, baselines, the learner's twists) to ``path``:
    atomically (a temporary file renamed over it), so a crash never leaves half a file.
    ``owner``: the valve the state belongs to (the controller node's fully qualified name),
    written as ``owner`` so that another valve's controller refuses the file
    (:func:`load_state`)."""
    path = Path(path)
    doc = {"format": STATE_FORMAT, "version": STATE_VERSION, **({"owner": owner} if owner else {}),
           **health.to_dict(), "fine_learner": learner.to_dict() if learner is not None else None}
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    os.replace(tmp, path)


def load_state(path: str | Path, health: ValveHealth, learner=None, owner: str | None = None) -> tuple[bool, str]:
    """Load the learned state of ``path`` into ``health`` (and ``learner``).  Never raises:
    ``(True, message)`` when loaded; ``(False, why)`` for a missing or unusable file, and then
    nothing is changed (the valve starts from zero counters and no baselines).  ``owner``
    given: a file that names another owner is unusable (another valve's friction and duty are
    not this one's); a file without an owner (written before owners were recorded, or by hand)
    is accepted."""
    path = Path(path)
    if not path.exists():
        return False, f"learned state file {path} not found: counters and baselines start from zero"
    try:
        doc = json.loads(path.read_text())
        if not isinstance(doc, dict) or doc.get("format") != STATE_FORMAT:
            raise ValueError(f"not a {STATE_FORMAT} file")
        if doc.get("version") != STATE_VERSION:
            raise ValueError(f"version {doc.get('version')!r}, this controller reads version {STATE_VERSION}")
        if owner and doc.get("owner") not in (None, owner):
            raise ForeignStateError(f"written for {doc['owner']!r}, this is {owner!r}")
        trial = ValveHealth(health.ps)
        trial.from_dict(doc)                 # validate everything before changing anything
        if learner is not None and doc.get("fine_learner") is not None:
            learner.from_dict(doc["fine_learner"])
        health.from_dict(doc)
    except Exception as exc:                 # noqa: BLE001 - any unusable file: say why, start from zero
        return False, (f"learned state file {path} unusable ({type(exc).__name__}: {exc}): counters and "
                       f"baselines start from zero")
    c = health.counters
    return True, (f"learned state loaded from {path}: travel {c.travel_rad:.3g} rad, {c.reversals} reversals, "
                  f"{c.high_dp_s:.3g} s at high Δp")

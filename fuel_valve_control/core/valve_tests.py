"""Valve diagnostics a positioner runs on request: the signature test and the partial-stroke test.

ROS-free, like the rest of :mod:`fuel_valve_control.core`: the controller node and the offline
simulator attach the same :class:`ValveTests` object to their :class:`~.driver.ValveDriver`
(``ValveTests(driver)``).  While no test runs it passes the operator demand through unchanged
(the loop behaves exactly as without it); a started test takes over the position demand period
by period (:meth:`ValveTests.demand`), records what it needs (:meth:`ValveTests.observe`) and
hands the demand back when it ends.

**Signature test** (needs the operator's consent, parameter ``tests.enable``): from where the
valve rests, a ramp to ``tests.signature.start_pct``, a rest, a slow ramp open to
``end_pct``, a rest, the ramp closed again, a rest, then for each size in ``steps_pct`` a step
up from the start position and back, then a ramp back to the operator's demand.

**Partial-stroke test**: from the valve's position (it must be at rest on a steady demand) a
ramp of ``tests.partial.fraction_pct`` toward closed (toward open when there is no room), a
rest, and back; within ``tests.partial.max_travel_pct`` and ``tests.partial.max_time_s``.

How the figures are measured (valve side, SI units; sign: positive = opening):

* drive torque ``T = Kt * N * i_cmd - J * a``: the commanded q current (the 1.5 kHz current loop
  follows it closely at these speeds) through the nominal torque constant and gear ratio,
  minus the rigid-body inertia (``model`` motor inertia reflected + valve inertia) times the
  valve acceleration from the observer's velocity estimate;
* friction vs position: ``T`` binned over the inner 80 % of the ramp range, median per bin and
  direction; friction = half the difference opening - closing, load = their mean.  What is
  measured is the whole drivetrain's Coulomb friction referred to the valve shaft (valve
  friction + N x motor friction + the small viscous torque at the ramp speed): the drive cannot
  tell them apart;
* spring: a straight line through the load after the nominal flow torque at the measured Δp is
  taken off: rate (N*m/rad) and preload (torque at the closed position, N*m);
* breakaway (per direction): the torque peak between the start of a move from rest and the
  moment the valve resolver has moved :data:`MOTION_COUNTS` counts, minus the load there;
* hysteresis: the largest gap between the opening and closing position at the same demand
  (ISA-75.25 style, ramp lag included), percent of stroke; deadband: the largest step that
  moved the valve less than half its size (0 when every step was answered), resolution: the
  smallest step answered;
* steps: overshoot (percent of the step), settling time (to within 10 % of the step or 2
  counts, whichever is larger) and final error (percent of stroke), per step and direction.

Degradation: against a baseline (the first completed run of each test, or a stored one),
friction and breakaway are compared as ratios to the nominal model's friction at each run's Δp
(so a baseline taken at another Δp still compares), the travel time directly; a ratio beyond
``tests.degradation_ratio`` (or below its inverse) is a finding, ``maintenance required``.

Results are one JSON-able dict (:meth:`ValveTests.last_result`): ``test``, ``status``
(``completed``/``aborted``), ``reason``, ``figures`` (flat name -> number; the unit is the
name's suffix, :func:`unit_of`), ``curve`` (binned torque per direction), ``trace`` (decimated
torque/position samples), ``baseline`` and ``findings``.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..common.contract import RESOLVER_COUNT_RAD

SIGNATURE, PARTIAL_STROKE = "signature", "partial_stroke"
#: valve resolver counts of travel that count as "the valve has moved" (4 counts: beyond the
#: resolver noise and quantisation, 0.25 counts rms)
MOTION_COUNTS = 4
#: velocity-estimate smoothing window before differentiation, s
ACCEL_WINDOW_S = 0.01
#: largest number of raw samples kept in a result's trace (the report plots them)
TRACE_POINTS = 2000
#: figures compared against the baseline, and whether they scale with the nominal friction
COMPARED = {SIGNATURE: {"friction_mean_nm": True, "breakaway_open_nm": True, "breakaway_close_nm": True},
            PARTIAL_STROKE: {"friction_mean_nm": True, "breakaway_nm": True, "travel_time_out_s": False}}
#: unit of a figure by the suffix of its name
_UNITS = (("_nm_per_rad", "N*m/rad"), ("_nm", "N*m"), ("_pct", "%"), ("_kpa", "kPa"), ("_rad", "rad"),
          ("_s", "s"), ("_ratio", ""), ("_count", ""))


def unit_of(name: str) -> str:
    """The unit of a figure, from its name's suffix (``friction_mean_nm`` -> ``N*m``)."""
    for suffix, unit in _UNITS:
        if name.endswith(suffix):
            return unit
    return ""


@dataclass(frozen=True)
class Segment:
    """One piece of a test's demand: a ramp from ``start`` to ``end`` (rad) over ``duration``
    (s) starting at ``t0`` (s, loop time); a constant (rest, step) when they are equal."""
    tag: str
    t0: float
    duration: float
    start: float
    end: float

    def value(self, t: float) -> float:
        if self.duration <= 0.0:
            return self.end
        x = min(max((t - self.t0) / self.duration, 0.0), 1.0)
        return self.start + (self.end - self.start) * x


def _plan(t0: float, pieces) -> list[Segment]:
    """Segments back to back from ``t0``: ``pieces`` = (tag, duration, start, end)."""
    out, t = [], t0
    for tag, duration, start, end in pieces:
        out.append(Segment(tag, t, duration, start, end))
        t += duration
    return out


def _ramp(tag, start, end, rate):
    return (tag, abs(end - start) / rate, start, end)


class _Run:
    """A running test: its segments and the samples recorded while it runs."""

    def __init__(self, name: str, t0: float, segments: list[Segment], demand_pct: float, pressure_kpa: float,
                 origin_rad: float):
        self.name, self.t0, self.segments = name, t0, segments
        self.demand_pct = demand_pct        # operator demand at the start (abort band reference)
        self.pressure_kpa = pressure_kpa
        self.origin = origin_rad            # position at the start (partial stroke: excursion reference)
        self.end_t = segments[-1].t0 + segments[-1].duration
        self.index = 0
        #: (t, demand_rad, position_rad, velocity_rad_s, current_a, segment, gear_output_rad)
        self.rows: list[tuple] = []

    def segment(self, t: float) -> Segment | None:
        while self.index < len(self.segments) and t >= self.segments[self.index].t0 + self.segments[self.index].duration:
            self.index += 1
        return self.segments[self.index] if self.index < len(self.segments) else None


class ValveTests:
    """The signature and partial-stroke tests of one :class:`~.driver.ValveDriver`.

    ``ValveTests(driver)`` attaches itself (``driver.valve_test``).  ``start_signature`` /
    ``start_partial_stroke`` answer ``(accepted, message)``; the run starts at the next loop
    period.  :attr:`running` (the test's name or None), :attr:`findings` (degradation findings
    of the latest runs, texts) and :meth:`last_result` are what the node reports; callables
    in :attr:`listeners` get every finished result (completed or aborted)."""

    def __init__(self, driver):
        self.driver = driver
        self._run: _Run | None = None
        self._pending: str | None = None
        self._demands: deque = deque()            # (t, operator demand %) over the demand window
        self.results: dict[str, dict] = {}        # latest result per test
        self.baselines: dict[str, dict] = {}      # test -> {"figures", "pressure_kpa"}
        self.findings_by_test: dict[str, list[str]] = {}
        self.listeners: list = []
        self.refusals: list[str] = []             # messages of refused requests, oldest first
        driver.valve_test = self

    # ------------------------------------------------------------------ state
    @property
    def running(self) -> str | None:
        """Name of the test that owns the demand now (also while it is about to start), else None."""
        return self._run.name if self._run is not None else self._pending

    @property
    def findings(self) -> list[str]:
        """'Maintenance required' findings of the latest run of each test (empty: none)."""
        return [f for name in sorted(self.findings_by_test) for f in self.findings_by_test[name]]

    def report_health(self, health) -> None:
        """NE107 inputs (:class:`~.health.ValveHealth`), every period: a running test is a
        function check (the valve is off its demand on purpose); a test's degradation findings
        need maintenance until a later run of that test finds none."""
        running = self.running
        health.set_test_running(running is not None, f"{running} test" if running else "valve test")
        for name in COMPARED:
            found = self.findings_by_test.get(name)
            if found:
                health.raise_maintenance(f"valve_test:{name}", "; ".join(found))
            else:
                health.clear_maintenance(f"valve_test:{name}")

    def last_result(self, name: str | None = None) -> dict | None:
        """The latest result of test ``name`` (None: of any test, the newest)."""
        if name is not None:
            return self.results.get(name)
        return max(self.results.values(), key=lambda r: r["t_end_s"], default=None)

    def set_baseline(self, result: dict) -> None:
        """Adopt a stored result (a completed run's dict, e.g. from a JSON file) as its test's
        baseline.  Raises ``ValueError`` if it is not one."""
        name = result.get("test") if isinstance(result, dict) else None
        if name not in COMPARED or result.get("status") != "completed" or not isinstance(result.get("figures"), dict):
            raise ValueError("a baseline must be a completed signature or partial_stroke result "
                             "(keys test, status, figures, pressure_kpa)")
        self.baselines[name] = {"figures": dict(result["figures"]), "pressure_kpa": float(result.get("pressure_kpa", 0.0))}

    def summary(self) -> dict:
        """Key values for /diagnostics: running test and the latest results' headline figures."""
        out = {"valve_test_running": self.running or "none",
               "valve_test_findings": "; ".join(self.findings) or "none"}
        for name, res in sorted(self.results.items()):
            out[f"{name}_status"] = res["status"] + (f" ({res['reason']})" if res["reason"] else "")
            for key in COMPARED[name]:
                if key in res["figures"]:
                    out[f"{name}_{key}"] = res["figures"][key]
        return out

    # ------------------------------------------------------------------ start (refusal rules)
    def _refusal(self) -> str | None:
        d = self.driver
        if self.running:
            return f"a {self.running} test is running already"
        if d.faults:
            return "a fault is active: " + "; ".join(d.faults.values())
        if d.last.state != "running":
            return f"the drive is not running (state {d.last.state})"
        return None

    def start(self, name: str) -> tuple[bool, str]:
        """Request test ``name`` (:data:`SIGNATURE` or :data:`PARTIAL_STROKE`); a refusal's
        message is also kept in :attr:`refusals`."""
        accepted, message = (self.start_signature if name == SIGNATURE else self.start_partial_stroke)()
        if not accepted:
            self.refusals.append(message)
        return accepted, message

    def start_signature(self) -> tuple[bool, str]:
        """Request a signature test (starts at the next period); refused unless test mode is on
        and the valve is healthy: no fault, running, not hunting, no tracking error."""
        d, ps = self.driver, self.driver.ps
        why = self._refusal()
        if why is None and not ps["tests.enable"]:
            why = "test mode is off (set parameter tests.enable to true first)"
        if why is None:
            error = abs(d.demand_rad() - d._meas.valve_rad)
            if error > 0.5 * ps["faults.tracking_error_rad"]:
                why = (f"tracking error {error:.4f} rad (more than half the fault limit "
                       f"{ps['faults.tracking_error_rad']:g} rad)")
        if why is None:
            spread = d.recent_position_spread()
            if spread > ps["tests.hunting_limit_rad"]:
                why = (f"valve hunting or moving: position spread {spread:.4f} rad over the last 2 s "
                       f"(tests.hunting_limit_rad {ps['tests.hunting_limit_rad']:g})")
        return self._accept(SIGNATURE, why)

    def start_partial_stroke(self) -> tuple[bool, str]:
        """Request a partial-stroke test; refused when a fault is active or the demand moved over
        ``tests.partial.demand_window_s``, and when the travel or the time the test needs exceed
        what the turbine tolerates."""
        ps = self.driver.ps
        why = self._refusal()
        if why is None:
            why = self._demand_changing()
        if why is None and ps["tests.partial.fraction_pct"] > ps["tests.partial.max_travel_pct"]:
            why = (f"tests.partial.fraction_pct {ps['tests.partial.fraction_pct']:g} % exceeds "
                   f"tests.partial.max_travel_pct {ps['tests.partial.max_travel_pct']:g} %")
        if why is None:
            need = self._partial_pieces(self.driver.demand_rad())
            if isinstance(need, str):
                why = need
            else:
                total = sum(p[1] for p in need)
                if total > ps["tests.partial.max_time_s"]:
                    why = (f"the test needs {total:.2f} s, more than tests.partial.max_time_s "
                           f"{ps['tests.partial.max_time_s']:g} s (raise tests.partial.rate_pct_s)")
        return self._accept(PARTIAL_STROKE, why)

    def _accept(self, name: str, why: str | None) -> tuple[bool, str]:
        if why:
            return False, f"{name} test refused: {why}"
        self._pending = name
        return True, f"{name} test accepted: it takes over the position demand from the next period"

    def _demand_changing(self) -> str | None:
        ps = self.driver.ps
        window = ps["tests.partial.demand_window_s"]
        if not self._demands or self._demands[-1][0] - self._demands[0][0] < window - 2.0 * self.driver.period:
            return f"the demand has not been watched for tests.partial.demand_window_s ({window:g} s) yet"
        values = [v for _, v in self._demands]
        moved = max(values) - min(values)
        if moved > ps["tests.partial.demand_band_pct"]:
            return (f"the demand is changing: it moved {moved:.2f} % in the last {window:g} s "
                    f"(tests.partial.demand_band_pct {ps['tests.partial.demand_band_pct']:g} %)")
        return None

    # ------------------------------------------------------------------ plans
    def _pct(self, pct: float) -> float:
        return pct / 100.0 * self.driver.stroke

    def _signature_pieces(self, position: float, demand: float):
        ps = self.driver.ps
        a, b = self._pct(ps["tests.signature.start_pct"]), self._pct(ps["tests.signature.end_pct"])
        rate, dwell, hold = self._pct(ps["tests.signature.ramp_rate_pct_s"]), ps["tests.signature.dwell_s"], \
            ps["tests.signature.step_time_s"]
        pieces = [_ramp("approach", position, a, rate), ("rest", dwell, a, a), _ramp("open", a, b, rate),
                  ("rest", dwell, b, b), _ramp("close", b, a, rate), ("rest", dwell, a, a)]
        for i, size in enumerate(ps["tests.signature.steps_pct"]):
            up = min(a + self._pct(size), self.driver.stroke)
            pieces += [(f"step_up:{i}", hold, up, up), (f"step_down:{i}", hold, a, a)]
        pieces.append(_ramp("return", a, demand, rate))
        return pieces

    def _partial_pieces(self, origin: float):
        ps = self.driver.ps
        travel, margin = self._pct(ps["tests.partial.fraction_pct"]), self._pct(1.0)
        if origin - travel >= margin:
            target = origin - travel
        elif origin + travel <= self.driver.stroke - margin:
            target = origin + travel
        else:
            return "no room for the partial stroke within 1 % of either stop"
        rate, dwell = self._pct(ps["tests.partial.rate_pct_s"]), ps["tests.partial.dwell_s"]
        return [("rest0", dwell, origin, origin), _ramp("out", origin, target, rate), ("rest", dwell, target, target),
                _ramp("back", target, origin, rate), ("rest_end", dwell, origin, origin)]

    # ------------------------------------------------------------------ loop hooks (driver)
    def demand(self, t: float, demand_rad: float) -> float:
        """The demand the loop follows this period (rad): the test's while one runs, else
        ``demand_rad`` unchanged."""
        if self._pending is not None:
            self._begin(t, demand_rad)
        run = self._run
        if run is None:
            return demand_rad
        seg = run.segment(t)
        return demand_rad if seg is None else seg.value(t)

    def _begin(self, t: float, demand_rad: float) -> None:
        name, self._pending = self._pending, None
        d = self.driver
        position = d._meas.valve_rad
        pieces = (self._signature_pieces(position, demand_rad) if name == SIGNATURE
                  else self._partial_pieces(demand_rad))
        if isinstance(pieces, str):                     # conditions changed since the request
            self._finish(t, name, "aborted", pieces, None)
            return
        self._run = _Run(name, t, _plan(t, pieces), d._demand_pct, d.pressure_kpa, demand_rad)

    def observe(self, t: float, out) -> None:
        """After each driver period: record, check the abort rules, finish.  Never raises (an
        error here aborts the test, it does not trip the valve)."""
        try:
            self._observe(t, out)
        except Exception as exc:       # noqa: BLE001 - a defect in a diagnostic must not stop the loop
            run, self._run = self._run, None
            self._finish(t, run.name if run else "valve", "aborted", f"internal error in the test: {exc!r}", None)

    def _observe(self, t: float, out) -> None:
        ps, d = self.driver.ps, self.driver
        if out.demand_pct is not None:
            self._demands.append((t, out.demand_pct))
            while self._demands and t - self._demands[0][0] > ps["tests.partial.demand_window_s"]:
                self._demands.popleft()
        run = self._run
        if run is None:
            return
        why = None
        if out.faults:
            why = "fault: " + "; ".join(out.faults.values())
        elif out.state != "running":
            why = f"drive state {out.state}"
        elif out.demand_pct is not None and abs(out.demand_pct - run.demand_pct) > ps["tests.abort_band_pct"]:
            why = (f"the demand moved {out.demand_pct - run.demand_pct:+.2f} % (beyond tests.abort_band_pct "
                   f"{ps['tests.abort_band_pct']:g} %): control handed back")
        elif run.name == PARTIAL_STROKE:
            excursion = abs(d._meas.valve_rad - run.origin) / d.stroke * 100.0
            if excursion > ps["tests.partial.max_travel_pct"]:
                why = f"excursion {excursion:.2f} % beyond tests.partial.max_travel_pct"
            elif t - run.t0 > ps["tests.partial.max_time_s"]:
                why = f"running {t - run.t0:.2f} s, longer than tests.partial.max_time_s"
        if why:
            self._run = None
            self._finish(t, run.name, "aborted", why, None)
            return
        seg = run.segment(t)
        seg_index = run.index
        if seg is None:
            self._run = None
            self._finish(t, run.name, "completed", "", run)
            return
        est = d.controller.estimate()
        run.rows.append((t, seg.value(t), d._meas.valve_rad, est.valve_velocity, out.current_a, seg_index,
                         d._meas.motor_rad / d.n))

    # ------------------------------------------------------------------ results
    def _finish(self, t: float, name: str, status: str, reason: str, run: _Run | None) -> None:
        result = {"test": name, "status": status, "reason": reason, "t_end_s": t,
                  "pressure_kpa": run.pressure_kpa if run else self.driver.pressure_kpa,
                  "figures": {}, "curve": {}, "trace": {}, "baseline": None, "findings": []}
        if run is not None:
            analysis = Analysis(run, self.driver)
            result["figures"], result["curve"], result["trace"] = analysis.figures(), analysis.curve, analysis.trace
            result["t_start_s"] = run.t0
            self._compare(result)
        self.results[name] = result
        for listener in list(self.listeners):
            listener(result)

    def nominal_friction(self, pressure_kpa: float, static: bool = False) -> float:
        """The nominal model's drivetrain friction at the valve, N*m: valve + N x motor level."""
        lv = self.driver.controller.model.friction(pressure_kpa)
        n = self.driver.n
        return (lv.valve_static_nm + n * lv.motor_coulomb_nm) if static else (lv.valve_coulomb_nm + n * lv.motor_coulomb_nm)

    def _compare(self, result: dict) -> None:
        name, figs = result["test"], result["figures"]
        figs["friction_to_nominal_ratio"] = figs.get("friction_mean_nm", math.nan) / self.nominal_friction(
            result["pressure_kpa"])
        base = self.baselines.get(name)
        if base is None:
            self.set_baseline(result)
            self.findings_by_test[name] = []
            result["baseline"] = {"source": "this run", **self.baselines[name]}
            return
        result["baseline"] = {"source": "stored", **base}
        band = self.driver.ps["tests.degradation_ratio"]
        findings = []
        for key, scales in COMPARED[name].items():
            now, was = figs.get(key), base["figures"].get(key)
            if now is None or was is None or not (math.isfinite(now) and math.isfinite(was)) or was <= 0.0:
                continue
            if scales:      # the same valve has more friction at a higher Δp: compare like with like
                static = key.startswith("breakaway")
                was = was * self.nominal_friction(result["pressure_kpa"], static) / self.nominal_friction(
                    base["pressure_kpa"], static)
            ratio = now / was
            figs[f"{key[:key.rfind('_')]}_to_baseline_ratio"] = ratio
            if not 1.0 / band <= ratio <= band:
                findings.append(f"maintenance required: {name} {key} {now:.3g} {unit_of(key)} is {ratio:.2f}x "
                                f"the baseline's {was:.3g} (band {1 / band:.2f}..{band:.2f})")
        result["findings"] = findings
        self.findings_by_test[name] = findings


def results_in(doc) -> list[dict]:
    """Valve-test results in a JSON document, oldest first: one result (a dict with ``test``),
    ``fuel_valve_sim --json`` output (``valve_tests``: name -> result), a
    ``fuel_valve_report --json`` document (``valve_tests``: a list) or a list of results."""
    if isinstance(doc, list):
        return [r for r in doc if isinstance(r, dict) and "test" in r]
    if not isinstance(doc, dict):
        return []
    if "test" in doc:
        return [doc]
    found = doc.get("valve_tests")
    if isinstance(found, dict):
        found = sorted(found.values(), key=lambda r: r.get("t_end_s") or 0.0)
    return results_in(found or [])


def load_baselines(path: str) -> list[dict]:
    """The completed results in the JSON file ``path`` (:func:`results_in`); raises
    ``OSError``/``ValueError`` for a missing or unreadable file or one without results."""
    import json
    with open(path) as f:
        found = [r for r in results_in(json.load(f)) if r.get("status") == "completed"]
    if not found:
        raise ValueError(f"{path}: no completed valve-test result in it")
    return found


class Analysis:
    """Figures of one completed run (see the module docstring for the definitions)."""

    def __init__(self, run: _Run, driver):
        rows = np.asarray(run.rows, dtype=float).reshape(-1, 7)
        self.run, self.driver = run, driver
        self.t, self.demand, self.pos, vel, current, seg, gear = rows.T
        #: gear-output displacement per period, rad: the work weights (see :meth:`_pair`)
        self.step = np.diff(gear, prepend=gear[:1]) if len(gear) else gear
        self.seg = seg.astype(int)
        model = driver.controller.model
        period = driver.period
        win = max(int(round(ACCEL_WINDOW_S / period)), 1)
        smooth = np.convolve(vel, np.ones(win) / win, mode="same") if len(vel) > win else vel
        accel = np.gradient(smooth, period) if len(smooth) > 1 else np.zeros_like(smooth)
        self.torque = model.torque_constant_nm_per_a * model.gear_ratio * current - model.total_inertia * accel
        self.model = model
        self.count = RESOLVER_COUNT_RAD
        self.curve: dict = {}
        self.trace: dict = {}

    def _mask(self, tag: str) -> np.ndarray:
        idx = [i for i, s in enumerate(self.run.segments) if s.tag == tag]
        return np.isin(self.seg, idx)

    def _load_model(self, pos: np.ndarray) -> np.ndarray:
        """Nominal flow torque at the run's Δp (known, taken off the measured load), N*m."""
        m = self.model
        frac = np.clip(pos / m.stroke_rad, 0.0, 1.0)
        return m.flow_torque_max_nm * m.pressure_fraction(self.run.pressure_kpa) * np.sin(np.pi * frac)

    def _pair(self, up_tag: str, down_tag: str, low: float, high: float, bins: int) -> dict:
        """Torque per direction and position bin over ``low..high`` (rad, inner 80 %): the work
        the drive did in the bin over the gear-output travel in it, ``sum(T dθ) / sum(dθ)``.
        Weighting by travel, not time, is what makes it the friction *level* when the valve
        moves in stick-slip jumps (high Δp): torque held while the drive train stands still
        does no work, and the energy a breakaway stores in the coupling is spent against
        Coulomb friction in the jump that follows; a time average would read between the
        Coulomb and the static level (+11 % at 6206 kPa on the nominal plant)."""
        span = high - low
        edges = np.linspace(low + 0.1 * span, high - 0.1 * span, bins + 1)
        centres = 0.5 * (edges[1:] + edges[:-1])
        out = {}
        for tag, key in ((up_tag, "open"), (down_tag, "close")):
            m = self._mask(tag)
            p, tq, dem, dx = self.pos[m], self.torque[m], self.demand[m], self.step[m]
            which = np.digitize(p, edges) - 1
            work = np.bincount(which[(which >= 0) & (which < bins)], (tq * dx)[(which >= 0) & (which < bins)], bins)
            travel = np.bincount(which[(which >= 0) & (which < bins)], dx[(which >= 0) & (which < bins)], bins)
            with np.errstate(invalid="ignore", divide="ignore"):
                out[key] = np.where(np.abs(travel) > MOTION_COUNTS * self.count, work / travel, np.nan)
            dwhich = np.digitize(dem, edges) - 1
            out[key + "_pos"] = np.array([np.mean(p[dwhich == i]) if np.any(dwhich == i) else np.nan
                                          for i in range(bins)])
        out["centres"] = centres
        out["friction"] = 0.5 * (out["open"] - out["close"])
        out["load"] = 0.5 * (out["open"] + out["close"])
        ok = np.isfinite(out["load"])
        spring = out["load"][ok] - self._load_model(centres[ok])
        if ok.sum() >= 2:
            rate, preload = np.polyfit(centres[ok], spring, 1)
        else:
            rate, preload = math.nan, math.nan
        out["rate"], out["preload"] = rate, preload
        return out

    def _load_at(self, pair: dict, pos: float) -> float:
        return pair["preload"] + pair["rate"] * pos + float(self._load_model(np.array([pos]))[0])

    def _breakaway(self, tag: str, sign: float, pair: dict) -> tuple[float, float]:
        """(friction-equivalent breakaway torque N*m, time to move s) of the move ``tag`` from rest."""
        m = np.flatnonzero(self._mask(tag))
        if len(m) < 2:
            return math.nan, math.nan
        p0 = self.pos[m[0]]
        moved = np.flatnonzero(sign * (self.pos[m] - p0) > MOTION_COUNTS * self.count)
        if len(moved) == 0:
            return math.nan, math.nan
        k = moved[0]
        peak = np.max(sign * self.torque[m[:k + 1]])
        return peak - sign * self._load_at(pair, self.pos[m[k]]), self.t[m[k]] - self.t[m[0]]

    def figures(self) -> dict:
        run = self.run
        figs = {"pressure_differential_kpa": run.pressure_kpa, "duration_s": float(self.t[-1] - self.t[0])}
        ps = self.driver.ps
        if run.name == SIGNATURE:
            low, high = sorted((self.driver.stroke * ps["tests.signature.start_pct"] / 100.0,
                                self.driver.stroke * ps["tests.signature.end_pct"] / 100.0))
            pair = self._pair("open", "close", low, high, ps["tests.signature.bins"])
            figs.update(self._friction_figures(pair))
            figs["breakaway_open_nm"], figs["breakaway_open_time_s"] = self._breakaway("open", 1.0, pair)
            figs["breakaway_close_nm"], figs["breakaway_close_time_s"] = self._breakaway("close", -1.0, pair)
            gap = np.abs(pair["open_pos"] - pair["close_pos"])
            figs["hysteresis_pct"] = float(np.nanmax(gap)) / self.driver.stroke * 100.0 if np.any(
                np.isfinite(gap)) else math.nan
            figs.update(self._steps(ps["tests.signature.steps_pct"]))
        else:
            seg_out = next(s for s in run.segments if s.tag == "out")
            closing = seg_out.end < seg_out.start
            up, down = ("back", "out") if closing else ("out", "back")
            pair = self._pair(up, down, min(seg_out.start, seg_out.end), max(seg_out.start, seg_out.end), 4)
            figs.update(self._friction_figures(pair))
            sign = -1.0 if closing else 1.0
            figs["breakaway_nm"], figs["breakaway_time_s"] = self._breakaway("out", sign, pair)
            figs["breakaway_back_nm"], _ = self._breakaway("back", -sign, pair)
            for tag in ("out", "back"):
                figs[f"travel_time_{tag}_s"] = self._travel_time(tag)
            figs["travel_pct"] = abs(seg_out.end - seg_out.start) / self.driver.stroke * 100.0
            # where the valve came to rest after the return, against where it started
            figs["return_error_pct"] = float(self.pos[-1] - run.origin) / self.driver.stroke * 100.0
        self.curve = {"position_pct": _pct_list(pair["centres"], self.driver.stroke),
                      "torque_open_nm": _list(pair["open"]), "torque_close_nm": _list(pair["close"]),
                      "friction_nm": _list(pair["friction"]), "load_nm": _list(pair["load"])}
        self._make_trace(up_tag="open" if run.name == SIGNATURE else up,
                         down_tag="close" if run.name == SIGNATURE else down)
        return {k: float(v) for k, v in figs.items()}

    @staticmethod
    def _friction_figures(pair: dict) -> dict:
        f = pair["friction"][np.isfinite(pair["friction"])]
        nan = math.nan
        return {"friction_mean_nm": float(np.mean(f)) if len(f) else nan,
                "friction_min_nm": float(np.min(f)) if len(f) else nan,
                "friction_max_nm": float(np.max(f)) if len(f) else nan,
                "spring_rate_nm_per_rad": pair["rate"], "spring_preload_nm": pair["preload"]}

    def _travel_time(self, tag: str) -> float:
        """Time from the start of move ``tag`` until the valve covered 90 % of it, s."""
        seg = next(s for s in self.run.segments if s.tag == tag)
        after = np.flatnonzero(self.t >= seg.t0)
        if len(after) == 0:
            return math.nan
        target = seg.start + 0.9 * (seg.end - seg.start)
        sign = 1.0 if seg.end > seg.start else -1.0
        reached = after[sign * (self.pos[after] - target) >= 0.0]
        return float(self.t[reached[0]] - seg.t0) if len(reached) else math.nan

    def _steps(self, sizes) -> dict:
        figs, answered, unanswered = {}, [], []
        stroke = self.driver.stroke
        for i, size in enumerate(sizes):
            for direction in ("up", "down"):
                seg = next(s for s in self.run.segments if s.tag == f"step_{direction}:{i}")
                m = np.flatnonzero(self._mask(seg.tag))
                if len(m) < 2:
                    continue
                p, t = self.pos[m], self.t[m] - seg.t0
                start = self.pos[m[0] - 1] if m[0] > 0 else p[0]
                step = seg.end - start
                if abs(step) < 0.5 * self.count:
                    continue
                sign = 1.0 if step > 0 else -1.0
                key = f"step_{size:g}pct_{direction}"
                figs[f"{key}_overshoot_pct"] = max(float(np.max(sign * (p - seg.end))), 0.0) / abs(step) * 100.0
                band = max(0.1 * abs(step), 2.0 * self.count)
                outside = np.flatnonzero(np.abs(p - seg.end) > band)
                figs[f"{key}_settling_time_s"] = (0.0 if len(outside) == 0 else
                                                  float(t[outside[-1]]) if outside[-1] < len(p) - 1 else math.nan)
                figs[f"{key}_final_error_pct"] = float(p[-1] - seg.end) / stroke * 100.0
                if direction == "up":
                    (answered if sign * (p[-1] - start) >= 0.5 * abs(step) else unanswered).append(size)
        figs["deadband_pct"] = max(unanswered, default=0.0)
        figs["resolution_pct"] = min(answered, default=math.nan)
        return figs

    def _make_trace(self, up_tag: str, down_tag: str) -> None:
        m = self._mask(up_tag) | self._mask(down_tag)
        idx = np.flatnonzero(m)
        if len(idx) > TRACE_POINTS:
            idx = idx[np.linspace(0, len(idx) - 1, TRACE_POINTS).astype(int)]
        up = self._mask(up_tag)[idx]
        self.trace = {"position_pct": _pct_list(self.pos[idx], self.driver.stroke), "torque_nm": _list(self.torque[idx]),
                      "opening": [bool(x) for x in up]}


def _list(a) -> list:
    return [None if not math.isfinite(float(x)) else round(float(x), 5) for x in a]


def _pct_list(a, stroke: float) -> list:
    return _list(np.asarray(a) / stroke * 100.0)

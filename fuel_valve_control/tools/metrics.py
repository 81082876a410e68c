"""Closed-loop metrics of SPEC §5, computed from a trace of the demand and the valve angle.

The same code serves the offline simulator and the bag report, so it only needs what a bag
holds: time, demand, valve angle (the *true* angle when the plant's ground truth is there),
current and drive enable.  Segments are found in the demand itself:

* **plateaus**: runs of constant demand at least ``MIN_PLATEAU_S`` long;
* **steps**: a change between two plateaus that happens within ``MAX_STEP_WIDTH_S``
  (also the move from the initial valve position to the first plateau);
* **holds**: plateaus of at least ``MIN_HOLD_S``; their second half is the settled window;
* **sweeps**: stretches between plateaus where the demand oscillates (>= 6 extrema);
* **ramps**: the monotonic pieces of the other stretches between plateaus (or before the first,
  after the last) that last at least ``MIN_RAMP_S`` and change the demand by more than
  ``MIN_STEP_RAD`` (a reversing ramp is two);
* **trips**: falling edges of the drive enable, each to the next rising edge (a re-enabled drive:
  a command watchdog's trip in real time, a reset) or to the end.

Metric definitions (all angles rad, times s, currents A):

* ``rise_time_s``: 10 % to 90 % of the step; ``overshoot_pct``: largest excursion beyond the
  new demand, percent of the step; ``settling_time_s``: from the step until the error stays
  inside ``max(2 % of the step, 0.1°)`` to the end of the following plateau (``null`` when it
  never does); worst over all steps.
* ``steady_state_error_rad``: ``|mean(demand - angle)|`` over the settled half of each hold
  (or of each step's plateau when there is no hold); worst.
* ``limit_cycle_amplitude_rad``: half the peak-to-peak angle over the settled half of a hold;
  ``limit_cycle_frequency_hz``: dominant frequency there, 0 when the amplitude is within one
  resolver count; worst hold.
* ``peak_current_a``, ``rms_current_a``: over the whole run.
* ``stroke_time_s``: from a step of >= 95 % of the stroke to 98 % of it.
* ``close_time_s``: from the drive being disabled to <= 2 % open (the first trip that closed the
  valve; ``null`` when none did before the drive was enabled again).
* ``bandwidth_hz``: where the per-cycle gain ``p-p(angle) / p-p(demand)`` of a sweep falls
  below -3 dB (interpolated in log frequency); the top frequency when it never does.
* ``iae_rad_s``: integral of ``|demand - angle|`` over the whole run.
* ``ramp_max_error_rad``: largest ``|demand - angle|`` during a ramp from ``RAMP_SETTLE_S`` after
  its start to its end (the valve had that long to pick the ramp up); ``ramp_lag_s``: the mean
  of ``(demand - angle)`` there divided by the ramp's rate (s, positive = the valve behind the
  demand); worst ramp (largest error) of the run.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..common.contract import RESOLVER_COUNT_RAD
from ..common.hunting import HUNT_COUNTS, HUNT_REVERSALS, HUNT_SETTLE_S, ReversalCounter

TENTH_DEGREE_RAD = math.radians(0.1)
MIN_PLATEAU_S = 0.1
MAX_STEP_WIDTH_S = 0.02
MIN_HOLD_S = 2.0
MIN_STEP_RAD = 1e-3
CONST_TOL_RAD = 1e-6
MINUS_3DB = 10.0 ** (-3.0 / 20.0)
MIN_RAMP_S = 0.4
RAMP_SETTLE_S = 0.2


@dataclass
class Trace:
    """Samples on a common time base (s).  ``current`` is the current magnitude, A."""

    t: np.ndarray
    demand: np.ndarray
    position: np.ndarray
    current: np.ndarray
    enable: np.ndarray
    stroke_rad: float = 1.0472

    def __post_init__(self):
        for name in ("t", "demand", "position", "current", "enable"):
            setattr(self, name, np.asarray(getattr(self, name), dtype=float))
        n = len(self.t)
        if n < 2 or any(len(getattr(self, k)) != n for k in ("demand", "position", "current", "enable")):
            raise ValueError("trace needs at least two samples and equal-length signals")


@dataclass
class Segment:
    kind: str            # plateau | step | hold | sweep | ramp | trip
    i0: int
    i1: int              # exclusive
    info: dict = field(default_factory=dict)


def plateaus(tr: Trace) -> list[Segment]:
    """Maximal runs of constant demand lasting at least MIN_PLATEAU_S."""
    d = tr.demand
    change = np.flatnonzero(np.abs(np.diff(d)) > CONST_TOL_RAD) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [len(d)]])
    out = []
    for a, b in zip(starts, ends):
        if tr.t[b - 1] - tr.t[a] >= MIN_PLATEAU_S:
            out.append(Segment("plateau", int(a), int(b), {"demand": float(d[a])}))
    return out


def _slope_signs(seg: np.ndarray) -> np.ndarray:
    """Sign (+1 / -1) of each sample-to-sample change of ``seg``; 0 where it stays put (within
    ``CONST_TOL_RAD``)."""
    slope = np.diff(seg)
    return np.where(np.abs(slope) > CONST_TOL_RAD, np.sign(slope), 0.0)


def _extrema(seg: np.ndarray) -> int:
    """Direction changes of ``seg``.  Samples where it stays put are no extrema: a demand
    recorded as the last message received reads as a staircase, and its flat treads counted as
    turning points made every ramp of a bag a "sweep"."""
    signs = _slope_signs(seg)
    return int(np.count_nonzero(np.diff(signs[signs != 0.0]) != 0))


def ramps(tr: Trace, i0: int, i1: int) -> list[Segment]:
    """The monotonic pieces of the demand over samples ``i0:i1`` (a stretch between plateaus
    that is no sweep) lasting at least ``MIN_RAMP_S`` and moving more than ``MIN_STEP_RAD``."""
    d, t = tr.demand, tr.t
    if i1 - i0 < 3:
        return []
    slope = _slope_signs(d[i0:i1])
    out = []
    a = 0
    while a < len(slope):
        if slope[a] == 0.0:
            a += 1
            continue
        b = a
        while b + 1 < len(slope) and slope[b + 1] in (slope[a], 0.0):
            b += 1
        lo, hi = i0 + a, i0 + b + 2           # samples a .. b+1 of the stretch
        if t[hi - 1] - t[lo] >= MIN_RAMP_S and abs(d[hi - 1] - d[lo]) > MIN_STEP_RAD:
            out.append(Segment("ramp", lo, hi, {"from": float(d[lo]), "to": float(d[hi - 1])}))
        a = b + 1
    return out


def find_segments(tr: Trace) -> list[Segment]:
    segs: list[Segment] = []
    plats = plateaus(tr)
    t = tr.t
    if plats and plats[0].i0 > 0 and _extrema(tr.demand[:plats[0].i0 + 1]) < 6:
        segs.extend(ramps(tr, 0, plats[0].i0 + 1))         # a ramp from the trace's start
    # the move from the initial angle onto the first plateau counts as a step
    if plats and plats[0].i0 == 0 and abs(plats[0].info["demand"] - tr.position[0]) > MIN_STEP_RAD:
        p = plats[0]
        segs.append(Segment("step", 0, p.i1, {"from": float(tr.position[0]), "to": p.info["demand"]}))
    for prev, nxt in zip(plats, plats[1:]):
        gap = t[nxt.i0] - t[prev.i1 - 1]
        delta = nxt.info["demand"] - prev.info["demand"]
        if gap <= MAX_STEP_WIDTH_S and abs(delta) > MIN_STEP_RAD:
            segs.append(Segment("step", nxt.i0, nxt.i1, {"from": prev.info["demand"], "to": nxt.info["demand"]}))
        elif gap > MAX_STEP_WIDTH_S:
            if _extrema(tr.demand[prev.i1:nxt.i0]) >= 6:
                segs.append(Segment("sweep", prev.i1, nxt.i0))
            else:
                # (from the previous plateau's last sample: the ramp leaves it there)
                segs.extend(ramps(tr, prev.i1 - 1, nxt.i0 + 1))
    # a sweep (or ramp) that runs to the end of the trace
    last = plats[-1].i1 if plats else 0
    if last < len(t) - 1:
        if _extrema(tr.demand[last:]) >= 6:
            segs.append(Segment("sweep", last, len(t)))
        elif plats:
            segs.extend(ramps(tr, last - 1, len(t)))
    for p in plats:
        if t[p.i1 - 1] - t[p.i0] >= MIN_HOLD_S:
            segs.append(Segment("hold", p.i0, p.i1, dict(p.info)))
    en = tr.enable > 0.5
    rises = np.flatnonzero(~en[:-1] & en[1:]) + 1
    for i in np.flatnonzero(en[:-1] & ~en[1:]) + 1:
        back = rises[rises > i]
        segs.append(Segment("trip", int(i), int(back[0]) if len(back) else len(t)))
    # steps and holds end where the drive is disabled for the rest of them: a tripped valve is not being
    # positioned.  A drive disabled and enabled again within one (in real time a command watchdog's trip of a
    # few ms, re-enabled by the loop) leaves it whole: the valve is positioned again and its end error is the
    # plateau's (cut at the first disabled sample, a start-up step of the start-up profile with a 5 ms watchdog
    # trip mid-move read 3.8e-2 rad "end error" where the valve ended 3.4e-4 off: benchmarks/loop_stalls.py)
    for seg in segs:
        if seg.kind in ("step", "hold") and not en[seg.i1 - 1]:
            on = np.flatnonzero(en[seg.i0:seg.i1])
            seg.i1 = seg.i0 + (int(on[-1]) + 1 if len(on) else 0)
    segs = [s for s in segs if s.i1 - s.i0 >= 2 and not (s.kind == "hold" and t[s.i1 - 1] - t[s.i0] < MIN_HOLD_S)]
    segs.sort(key=lambda s: s.i0)
    return segs


# --------------------------------------------------------------------------- per segment
def step_metrics(tr: Trace, seg: Segment) -> dict:
    t = tr.t[seg.i0:seg.i1] - tr.t[seg.i0]
    pos = tr.position[seg.i0:seg.i1]
    r0, r1 = seg.info["from"], seg.info["to"]
    delta = r1 - r0
    sgn = 1.0 if delta > 0 else -1.0
    progress = sgn * (pos - r0) / abs(delta)         # 0 at start, 1 at the new demand
    out: dict = {"from_rad": r0, "to_rad": r1}
    i10 = np.flatnonzero(progress >= 0.1)
    i90 = np.flatnonzero(progress >= 0.9)
    if len(i10) and len(i90):
        out["rise_time_s"] = float(t[i90[0]] - t[i10[0]])
    out["overshoot_pct"] = float(max(0.0, (progress.max() - 1.0) * 100.0))
    band = max(0.02 * abs(delta), TENTH_DEGREE_RAD)
    outside = np.flatnonzero(np.abs(pos - r1) > band)
    if len(outside) == 0:
        out["settling_time_s"] = 0.0
    elif outside[-1] < len(pos) - 1:
        out["settling_time_s"] = float(t[outside[-1] + 1])
    else:
        out["settling_time_s"] = None
    half = len(pos) // 2
    out["steady_state_error_rad"] = float(abs(np.mean(r1 - pos[half:])))
    if abs(delta) >= 0.95 * tr.stroke_rad:
        reached = np.flatnonzero(progress >= 0.98)
        out["stroke_time_s"] = float(t[reached[0]]) if len(reached) else None
    return out


def hold_metrics(tr: Trace, seg: Segment) -> dict:
    mid = (seg.i0 + seg.i1) // 2
    pos = tr.position[mid:seg.i1]
    t = tr.t[mid:seg.i1]
    amp = 0.5 * float(np.ptp(pos))
    freq = 0.0
    if amp > RESOLVER_COUNT_RAD and len(pos) > 8:
        x = pos - np.mean(pos)
        dt = float(np.median(np.diff(t)))
        spec = np.abs(np.fft.rfft(x * np.hanning(len(x))))
        f = np.fft.rfftfreq(len(x), dt)
        spec[0] = 0.0
        freq = float(f[int(np.argmax(spec))])
    return {"demand_rad": seg.info["demand"], "limit_cycle_amplitude_rad": amp, "limit_cycle_frequency_hz": freq,
            "steady_state_error_rad": float(abs(np.mean(seg.info["demand"] - pos)))}


def sweep_metrics(tr: Trace, seg: Segment) -> dict:
    d = tr.demand[seg.i0:seg.i1]
    pos = tr.position[seg.i0:seg.i1]
    t = tr.t[seg.i0:seg.i1]
    centre = 0.5 * (d.max() + d.min())
    up = np.flatnonzero((d[:-1] - centre < 0) & (d[1:] - centre >= 0))
    freqs, gains = [], []
    for a, b in zip(up, up[1:]):
        dd = np.ptp(d[a:b + 1])
        if dd <= 0:
            continue
        freqs.append(1.0 / (t[b] - t[a]))
        gains.append(np.ptp(pos[a:b + 1]) / dd)
    if len(gains) < 3:
        return {}
    freqs, gains = np.array(freqs), np.array(gains)
    smooth = np.array([np.median(gains[max(i - 1, 0):i + 2]) for i in range(len(gains))])
    below = np.flatnonzero(smooth < MINUS_3DB)
    if len(below) == 0:
        bw = float(freqs.max())
    elif below[0] == 0:
        bw = 0.0
    else:
        i = below[0]
        f0, f1, g0, g1 = freqs[i - 1], freqs[i], smooth[i - 1], smooth[i]
        frac = (g0 - MINUS_3DB) / (g0 - g1) if g0 != g1 else 0.0
        bw = float(math.exp(math.log(f0) + frac * (math.log(f1) - math.log(f0))))
    return {"bandwidth_hz": bw, "frequencies_hz": freqs.round(3).tolist(), "gains": gains.round(4).tolist()}


def ramp_metrics(tr: Trace, seg: Segment) -> dict:
    """Tracking of a ramp from ``RAMP_SETTLE_S`` after its start: the largest |demand - angle|
    (rad) and the lag (s; the mean of demand - angle over the ramp's rate, + = valve behind)."""
    t = tr.t[seg.i0:seg.i1]
    dur = float(t[-1] - t[0])
    rate = (seg.info["to"] - seg.info["from"]) / dur
    w = t - t[0] >= RAMP_SETTLE_S
    out = {"from_rad": seg.info["from"], "to_rad": seg.info["to"], "rate_rad_s": float(rate)}
    if np.count_nonzero(w) < 2:
        return out
    err = tr.demand[seg.i0:seg.i1][w] - tr.position[seg.i0:seg.i1][w]
    out["ramp_max_error_rad"] = float(np.max(np.abs(err)))
    out["ramp_lag_s"] = float(np.mean(err) / rate)
    return out


def trip_metrics(tr: Trace, seg: Segment) -> dict:
    pos = tr.position[seg.i0:seg.i1]                 # (None: re-enabled before the valve closed)
    t = tr.t[seg.i0:seg.i1] - tr.t[seg.i0]
    closed = np.flatnonzero(pos <= 0.02 * tr.stroke_rad)
    return {"close_time_s": float(t[closed[0]]) if len(closed) else None}


# --------------------------------------------------------------------------- aggregate
def compute(tr: Trace) -> tuple[dict, list[dict]]:
    """(metrics of SPEC §5, per-segment details).  Absent metrics are omitted."""
    metrics: dict = {}
    details: list[dict] = []
    steps, holds, ramp_results = [], [], []
    for seg in find_segments(tr):
        if seg.kind == "step":
            m = step_metrics(tr, seg)
            steps.append(m)
        elif seg.kind == "hold":
            m = hold_metrics(tr, seg)
            holds.append(m)
        elif seg.kind == "sweep":
            m = sweep_metrics(tr, seg)
            if "bandwidth_hz" in m and "bandwidth_hz" not in metrics:
                metrics["bandwidth_hz"] = m["bandwidth_hz"]
        elif seg.kind == "ramp":
            m = ramp_metrics(tr, seg)
            if "ramp_max_error_rad" in m:
                ramp_results.append(m)
        elif seg.kind == "trip":
            m = trip_metrics(tr, seg)
            if metrics.get("close_time_s") is None:     # the first trip that closed the valve (a watchdog's
                metrics["close_time_s"] = m["close_time_s"]  # few ms re-enabled first do not)
        else:
            continue
        details.append({"kind": seg.kind, "t_start_s": float(tr.t[seg.i0]), "t_end_s": float(tr.t[seg.i1 - 1]), **m})
    if steps:
        rises = [s["rise_time_s"] for s in steps if "rise_time_s" in s]
        if rises:
            metrics["rise_time_s"] = max(rises)
        metrics["overshoot_pct"] = max(s["overshoot_pct"] for s in steps)
        settle = [s["settling_time_s"] for s in steps]
        metrics["settling_time_s"] = None if any(v is None for v in settle) else max(settle)
        strokes = [s["stroke_time_s"] for s in steps if "stroke_time_s" in s]
        if strokes:
            metrics["stroke_time_s"] = strokes[0]
    sse_sources = holds if holds else steps
    if sse_sources:
        metrics["steady_state_error_rad"] = max(s["steady_state_error_rad"] for s in sse_sources)
    if holds:
        worst = max(holds, key=lambda h: h["limit_cycle_amplitude_rad"])
        metrics["limit_cycle_amplitude_rad"] = worst["limit_cycle_amplitude_rad"]
        metrics["limit_cycle_frequency_hz"] = worst["limit_cycle_frequency_hz"]
    if ramp_results:
        worst = max(ramp_results, key=lambda r: r["ramp_max_error_rad"])
        metrics["ramp_max_error_rad"] = worst["ramp_max_error_rad"]
        metrics["ramp_lag_s"] = worst["ramp_lag_s"]
    metrics["peak_current_a"] = float(np.max(np.abs(tr.current)))
    metrics["rms_current_a"] = float(np.sqrt(np.mean(tr.current ** 2)))
    dt = np.diff(tr.t)
    err = np.abs(tr.demand - tr.position)
    metrics["iae_rad_s"] = float(np.sum(0.5 * (err[1:] + err[:-1]) * dt))
    return metrics, details


# --------------------------------------------------------------------------- plateau sequences
# (how hunting is counted lives in common.hunting: the fine stage counts reversals the same way)


def reversals(angle: np.ndarray, hysteresis: float = RESOLVER_COUNT_RAD) -> int:
    """Direction reversals of ``angle``, counting only moves larger than ``hysteresis``
    (:class:`~fuel_valve_control.common.hunting.ReversalCounter`)."""
    counter = ReversalCounter(float(angle[0]), hysteresis)
    for x in map(float, angle[1:]):
        counter.update(x)
    return counter.count


def plateau_results(tr: Trace, settle_s: float = HUNT_SETTLE_S) -> list[dict]:
    """Per step onto a plateau (see :func:`find_segments`): the step metrics plus

    * ``final_error_rad``: |demand - angle| at the plateau's last sample (where the valve was
      left before the next demand);
    * ``overshoot_rad``: largest excursion beyond the new demand;
    * ``hunting_amplitude_rad``: half peak-to-peak of the angle from ``settle_s`` after the step
      to the plateau's end, ``hunting_reversals``: reversals there (moves > 1 count);
      ``hunts``: both sustained (>= 2 reversals) and larger than ``HUNT_COUNTS`` counts.
    """
    out = []
    for seg in find_segments(tr):
        if seg.kind != "step":
            continue
        m = step_metrics(tr, seg)
        pos = tr.position[seg.i0:seg.i1]
        r0, r1 = seg.info["from"], seg.info["to"]
        sgn = 1.0 if r1 > r0 else -1.0
        m["final_error_rad"] = float(abs(r1 - pos[-1]))
        m["overshoot_rad"] = float(max(0.0, sgn * (pos.max() if sgn > 0 else pos.min()) - sgn * r1))
        late = pos[tr.t[seg.i0:seg.i1] - tr.t[seg.i0] >= settle_s]
        if len(late) >= 2:
            amp = 0.5 * float(np.ptp(late))
            rev = reversals(late)
        else:
            amp, rev = 0.0, 0
        m.update(hunting_amplitude_rad=amp, hunting_reversals=rev,
                 hunts=bool(rev >= HUNT_REVERSALS and amp > HUNT_COUNTS * RESOLVER_COUNT_RAD),
                 duration_s=float(tr.t[seg.i1 - 1] - tr.t[seg.i0]))
        out.append(m)
    return out


#: a plateau step counts for the plateau-step overshoot when it is at least this fraction of the
#: stroke (smaller steps are the fine stage's, where a count or two of overshoot is a large percent)
STEP_OVERSHOOT_MIN_FRACTION = 0.01
#: the plateau-step overshoot's tail is counted beyond these percentages of the step
STEP_OVERSHOOT_TAIL_PCT = (10.0, 50.0)


def plateau_step_overshoots(plateaus: list[dict], stroke_rad: float,
                            min_fraction: float = STEP_OVERSHOOT_MIN_FRACTION) -> list[float]:
    """**Plateau-step overshoot**: the overshoot (percent of the step: the largest excursion
    beyond the new demand over ``|to - from|``) of each plateau step of at least
    ``min_fraction`` of the stroke ``stroke_rad`` (rad), in the order given.  ``plateaus``:
    records with ``from_rad``, ``to_rad`` and ``overshoot_pct`` (:func:`plateau_results`)."""
    least = min_fraction * stroke_rad
    return [float(pl["overshoot_pct"]) for pl in plateaus
            if abs(pl["to_rad"] - pl["from_rad"]) >= least and pl.get("overshoot_pct") is not None]


def overshoot_tail(values, limits_pct=STEP_OVERSHOOT_TAIL_PCT) -> dict:
    """Distribution of overshoots (percent): ``n``, ``median``, ``p95``, ``max`` (None when
    there are none) and ``over_<L>`` = how many exceed each of ``limits_pct`` (percent)."""
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    out = {"n": int(len(v)), "median": None, "p95": None, "max": None}
    if len(v):
        out.update(median=float(np.median(v)), p95=float(np.percentile(v, 95)), max=float(v.max()))
    for lim in limits_pct:
        out[f"over_{lim:g}"] = int(np.count_nonzero(v > lim))
    return out


def jsonable(obj):
    """``obj`` with non-finite floats as None and numpy scalars as Python numbers, recursively
    (the JSON the tools print: strict JSON has no NaN or Infinity)."""
    if isinstance(obj, (np.floating, np.integer)):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    return obj

"""Demand profiles (percent of stroke over time), shared by the demand node and the simulator.

A profile is built from a mapping (YAML or ROS parameters) with a ``type``:

* ``constant``: ``percent``
* ``step``: ``initial``, ``final``, ``at_s``
* ``ramp``: ``initial``, ``final``, ``start_s``, ``duration_s``
* ``sine``: ``offset``, ``amplitude``, ``frequency_hz``
* ``chirp``: ``offset``, ``amplitude``, ``f0_hz``, ``f1_hz``, ``start_s``, ``duration_s`` (log sweep;
  ``offset`` before and after)
* ``points``: ``points`` = [[t, percent], ...], ``interpolation`` = ``previous`` | ``linear``
* ``startup``: the start-up to core-idle profile (23 -> 28 % ramps and steps, 20 s), see
  :data:`STARTUP_POINTS`
* ``csv``: ``path`` to a file with ``t,percent`` rows (a header line is allowed)
* ``plateaus``: a seeded random sequence of plateaus (robustness campaigns, SPEC §6):
  ``seed``, ``count``, ``initial`` (percent, also the value before ``start_s``), ``start_s``,
  ``min_step_pct``/``max_step_pct`` (step sizes, log-uniform, random sign; a step that would
  leave ``low``..``high`` percent goes the other way), ``hold_s`` (plateau length; a
  ``[min, max]`` pair draws it uniformly) and ``final_hold_s`` (length of the last plateau)

Any profile may add an analog-signal imperfection on top (what the supervisor's 4-20 mA
loop delivers, not what it means): ``noise_rms_pct`` (white noise, percent rms, sampled and
held every ``noise_sample_s``, default 1 ms, seeded by ``noise_seed``) and ``glitches``
(``[[t, percent], ...]``: one sample of ``noise_sample_s`` offset by that much).

``value(t)`` returns percent (0 = closed, 100 = open); ``nominal(t)`` the demand without
noise and glitches (what metrics judge the valve against).
"""
from __future__ import annotations

import bisect
import csv
import math
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from ..common.paramspec import RECORDED_TOPICS, ConfigError, Param, ParamSpec
from ..core.params import CONTROLLER_SPEC

# Start-up to core idle as in the field recordings (dissertation figs 2-1, 2-5): light-off
# and acceleration with the demand moving between 23 and 28 % in ramps and steps, then
# holding at core idle.  (t [s], percent); linear between points, a repeated time is a step.
STARTUP_POINTS = (
    (0.0, 0.0), (0.5, 0.0), (0.5, 23.0), (3.0, 23.0), (6.0, 25.0), (8.0, 25.0), (8.0, 26.0),
    (10.0, 26.0), (13.0, 28.0), (15.0, 28.0), (15.0, 27.0), (17.0, 27.0), (17.0, 27.5), (20.0, 27.5),
)


class ProfileError(ValueError):
    """A profile description is incomplete or inconsistent."""


class Profile:
    type = "base"
    duration_s = 0.0

    def value(self, t: float) -> float:
        raise NotImplementedError

    def nominal(self, t: float) -> float:
        """The demand as meant, without signal noise (percent)."""
        return self.value(t)


class Points(Profile):
    type = "points"

    def __init__(self, points, interpolation: str = "linear"):
        pts = [(float(t), float(p)) for t, p in points]
        if not pts:
            raise ProfileError("points profile needs at least one [t, percent] point")
        if any(b[0] < a[0] for a, b in zip(pts, pts[1:])):
            raise ProfileError("points profile times must not decrease")
        if interpolation not in ("linear", "previous"):
            raise ProfileError("interpolation must be 'linear' or 'previous'")
        self.points = pts
        self.times = [p[0] for p in pts]
        self.linear = interpolation == "linear"
        self.duration_s = pts[-1][0]

    def value(self, t: float) -> float:
        i = bisect.bisect_right(self.times, t)     # points[i-1].t <= t < points[i].t
        if i == 0:
            return self.points[0][1]
        if i >= len(self.points) or not self.linear:
            return self.points[i - 1][1]
        (t0, p0), (t1, p1) = self.points[i - 1], self.points[i]
        return p0 if t1 == t0 else p0 + (p1 - p0) * (t - t0) / (t1 - t0)


class Sine(Profile):
    type = "sine"

    def __init__(self, offset: float, amplitude: float, frequency_hz: float):
        self.offset, self.amplitude, self.frequency = offset, amplitude, frequency_hz

    def value(self, t: float) -> float:
        return self.offset + self.amplitude * math.sin(2.0 * math.pi * self.frequency * t)


class Chirp(Profile):
    """Logarithmic sine sweep from ``f0`` to ``f1`` starting at ``start_s``."""

    type = "chirp"

    def __init__(self, offset: float, amplitude: float, f0_hz: float, f1_hz: float, start_s: float,
                 duration_s: float):
        if not (0 < f0_hz < f1_hz) or duration_s <= 0:
            raise ProfileError("chirp needs 0 < f0_hz < f1_hz and duration_s > 0")
        self.offset, self.amplitude = offset, amplitude
        self.f0, self.f1, self.start, self.length = f0_hz, f1_hz, start_s, duration_s
        self.k = math.log(f1_hz / f0_hz) / duration_s
        self.duration_s = start_s + duration_s

    def value(self, t: float) -> float:
        tau = t - self.start
        if tau < 0.0 or tau > self.length:
            return self.offset
        phase = 2.0 * math.pi * self.f0 * (math.exp(self.k * tau) - 1.0) / self.k
        return self.offset + self.amplitude * math.sin(phase)


def plateau_points(seed: int, count: int, initial: float, start_s: float, min_step_pct: float,
                   max_step_pct: float, hold_s, final_hold_s: float, low: float = 5.0,
                   high: float = 95.0) -> list[tuple[float, float]]:
    """(t, percent) corners of a random plateau sequence (see the module docstring)."""
    if not 0.0 < min_step_pct <= max_step_pct or count < 1 or not low < high:
        raise ProfileError("plateaus needs 0 < min_step_pct <= max_step_pct, count >= 1, low < high")
    lo_hold, hi_hold = (hold_s, hold_s) if np.isscalar(hold_s) else (float(hold_s[0]), float(hold_s[1]))
    if not 0.0 < lo_hold <= hi_hold:
        raise ProfileError("plateaus hold_s must be > 0 (or a [min, max] pair)")
    rng = np.random.default_rng(int(seed))
    pct = min(max(float(initial), low), high)
    t = float(start_s)
    pts = [(0.0, pct)]
    for k in range(int(count)):
        size = math.exp(rng.uniform(math.log(min_step_pct), math.log(max_step_pct)))
        sign = 1.0 if rng.random() < 0.5 else -1.0
        if not low <= pct + sign * size <= high:
            sign = -sign
        pts += [(t, pct), (t, pct + sign * size)]
        pct += sign * size
        t += final_hold_s if k == count - 1 else rng.uniform(lo_hold, hi_hold)
    pts.append((t, pct))
    return pts


class Noisy(Profile):
    """A profile with analog-signal noise and single-sample glitches added (percent)."""

    BLOCK = 4096

    def __init__(self, inner: Profile, noise_rms_pct: float, seed: int, sample_s: float, glitches=()):
        if noise_rms_pct < 0.0 or sample_s <= 0.0:
            raise ProfileError("noise_rms_pct must be >= 0 and noise_sample_s > 0")
        self.inner, self.rms, self.sample_s = inner, float(noise_rms_pct), float(sample_s)
        self.type, self.duration_s = inner.type, inner.duration_s
        self._rng = np.random.default_rng(int(seed))
        self._noise = np.zeros(0)
        try:
            self._glitches = {int(math.floor(float(t) / self.sample_s + 1e-9)): float(p) for t, p in glitches}
        except (TypeError, ValueError):
            raise ProfileError("glitches must be [[t, percent], ...]") from None

    def _sample(self, k: int) -> float:
        while k >= len(self._noise):          # drawn in order, so any access pattern is reproducible
            self._noise = np.concatenate([self._noise, self._rng.standard_normal(self.BLOCK)])
        return self.rms * float(self._noise[k])

    def value(self, t: float) -> float:
        k = max(int(math.floor(t / self.sample_s + 1e-9)), 0)
        return self.inner.value(t) + self._sample(k) + self._glitches.get(k, 0.0)

    def nominal(self, t: float) -> float:
        return self.inner.nominal(t)


def _need(spec: Mapping[str, Any], *keys: str) -> list:
    missing = [k for k in keys if k not in spec]
    if missing:
        raise ProfileError(f"{spec.get('type')} profile needs {', '.join(missing)}")
    try:
        return [float(spec[k]) for k in keys]
    except (TypeError, ValueError):
        raise ProfileError(f"{spec.get('type')} profile: {', '.join(keys)} must be numbers") from None


def read_csv_points(path: str | Path) -> list[tuple[float, float]]:
    """``t,percent`` rows; a non-numeric first row is taken as a header."""
    rows = []
    try:
        with open(path, newline="") as f:
            for n, row in enumerate(csv.reader(f)):
                if not row or row[0].strip().startswith("#"):
                    continue
                try:
                    rows.append((float(row[0]), float(row[1])))
                except (ValueError, IndexError):
                    if n == 0:
                        continue
                    raise ProfileError(f"{path}:{n + 1}: expected 't,percent', got {row!r}") from None
    except OSError as exc:
        raise ProfileError(f"cannot read demand file {path}: {exc.strerror}") from None
    if not rows:
        raise ProfileError(f"{path}: no demand rows")
    return rows


def make_profile(spec: Mapping[str, Any], base_dir: Path | None = None) -> Profile:
    """Build a profile from its description (see the module docstring)."""
    profile = _make_clean(spec, base_dir)
    rms = spec.get("noise_rms_pct") or 0.0
    glitches = spec.get("glitches") or ()
    if rms or glitches:
        try:
            return Noisy(profile, float(rms), int(spec.get("noise_seed", 0)), float(spec.get("noise_sample_s", 1e-3)),
                         glitches)
        except (TypeError, ValueError):
            raise ProfileError("noise_rms_pct, noise_seed and noise_sample_s must be numbers") from None
    return profile


def _make_clean(spec: Mapping[str, Any], base_dir: Path | None) -> Profile:
    kind = spec.get("type")
    if kind == "constant":
        (pct,) = _need(spec, "percent")
        return Points([(0.0, pct)], "previous")
    if kind == "step":
        a, b, at = _need(spec, "initial", "final", "at_s")
        return Points([(0.0, a), (at, b)], "previous")
    if kind == "ramp":
        a, b, start, dur = _need(spec, "initial", "final", "start_s", "duration_s")
        return Points([(0.0, a), (start, a), (start + max(dur, 0.0), b)], "linear")
    if kind == "sine":
        return Sine(*_need(spec, "offset", "amplitude", "frequency_hz"))
    if kind == "chirp":
        return Chirp(*_need(spec, "offset", "amplitude", "f0_hz", "f1_hz", "start_s", "duration_s"))
    if kind == "points":
        if "points" not in spec:
            raise ProfileError("points profile needs points")
        return Points(spec["points"], spec.get("interpolation", "linear"))
    if kind == "startup":
        return Points(STARTUP_POINTS, "linear")
    if kind == "csv":
        if "path" not in spec:
            raise ProfileError("csv profile needs path")
        path = Path(spec["path"])
        if base_dir is not None and not path.is_absolute():
            path = base_dir / path
        return Points(read_csv_points(path), spec.get("interpolation", "linear"))
    if kind == "plateaus":
        seed, count, initial, start, lo, hi, final = _need(spec, "seed", "count", "initial", "start_s", "min_step_pct",
                                                           "max_step_pct", "final_hold_s")
        if "hold_s" not in spec:
            raise ProfileError("plateaus profile needs hold_s")
        return Points(plateau_points(int(seed), int(count), initial, start, lo, hi, spec["hold_s"], final,
                                     float(spec.get("low", 5.0)), float(spec.get("high", 95.0))), "previous")
    raise ProfileError(f"unknown profile type {kind!r}; allowed: constant, step, ramp, sine, chirp, points, "
                       f"startup, csv, plateaus")


PROFILE_TYPES = ("constant", "step", "ramp", "sine", "chirp", "points", "startup", "csv")


def _pct(name: str, default: float, description: str) -> Param:
    # a demand emulator may also send out-of-range demands (the controller clamps or rejects them)
    return Param(name, default, "%", description, -50.0, 150.0, runtime=True)


def _time(name: str, default: float, description: str) -> Param:
    return Param(name, default, "s", description, 0.0, 1e6, runtime=True)


#: the demand profile as ROS parameters of the ``demand`` node (all changeable at run time:
#: the new profile starts from the time of the change)
PROFILE_SPEC = ParamSpec("demand", [
    Param("profile", "startup", "", "demand profile type", choices=PROFILE_TYPES, runtime=True),
    _pct("percent", 20.0, "constant: demand"),
    _pct("initial", 20.0, "step/ramp: start value"),
    _pct("final", 22.0, "step/ramp: end value"),
    _time("at_s", 1.0, "step: time of the step"),
    _time("start_s", 1.0, "ramp/chirp: start time"),
    _time("duration_s", 10.0, "ramp/chirp: duration"),
    _pct("offset", 50.0, "sine/chirp: centre"),
    _pct("amplitude", 2.0, "sine/chirp: amplitude"),
    Param("frequency_hz", 1.0, "Hz", "sine: frequency", 0.0, 1000.0, runtime=True),
    Param("f0_hz", 0.5, "Hz", "chirp: start frequency", 0.0, 1000.0, low_open=True, runtime=True),
    Param("f1_hz", 20.0, "Hz", "chirp: end frequency", 0.0, 1000.0, low_open=True, runtime=True),
    Param("points", [0.0, 20.0], "s, %", "points: flat list t0, p0, t1, p1, ...", runtime=True),
    Param("interpolation", "linear", "", "points/csv: interpolation between points",
          choices=("linear", "previous"), runtime=True),
    Param("csv_path", "", "", "csv: file with t,percent rows", runtime=True),
])

#: parameters of the demand *node* only; its schema is :data:`DEMAND_NODE_SPEC` = these +
#: :data:`PROFILE_SPEC`, and ``config/demand.yaml`` is written from it
DEMAND_NODE_PARAMS = (
    Param("output", "percent", "", "percent: topic demand (%); ma: topic demand_ma (4-20 mA)",
          choices=("percent", "ma"), runtime=True),
    Param("publish_rate_hz", 200.0, "Hz", "publish rate in real time", 1.0, 10000.0),
    Param("lockstep", False, "", "publish once per /clock tick (deterministic lockstep runs)"),
    Param("tick_period_s", 1.0 / CONTROLLER_SPEC.params["loop_rate_hz"].default, "s",
          "lockstep: the control period the /clock ticks step by; a tick stamp within 0.1 us of k "
          "periods is evaluated at k * period, the time the offline simulator uses (the stamp's "
          "nanoseconds differ from it in the last bit, and a stick-slip breakaway can amplify that)",
          1e-5, 1.0),
    RECORDED_TOPICS,
)
DEMAND_NODE_SPEC = PROFILE_SPEC.extended(DEMAND_NODE_PARAMS)


def profile_from_params(values: Mapping[str, Any]) -> Profile:
    """The profile described by :data:`PROFILE_SPEC` values (validated first; raises
    :class:`ProfileError` with the reason)."""
    try:
        ps = PROFILE_SPEC.pick(values)
    except ConfigError as exc:
        raise ProfileError(str(exc)) from None
    flat = list(ps["points"])
    if len(flat) % 2:
        raise ProfileError("points must hold t, percent pairs")
    spec = {k: ps[k] for k in PROFILE_SPEC.params if k not in ("profile", "points", "csv_path")}
    spec.update(type=ps["profile"], points=list(zip(flat[0::2], flat[1::2])), path=ps["csv_path"])
    return make_profile(spec)

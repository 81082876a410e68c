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

``value(t)`` returns percent (0 = closed, 100 = open).
"""
from __future__ import annotations

import bisect
import csv
import math
from pathlib import Path
from typing import Any, Mapping

from ..common.paramspec import ConfigError, Param, ParamSpec

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
    raise ProfileError(f"unknown profile type {kind!r}; allowed: constant, step, ramp, sine, chirp, points, "
                       f"startup, csv")


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

"""Seconds <-> ``builtin_interfaces/Time`` stamps, written once for every node and tool.

In lockstep the plant's clock is the loop's clock: the plant stamps ``/clock`` and its
samples with its time, the demand node evaluates its profile at the ``/clock`` tick, and the
controller runs each period at the stamp of the resolver sample it answers.  The offline
simulator runs the same periods at ``k * period``.  ``sec + 1e-9 * nanosec`` differs from
``k * period`` in the last bit on many ticks, and the loop amplifies a last-bit difference
(a stick-slip breakaway, a threshold on a time difference): nodes and simulator then agree
with each other only to ~1e-6 rad.  So every stamp that stands for a loop period is read back
through :func:`stamp_seconds` with the loop's period, which gives exactly the simulator's float.

Times in s; stamps as ``(sec, nanosec)`` integers with ``0 <= nanosec < 1e9`` (ROS 2 Time).
"""
from __future__ import annotations

#: a stamp within this of a whole number of periods is that period's time (s): far below any
#: period (>= 1e-4 s) and far above the nanosecond rounding of a stamp
ON_GRID_S = 1e-7


def to_stamp(t: float) -> tuple[int, int]:
    """``t`` (s, >= 0) as ``(sec, nanosec)``, to the nearest nanosecond (a carry into the next
    second is taken: ``nanosec`` never reaches 1e9)."""
    sec = int(t)
    nanosec = int(round((t - sec) * 1e9))          # t - sec is exact: no error grows with sec
    return (sec + 1, nanosec - 1_000_000_000) if nanosec >= 1_000_000_000 else (sec, nanosec)


def stamp_seconds(sec: int, nanosec: int, period: float | None = None) -> float:
    """A stamp as seconds.  With the loop's ``period`` (s): ``k * period`` when the stamp is k
    periods (within :data:`ON_GRID_S`) -- exactly the float the offline simulator uses for
    period k -- and any other stamp as it is; without it ``sec + 1e-9 * nanosec``."""
    t = sec + 1e-9 * nanosec
    if period is None:
        return t
    k = round(t / period)
    return k * period if abs(t - k * period) < ON_GRID_S else t

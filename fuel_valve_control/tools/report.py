"""``fuel_valve_report BAG [--json PATH] [--plot PATH] [--trace PATH.csv] [--baseline PATH.json]``: SPEC §5 metrics of a recorded run.

Valve tests (issue 12): a bag with results on the controller's latched ``valve_test`` topic
(signature / partial-stroke runs) also gets them in the report (``valve_tests``) and, with
``--plot out.png``, the friction/hysteresis diagram of the latest run of each test in
``out_signature.png`` / ``out_partial_stroke.png``, drawn next to a baseline: the matching
completed result in ``--baseline`` (a JSON file: a result, or ``fuel_valve_sim --json`` /
``fuel_valve_report --json`` output), else the first completed run of that test in the bag.
``BAG`` may also be such a JSON file (an offline run): then only the diagrams are drawn.

Reads a bag (MCAP or sqlite3, from ``recorder`` or ``ros2 bag record``) with :mod:`.bag_io`,
rebuilds the trace the offline simulator logs and runs the *same* metric code on it
(:func:`fuel_valve_control.tools.metrics.compute`: step / hold / sweep / trip detection in the
demand).  Prints a readable report and one JSON line shaped like ``fuel_valve_sim``'s
output (``scenario`` = bag name, ``controller`` = the mode the controller reported on
``/diagnostics``, else ``"unknown"``, ``metrics``, ``segments``).  Bad input (not a bag,
empty, required topics missing): a message on stderr and exit code 2.  ``--trace`` writes
the reconstructed time series as CSV, in the columns of ``fuel_valve_sim --trace``
(:mod:`.trace`; what the bag lacks is left empty, the fault state always).

Trace reconstruction (all angles rad):

* time base and valve angle: ``joint_states`` (plant ground truth, header stamp = sample
  time), else ``resolver`` (measured), else the decimated ``position`` feedback;
* demand: ``demand`` (%), else ``demand_ma`` (4-20 mA); current: |(i_d, i_q)| from
  ``drive``, else |``current_command``|; enable: ``drive_enable`` (held between changes;
  assumed on when absent);
* topics without a header (demand, drive, current_command) are aligned with the time base
  one to one when they have exactly one message per sample (a lockstep run publishes each
  once per control period), otherwise by receive time (the value in force at each sample).
  Receive times in another clock than the stamps (``ros2 bag record`` without sim time
  on a lockstep run) are mapped onto sim time through ``/clock``.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from ..common import contract
from . import metrics as M
from ..core.valve_tests import PARTIAL_STROKE, SIGNATURE, load_baselines, results_in, unit_of
from .bag_io import Bag, BagError, TopicData, read_bag

REQUIRED = {
    "demand": ("demand", "demand_ma"),
    "valve angle": ("joint_states", "resolver", "position"),
    "current": ("drive", "current_command"),
}


class ReportError(Exception):
    """Input problem: exit code 2."""


def _stroke() -> float:
    return contract.STROKE_RAD


def _hold(src_t: np.ndarray, values: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Value in force at each ``t`` (zero-order hold; before the first sample: the first)."""
    idx = np.searchsorted(src_t, t, side="right") - 1
    return np.asarray(values, dtype=float)[np.clip(idx, 0, len(values) - 1)]


class _Timeline:
    """Maps a topic's samples onto the base time (seconds of the base's clock)."""

    def __init__(self, bag: Bag, base: TopicData, base_t_ns: np.ndarray, base_is_stamped: bool):
        self.base = base
        self.t_ns = base_t_ns
        self.to_base = None
        clock = bag.find("/clock")
        if base_is_stamped and clock is not None and len(clock) > 1:
            offset = np.median(base.log_ns - base.stamp_ns)
            if abs(offset) > 1e9:     # receive times in another clock: map them through /clock
                order = np.argsort(clock.log_ns, kind="stable")
                cl_log, cl_val = clock.log_ns[order], clock.stamp_ns[order]
                self.to_base = lambda ns: cl_val[np.clip(np.searchsorted(cl_log, ns, side="right") - 1, 0,
                                                         len(cl_val) - 1)]

    def time_of(self, topic: TopicData) -> np.ndarray:
        ns = topic.log_ns
        return self.to_base(ns) if self.to_base is not None else ns

    def align(self, topic: TopicData, values: np.ndarray) -> np.ndarray:
        n = len(self.t_ns)
        if len(topic) == n and len(self.base) == n:
            return np.asarray(values, dtype=float)          # one per sample: pair in order
        if topic.stamp_ns is not None:
            order = np.argsort(topic.stamp_ns, kind="stable")
            return _hold(topic.stamp_ns[order], np.asarray(values)[order], self.t_ns)
        tt = self.time_of(topic)
        order = np.argsort(tt, kind="stable")
        return _hold(tt[order], np.asarray(values)[order], self.t_ns)


def _first(bag: Bag, names) -> TopicData | None:
    for name in names:
        t = bag.find(name)
        if t is not None and len(t):
            return t
    return None


def build_series(bag: Bag, profile_s: float | None = None) -> tuple[M.Trace, dict, dict]:
    """(metrics trace, plot series, source notes) of a bag.

    ``profile_s``: the run's demand profile lasted this long (s) from the first demand message;
    samples after that (the suite shutting down: a controller stopped, the drive's watchdog or a
    stale-demand trip letting the spring close the valve) are left out, so the last plateau is
    judged on the run, not on the teardown.  None: the whole bag."""
    missing = [what + " (" + " | ".join(names) + ")" for what, names in REQUIRED.items()
               if _first(bag, names) is None]
    if missing:
        have = ", ".join(f"{n} [{c}]" for n, c in sorted(bag.counts.items())) or "none"
        raise ReportError(f"bag {bag.name} lacks messages for: {'; '.join(missing)}. Topics in the bag: {have}")
    stroke = _stroke()
    sources = {}
    base = _first(bag, ("joint_states", "resolver"))
    if base is not None and base.stamp_ns is not None and f"{'valve_shaft'}.position" in base:
        order = np.argsort(base.stamp_ns, kind="stable")
        if not np.all(order == np.arange(len(order))):
            base = _reorder(base, order)
        t_ns = base.stamp_ns
        position = base["valve_shaft.position"]
        stamped = True
        sources["position"] = base.topic + " (valve_shaft)"
    else:
        base = _first(bag, ("position",))
        t_ns = base.log_ns
        position = base["data"] / 100.0 * stroke
        stamped = False
        sources["position"] = base.topic + " (percent feedback)"
    # duplicated stamps (a republished sample) would make zero time steps: keep the first
    keep = np.concatenate([[True], np.diff(t_ns) > 0])
    tl = _Timeline(bag, base, t_ns, stamped)
    if not np.all(keep):
        base = _reorder(base, np.flatnonzero(keep))
        tl = _Timeline(bag, base, t_ns[keep], stamped)
        position = position[keep]
        t_ns = t_ns[keep]
    t0 = t_ns[0]
    t = (t_ns - t0) * 1e-9
    series: dict = {"t": t, "position": position}
    for key, column in (("motor", "motor_shaft.position"), ("velocity", "valve_shaft.velocity")):
        if column in base:
            series[key] = base[column]

    dem = _first(bag, ("demand",))
    if dem is not None:
        pct = dem["data"]
        sources["demand"] = dem.topic
    else:
        dem = _first(bag, ("demand_ma",))
        pct = np.clip((dem["data"] - 4.0) / 16.0 * 100.0, 0.0, 100.0)
        sources["demand"] = dem.topic + " (4-20 mA)"
    series["demand"] = tl.align(dem, pct / 100.0 * stroke)

    drive = _first(bag, ("drive",))
    if drive is not None and "i_d" in drive and "i_q" in drive:
        current = tl.align(drive, np.hypot(drive["i_d"], drive["i_q"]))
        series["i_d"] = tl.align(drive, drive["i_d"])
        series["i_q"] = tl.align(drive, drive["i_q"])
        for key, name in (("friction_valve", "friction_valve_nm"), ("friction_motor", "friction_motor_nm")):
            if name in drive:
                series[key] = -tl.align(drive, drive[name])
        sources["current"] = drive.topic + " |(i_d, i_q)|"
    else:
        cmd = _first(bag, ("current_command",))
        current = np.abs(tl.align(cmd, cmd["data"]))
        sources["current"] = cmd.topic + " (command)"
    cmd = _first(bag, ("current_command",))
    if cmd is not None:
        series["current_cmd"] = tl.align(cmd, cmd["data"])
    en = _first(bag, ("drive_enable",))
    if en is not None:
        enable = _hold(np.sort(tl.time_of(en)), en["data"][np.argsort(tl.time_of(en), kind="stable")], t_ns)
        sources["enable"] = en.topic
    else:
        enable = np.ones_like(t)
        sources["enable"] = "assumed on (no drive_enable)"
    series["enable"] = enable
    res = _first(bag, ("resolver",))
    if res is not None and res is not base and "valve_shaft.position" in res:
        series["measured"] = tl.align(res, res["valve_shaft.position"])
    est = _first(bag, ("estimate",))
    if est is not None:
        for key, name in (("friction_valve_est", "valve_shaft.effort"), ("friction_motor_est", "motor_shaft.effort")):
            if name in est:
                series[key] = tl.align(est, est[name])
    series["current"] = current
    if profile_s is not None:
        if not profile_s > 0.0:
            raise ReportError(f"the profile's duration must be positive, got {profile_s} s")
        end_ns = float(np.min(tl.time_of(dem))) + profile_s * 1e9
        n = int(np.searchsorted(t_ns, end_ns, side="right"))
        if n < 2:
            raise ReportError(f"bag {bag.name}: no position samples within {profile_s} s of the first demand")
        if n < len(t):
            series = {k: (v[:n] if isinstance(v, np.ndarray) and len(v) == len(t) else v) for k, v in series.items()}
            sources["profile"] = f"the first {profile_s:g} s from the first demand (the rest: shutdown)"
            t, position, current, enable = series["t"], series["position"], series["current"], series["enable"]
    trace = M.Trace(t, series["demand"], position, current, enable, stroke)
    return trace, series, sources


def _reorder(topic: TopicData, idx: np.ndarray) -> TopicData:
    return TopicData(topic.topic, topic.msgtype, topic.log_ns[idx],
                     None if topic.stamp_ns is None else topic.stamp_ns[idx],
                     {k: v[idx] for k, v in topic.columns.items()})


def controller_mode(bag: Bag) -> str:
    for name, values in bag.diagnostics.items():
        if "valve driver" in name and values.get("mode"):
            return str(values["mode"])
    return "unknown"




def valve_test_results(bag: Bag) -> list[dict]:
    """The valve-test results recorded on the ``valve_test`` topic(s), in recording order."""
    out = []
    for topic, texts in bag.texts.items():
        if topic.rstrip("/").rsplit("/", 1)[-1] != contract.VALVE_TEST:
            continue
        for text in texts:
            try:
                out.extend(results_in(json.loads(text)))
            except ValueError:
                continue                     # not ours: a foreign String on a same-named topic
    return out


def plot_valve_tests(results: list[dict], plot: str | Path, baselines: list[dict] = ()) -> list[str]:
    """Diagram of the latest completed run of each test in ``results`` next to its baseline
    (the test's first result in ``baselines``, else its first completed run in ``results``
    when that is another run); written beside ``plot`` as ``<stem>_<test>.png``."""
    from .plotting import plot_valve_test
    written = []
    plot = Path(plot)
    for name in (SIGNATURE, PARTIAL_STROKE):
        runs = [r for r in results if r.get("test") == name and r.get("status") == "completed"]
        if not runs:
            continue
        stored = [b for b in baselines if b.get("test") == name]
        base = stored[0] if stored else (runs[0] if len(runs) > 1 else None)
        path = plot.with_name(f"{plot.stem}_{name}{plot.suffix or '.png'}")
        written.append(plot_valve_test(runs[-1], str(path), base))
    return written


def analyse(bag: Bag, profile_s: float | None = None) -> tuple[dict, dict]:
    """(report dict, plot series) of a bag already read (``profile_s``: :func:`build_series`)."""
    if bag.message_count == 0:
        raise ReportError(f"bag {bag.name} is empty (no messages)")
    trace, series, sources = build_series(bag, profile_s)
    metrics, segments = M.compute(trace)
    doc = {"scenario": bag.name, "controller": controller_mode(bag), "metrics": metrics,
           "sim_time_s": float(trace.t[-1] - trace.t[0]), "segments": segments,
           "bag": {"path": str(bag.path), "storage": bag.storage, "messages": bag.message_count,
                   "topics": dict(sorted(bag.counts.items())), "sources": sources}}
    tests = valve_test_results(bag)
    if tests:
        doc["valve_tests"] = tests
    return M.jsonable(doc), series


def analyse_bag(path: str | Path, plot: str | Path | None = None, trace: str | Path | None = None,
                baselines: list[dict] = (), profile_s: float | None = None) -> dict:
    """SPEC §5 metrics of the bag at ``path`` as ``fuel_valve_sim`` reports them (plus a
    ``bag`` section); writes the multi-panel PNG to ``plot`` and the time-series CSV
    (:mod:`.trace`) to ``trace`` when given.  Raises :class:`ReportError` /
    :class:`~.bag_io.BagError` for bad input.  ``profile_s``: judge only the run's profile
    (:func:`build_series`)."""
    doc, series = analyse(read_bag(path), profile_s)
    if trace:
        from .trace import write_trace
        write_trace(trace, series)
    if plot:
        from .plotting import plot_series
        plot_series(series, str(plot), f"{doc['scenario']} - mode {doc['controller']} (bag)", doc["segments"],
                    doc["metrics"])
        doc["valve_test_plots"] = plot_valve_tests(doc.get("valve_tests", []), plot, baselines)
    return doc


UNITS = {"rise_time_s": "s", "overshoot_pct": "%", "settling_time_s": "s", "steady_state_error_rad": "rad",
         "limit_cycle_amplitude_rad": "rad", "limit_cycle_frequency_hz": "Hz", "peak_current_a": "A",
         "rms_current_a": "A", "stroke_time_s": "s", "close_time_s": "s", "bandwidth_hz": "Hz", "iae_rad_s": "rad*s"}


def format_report(doc: dict) -> str:
    b = doc["bag"]
    lines = [f"bag {b['path']} ({b['storage']}, {b['messages']} messages, {doc['sim_time_s']:.3f} s)",
             f"controller mode: {doc['controller']}",
             "sources: " + "; ".join(f"{k} <- {v}" for k, v in b["sources"].items()),
             "segments:"]
    for s in doc["segments"]:
        extra = ""
        if s["kind"] == "step":
            extra = f" {s['from_rad']:.4f} -> {s['to_rad']:.4f} rad"
        elif s["kind"] == "hold":
            extra = f" at {s['demand_rad']:.4f} rad"
        elif s["kind"] == "ramp" and "ramp_max_error_rad" in s:
            extra = f" {s['rate_rad_s']:+.2e} rad/s, max error {s['ramp_max_error_rad']:.2e} rad"
        lines.append(f"  {s['kind']:<6} {s['t_start_s']:8.3f} - {s['t_end_s']:8.3f} s{extra}")
    if not doc["segments"]:
        lines.append("  (no steps, holds, ramps, sweeps or trips found in the demand)")
    for res in doc.get("valve_tests", []):
        figs = res.get("figures") or {}
        lines.append(f"valve test {res.get('test')}: {res.get('status')}" + (f" ({res['reason']})" if res.get("reason") else "")
                     + "".join(f", {k} {figs[k]:.4g} {unit_of(k)}" for k in ("friction_mean_nm", "breakaway_open_nm",
                                                                              "breakaway_close_nm", "breakaway_nm")
                               if isinstance(figs.get(k), (int, float))))
        lines.extend(f"  {f}" for f in res.get("findings") or [])
    lines.append("metrics:")
    for key, value in doc["metrics"].items():
        text = "n/a (not reached)" if value is None else f"{value:.6g} {UNITS.get(key, '')}"
        lines.append(f"  {key:<27} {text}")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="fuel_valve_report", description="SPEC §5 metrics of a recorded "
                                     "fuel_valve run (rosbag2 bag, MCAP or sqlite3).")
    parser.add_argument("bag", help="bag directory (or its .mcap / .db3 file), or a JSON file of valve-test "
                        "results (fuel_valve_sim --json of a config/valve_tests scenario): diagrams only")
    parser.add_argument("--json", metavar="PATH", help="also write the JSON result here")
    parser.add_argument("--plot", metavar="PATH", help="write a multi-panel PNG here")
    parser.add_argument("--trace", metavar="PATH.csv", help="write the run's time series here (CSV, the columns "
                        "of fuel_valve_sim --trace)")
    parser.add_argument("--baseline", metavar="PATH.json", help="valve tests: draw the diagrams next to the "
                        "completed results in this JSON file (default: the first run of each test)")
    parser.add_argument("--profile-s", type=float, metavar="S", help="the run's demand profile lasted S s from "
                        "its first demand message: judge only that, not the suite's shutdown after it "
                        "(fuel_valve_demo passes its profile's duration)")
    args = parser.parse_args(argv)
    try:
        baselines = load_baselines(args.baseline) if args.baseline else []
        if args.bag.endswith(".json"):
            return _report_json(args.bag, args.plot, baselines)
        doc = analyse_bag(args.bag, args.plot, args.trace, baselines, args.profile_s)
    except (BagError, ReportError, OSError, ValueError) as exc:
        print(f"fuel_valve_report: error: {exc}", file=sys.stderr)
        return 2
    print(format_report(doc))
    print(json.dumps(doc))
    if args.json:
        with open(args.json, "w") as f:
            f.write(json.dumps(doc, indent=2) + "\n")
    return 0


def _report_json(path: str, plot: str | None, baselines: list[dict]) -> int:
    """``fuel_valve_report RESULTS.json``: the valve-test results of an offline run."""
    with open(path) as f:
        results = results_in(json.load(f))
    if not results:
        raise ReportError(f"{path}: no valve-test results in it")
    for res in results:
        figs = res.get("figures") or {}
        print(f"{res['test']}: {res['status']} {res.get('reason') or ''}")
        for key, value in figs.items():
            text = "n/a" if not isinstance(value, (int, float)) else f"{value:.6g} {unit_of(key)}"
            print(f"  {key:<36} {text}")     # n/a: NaN, written as null by fuel_valve_sim --json
        for finding in res.get("findings") or []:
            print(f"  {finding}")
    if plot:
        for written in plot_valve_tests(results, plot, baselines):
            print(f"diagram: {written}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

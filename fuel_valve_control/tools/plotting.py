"""Multi-panel PNG of a run, shared by ``fuel_valve_sim --plot`` and ``fuel_valve_report --plot``.

Input is a mapping of equal-length arrays on a common time base (missing keys are skipped):

``t`` [s], ``demand`` [rad], ``position`` [rad] (true valve angle), ``measured`` [rad]
(resolver), ``current_cmd`` [A], ``i_q`` / ``i_d`` [A], ``friction_valve`` /
``friction_valve_est`` [N*m], ``friction_motor`` / ``friction_motor_est`` [N*m], ``enable``.

Panels: demand vs position, error, currents, true vs estimated friction, and a zoom on the
settled window (the limit-cycle view), whose span is chosen from the metrics segments when
given, otherwise the last quarter of the run.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

RESOLVER_COUNT_RAD = 2.0 * np.pi / 65536


def plot_series(series: Mapping[str, np.ndarray], path: str, title: str = "",
                segments: Sequence[Mapping] | None = None, metrics: Mapping | None = None) -> str:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.asarray(series["t"])
    fig, axes = plt.subplots(5, 1, figsize=(11, 13), constrained_layout=True)
    ax = axes[0]
    if "demand" in series:
        ax.plot(t, np.degrees(series["demand"]), "k-", lw=1.2, label="demand")
    if "position" in series:
        ax.plot(t, np.degrees(series["position"]), "r-", lw=1.0, label="valve (true)")
    if "measured" in series:
        ax.plot(t, np.degrees(series["measured"]), "b:", lw=0.8, label="resolver")
    ax.set_ylabel("angle [deg]")
    ax.legend(loc="best", fontsize=8)
    ax.set_title(title)

    ax = axes[1]
    if "demand" in series and "position" in series:
        err = np.asarray(series["demand"]) - np.asarray(series["position"])
        ax.plot(t, err * 1e3, "m-", lw=0.8)
        ax.axhline(0.0, color="k", lw=0.5)
    ax.set_ylabel("error [mrad]")

    ax = axes[2]
    for key, style, label in (("current_cmd", "k-", "command"), ("i_q", "g-", "i_q"), ("i_d", "c-", "i_d")):
        if key in series:
            ax.plot(t, series[key], style, lw=0.8, label=label)
    ax.axhline(37.0, color="r", lw=0.5, ls="--")
    ax.axhline(-37.0, color="r", lw=0.5, ls="--")
    ax.set_ylabel("current [A]")
    ax.legend(loc="best", fontsize=8)

    ax = axes[3]
    for key, style, label in (("friction_valve", "r-", "valve true"), ("friction_valve_est", "r--", "valve est."),
                              ("friction_motor", "b-", "motor true x N"),
                              ("friction_motor_est", "b--", "motor est. x N")):
        if key in series:
            y = np.asarray(series[key])
            if key.startswith("friction_motor"):
                y = y * 48.019
            ax.plot(t, y, style, lw=0.8, label=label)
    ax.set_ylabel("friction [N*m]")
    ax.legend(loc="best", fontsize=8)

    ax = axes[4]
    lo, hi = _zoom_window(t, segments)
    sel = (t >= lo) & (t <= hi)
    if "position" in series and np.any(sel):
        pos = np.asarray(series["position"])[sel]
        ax.plot(t[sel], (pos - np.mean(pos)) / RESOLVER_COUNT_RAD, "r-", lw=0.8, label="valve - mean")
        if "demand" in series:
            d = np.asarray(series["demand"])[sel]
            ax.plot(t[sel], (d - np.mean(pos)) / RESOLVER_COUNT_RAD, "k-", lw=0.8, label="demand - mean")
    ax.set_ylabel("zoom [resolver counts]")
    ax.set_xlabel("time [s]")
    label = f"settled window {lo:.2f}-{hi:.2f} s"
    if metrics and metrics.get("limit_cycle_amplitude_rad") is not None:
        label += (f": limit cycle {metrics['limit_cycle_amplitude_rad']:.2e} rad at "
                  f"{metrics.get('limit_cycle_frequency_hz', 0):.2f} Hz")
    ax.set_title(label, fontsize=9)
    ax.legend(loc="best", fontsize=8)
    for a in axes[:4]:
        a.grid(True, alpha=0.3)
    axes[4].grid(True, alpha=0.3)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _zoom_window(t: np.ndarray, segments) -> tuple[float, float]:
    holds = [s for s in (segments or []) if s.get("kind") == "hold"]
    if holds:
        h = max(holds, key=lambda s: s["t_end_s"] - s["t_start_s"])
        return 0.5 * (h["t_start_s"] + h["t_end_s"]), h["t_end_s"]
    return t[0] + 0.75 * (t[-1] - t[0]), t[-1]


def plot_result(result, path: str) -> str:
    """Plot a :class:`~fuel_valve_control.tools.sim.SimResult`."""
    series = result.series()
    title = f"{result.scenario} - mode {result.controller}"
    return plot_series(series, path, title, result.segments, result.metrics)


def _nan(values) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], dtype=float)


def plot_valve_test(result: Mapping, path: str, baseline: Mapping | None = None, title: str = "") -> str:
    """The friction/hysteresis diagram of a valve-test result (core/valve_tests.py): drive
    torque at the valve vs position in both directions (raw samples light, per-bin levels
    bold; a ``baseline`` result dashed), and friction vs position next to the baseline's."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, axf) = plt.subplots(1, 2, figsize=(13, 5.5), constrained_layout=True)
    trace = result.get("trace") or {}
    if trace.get("position_pct"):
        pos, tq = _nan(trace["position_pct"]), _nan(trace["torque_nm"])
        up = np.array(trace["opening"], dtype=bool)
        ax.plot(pos[up], tq[up], ".", color="tab:red", ms=1.5, alpha=0.3, label="opening (samples)")
        ax.plot(pos[~up], tq[~up], ".", color="tab:blue", ms=1.5, alpha=0.3, label="closing (samples)")
    for res, style, who in ((result, "-", "this run"), (baseline, "--", "baseline")):
        curve = (res or {}).get("curve") or {}
        if not curve.get("position_pct"):
            continue
        x = _nan(curve["position_pct"])
        ax.plot(x, _nan(curve["torque_open_nm"]), style, color="darkred", lw=2, label=f"opening, {who}")
        ax.plot(x, _nan(curve["torque_close_nm"]), style, color="navy", lw=2, label=f"closing, {who}")
        axf.plot(x, _nan(curve["friction_nm"]), style, color="k", lw=2,
                 label=f"{who}: {res['figures'].get('friction_mean_nm', float('nan')):.3f} N*m "
                       f"at {res.get('pressure_kpa', 0):.0f} kPa")
    figs = result.get("figures", {})
    ax.set_xlabel("valve position [% of stroke]")
    ax.set_ylabel("drive torque at the valve [N*m]")
    ax.set_title(title or f"{result.get('test')} test ({result.get('status')}): torque vs position", fontsize=10)
    ax.legend(loc="best", fontsize=8)
    ax.grid(True, alpha=0.3)
    axf.set_xlabel("valve position [% of stroke]")
    axf.set_ylabel("friction = (opening - closing) / 2 [N*m]")
    axf.set_ylim(0.0, 1.3 * max(axf.get_ylim()[1], 1e-3))     # a flat friction line off the frame
    lines = [f"{k} = {figs[k]:.4g}" for k in ("friction_mean_nm", "breakaway_open_nm", "breakaway_close_nm",
                                              "breakaway_nm", "spring_rate_nm_per_rad", "spring_preload_nm",
                                              "hysteresis_pct", "deadband_pct", "travel_time_out_s",
                                              "friction_to_baseline_ratio")
             if isinstance(figs.get(k), (int, float))]
    lines += list(result.get("findings") or []) or ["no findings"]
    axf.set_title("\n".join(lines), fontsize=8, loc="left")
    axf.legend(loc="lower right", fontsize=8)
    axf.grid(True, alpha=0.3)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path

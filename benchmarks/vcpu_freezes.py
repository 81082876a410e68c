#!/usr/bin/env python3
"""Controller freezes against the drive's command watchdog, offline: the valve around a
watchdog trip and the driver's re-arm.

Why: in the real-time soak every plant watchdog trip (10-12 per 3 min) came with a 6-9 ms
freeze of the controller and of the other processes on the same vCPU (the demand node's
messages stop too), on a 100 ms wall-clock grid; a SCHED_FIFO 50 probe pinned to each CPU sees
the same 6.4-6.9 ms freezes, so they are the host descheduling this VM's vCPUs, beyond any
priority inside it.  The product has to ride through them: the drive (5 ms watchdog) switches
itself off and reports it, the driver re-arms and re-enables it.

The loop here is the offline simulator's (``fuel_valve_sim``'s exchange), on the soak's demand
(a 40 ± 20 % sine at 0.1 Hz), with freezes: nobody steps the driver for ``n`` periods, the
drive (``tools/loop_stalls.StalledDrive``, the plant node's rules) holds the last command or the
controller's fallback for its command timeout (``contract.DRIVE_COMMAND_TIMEOUT_S``) and is then
off, reports ``watchdog`` and stays off until the driver re-enables it;
after the freeze the driver gets the report and the latest sample only (depth-1 topics).
Measured after the first second: the valve's excess over the highest demand of the trailing
0.5 s and its shortfall under the lowest (soak.py's window), percent of stroke, re-arms.

Also: shorter freezes (3-4 ms: late periods, no trip) on plateau sequences of 0.1-0.5 % steps,
whose plateaus the fine stage finishes with timed pulses; a late period stretches the pulse in
force, and ``thrown_rad`` is how far a valve that had arrived was thrown off its plateau, with
the driver's late-loop guard (``fine.late_loop_holdoff_s``) and without it.

    python benchmarks/vcpu_freezes.py [--seconds 20] [--plateau-seeds 10]

Last line: one JSON object.
"""
from __future__ import annotations

import argparse
import json
import math

import numpy as np

from fuel_valve_control.common import contract
from fuel_valve_control.common.contract import STROKE_RAD
from fuel_valve_control.core.driver import ValveDriver
from fuel_valve_control.core.params import load_controller_params
from fuel_valve_control.tools import sim
from fuel_valve_control.tools.loop_stalls import LoopStalls, StalledDrive
from fuel_valve_plant.physics.params import load_plant_params
from fuel_valve_plant.physics.plant import Plant

#: the soak's demand (benchmarks/soak.py DEMAND), percent, from its trough on (t0 = 7.5 s)
SINE_OFFSET, SINE_AMPLITUDE, SINE_HZ, SINE_T0 = 40.0, 20.0, 0.1, 7.5
#: judged from this time on, s (the start-up move before it), over this trailing window, s
START_S, WINDOW_S = 1.0, 0.5
#: a plateau demand: a valve within this of its plateau has arrived (about half the nominal
#: stick-slip jump at max Δp: what the main law's hold leaves), rad
ARRIVED_RAD = 2.5e-3
#: length of a plateau-sequence run (12 plateaus of 0.6 s after the start), s
PLATEAU_SECONDS = 8.0


def soak_demand(t: float) -> float:
    return SINE_OFFSET + SINE_AMPLITUDE * math.sin(2.0 * math.pi * SINE_HZ * (SINE_T0 + t))


def plateau_demand(seed: int = 0, start_pct: float = 30.0, steps: int = 40, hold_s: float = 0.6,
                   low_pct: float = 0.1, high_pct: float = 2.0):
    """A plateau sequence (the robustness campaign's kind of demand, percent): from
    ``start_pct``, ``steps`` random steps of ``low_pct``..``high_pct`` either way, ``hold_s``
    apart; held at the last one after."""
    rng = np.random.default_rng(seed)
    levels = [start_pct]
    for _ in range(steps):
        levels.append(levels[-1] + rng.choice([-1.0, 1.0]) * rng.uniform(low_pct, high_pct))

    def demand(t: float) -> float:
        return levels[min(int(t / hold_s), len(levels) - 1)]
    demand.hold_s = hold_s
    return demand


def regular_freezes(freeze_periods: int, every_s: float, seconds: float, period: float) -> dict[int, int]:
    """{first period: length in periods} of a freeze every ``every_s`` from :data:`START_S` on."""
    every = int(round(every_s / period))
    return {k: freeze_periods for k in range(int(round(START_S / period)), int(round(seconds / period)), every)}


def random_freezes(low: int, high: int, mean_every_s: float, seconds: float, period: float, seed: int = 0) -> dict[int, int]:
    """Freezes of ``low``..``high`` periods, exponentially distributed ``mean_every_s`` apart."""
    rng = np.random.default_rng(seed)
    out, k, end = {}, int(round(START_S / period)), int(round(seconds / period))
    while True:
        k += int(rng.exponential(mean_every_s) / period) + high + 1
        if k >= end:
            return out
        out[k] = int(rng.integers(low, high + 1))


def simulate_freezes(freezes: dict[int, int], seconds: float, demand=soak_demand,
                     controller_overrides: dict | None = None) -> dict:
    """Closed loop with controller ``freezes`` ({first period: periods}); returns the valve's
    largest ``excess_pct`` over / ``shortfall_pct`` under the trailing window's demand, the
    ``freezes``, the driver's ``rearms`` and the ``driver`` itself (its state at the end)."""
    plant = Plant(load_plant_params(overrides={"pressure_sensor.noise_kpa": 0.0}))
    drv = ValveDriver(load_controller_params(overrides=controller_overrides or {}))
    period = drv.period
    # the drive (the plant node's rules, tools/loop_stalls.StalledDrive): without a command the last one or the
    # fallback the controller set (contract.CURRENT_FALLBACK, fine.pulse_fallback: a doublet's next step; docs
    # §113) for its command timeout, then off until a drive_enable true reaches it (a re-enable or an enable edge)
    drive = StalledDrive(LoopStalls(command_timeout_periods=int(round(contract.DRIVE_COMMAND_TIMEOUT_S / period))))
    reported = contract.DRIVE_STATE_ENABLED
    drv.drive_status(0.0, reported)
    n = int(round(seconds / period))
    started, left = False, 0
    valve, dem = np.empty(n), np.empty(n)
    for k in range(n):
        t = k * period
        if k in freezes and started:
            left = freezes[k]
        if left:                               # frozen: nobody steps the driver
            plant.set_command(*drive.no_command())
            left -= 1
        else:
            # the drive's state word reaches the driver before the period (after a freeze: its watchdog trip;
            # after a re-enable: on again), then the controller node's real-time timing check, before the period
            # as in the node (it ran after the period until stop 30: the first period after a freeze still ran
            # the stage's stale sequence, §113)
            if drive.state != reported:
                reported = drive.state
                drv.drive_status(t, reported)
            drv.loop_timing(t, t)
            out, _ = sim.exchange_period(drv, plant, t, demand(t))
            started = True
            plant.set_command(*drive.command(out))
            if drv.after_period():             # the work left for after the command, as the node does it
                drive.fallback(drv.fallback_currents())
        plant.advance(period)
        valve[k] = 100.0 * plant.truth().valve_angle / STROKE_RAD
        dem[k] = demand(t + period)
    start, window = int(round(START_S / period)), int(round(WINDOW_S / period))
    excess = max(valve[k] - dem[k - window:k + 1].max() for k in range(start, n))
    shortfall = max(dem[k - window:k + 1].min() - valve[k] for k in range(start, n))
    out = {"excess_pct": float(excess), "shortfall_pct": float(shortfall), "freezes": len(freezes),
           "rearms": drv.stall_rearms, "late": drv.late_loop_events, "faults": sorted(drv.last.faults),
           "driver": drv}
    hold_s = getattr(demand, "hold_s", None)
    if hold_s is not None:
        # a plateau demand: how far a valve that had arrived (within ARRIVED_RAD of its plateau)
        # was thrown off it later on the same plateau, rad (largest over the plateaus from START_S)
        err = np.abs(valve - dem) / 100.0 * STROKE_RAD
        per = int(round(hold_s / period))
        thrown = 0.0
        for k0 in range(int(round(START_S / period)) // per * per + per, n - per + 1, per):
            e = err[k0:k0 + per - 1]
            arrived = np.flatnonzero(e < ARRIVED_RAD)
            if arrived.size:
                thrown = max(thrown, float(e[arrived[0]:].max()))
        out["thrown_rad"] = thrown
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--plateau-seeds", type=int, default=10, help="plateau sequences per late-loop case")
    args = parser.parse_args()
    period = 1.0 / load_controller_params()["loop_rate_hz"]
    cases = {
        "none": {},
        "7 ms every 0.5 s": regular_freezes(7, 0.5, args.seconds, period),
        "9 ms every 0.5 s": regular_freezes(9, 0.5, args.seconds, period),
        "2-4 ms, mean every 0.3 s": random_freezes(2, 4, 0.3, args.seconds, period),
        "1-15 ms, mean every 0.1 s (starved)": random_freezes(1, 15, 0.1, args.seconds, period),
    }
    out = {}
    for name, freezes in cases.items():
        r = simulate_freezes(freezes, args.seconds)
        r.pop("driver")
        out[name] = {k: round(v, 3) if isinstance(v, float) else v for k, v in r.items()}
        print(f"{name:<38} excess {r['excess_pct']:6.2f} %  shortfall {r['shortfall_pct']:6.2f} %  "
              f"freezes {r['freezes']:4d}  re-arms {r['rearms']:4d}  faults {r['faults']}", flush=True)
    # short freezes (late periods, no watchdog trip) on plateaus the fine stage finishes with
    # timed pulses: how far a valve that had arrived is thrown, with the late-loop guard
    # (fine.late_loop_holdoff_s, default) and without it (0)
    plateaus = {}
    for late in (3, 4):
        freezes = regular_freezes(late, 0.25, PLATEAU_SECONDS, period)
        for guard, overrides in (("guard", {}), ("no guard", {"fine.late_loop_holdoff_s": 0.0})):
            thrown = [simulate_freezes(freezes, PLATEAU_SECONDS, plateau_demand(seed, steps=12, high_pct=0.5),
                                       overrides)["thrown_rad"] for seed in range(args.plateau_seeds)]
            name = f"plateaus, {late} ms late every 0.25 s, {guard}"
            q = {"median": float(np.median(thrown)), "p95": float(np.percentile(thrown, 95)), "max": max(thrown)}
            plateaus[name] = {k: float(f"{v:.3g}") for k, v in q.items()}
            print(f"{name:<46} thrown median {q['median']:.2e} p95 {q['p95']:.2e} max {q['max']:.2e} rad "
                  f"({args.plateau_seeds} sequences)", flush=True)
    print(json.dumps({"seconds": args.seconds, "cases": out, "plateaus": plateaus}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

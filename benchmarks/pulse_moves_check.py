#!/usr/bin/env python3
"""Validate the plant-free doublet move model (``core/pulse_moves.py``) against the plant (task h33m, docs §80).

Two parts:

1. **bare** (:func:`bare_check`): random (direction, excess, overdrive, aim) points, each doublet replayed on the
   bare nominal :class:`Plant` (max Δp, no scatter / ripple, static level ``T_c + K x``) started at rest with the
   twist at the preload (``apex - rise``; the drive holding it plus the motor's Coulomb friction, as after the
   park's climb), the FinePositioner's doublet currents and its observe servo on the plant's true states --
   the model's own idealisations, so what is compared is the dynamics.
2. **closed** (:func:`closed_check`): the default controller on nominal-box runs (``benchmarks/robustness.py
   --box nominal``); at each of the stage's doublets the plant's true twist at the kick, its drawn levels
   (``valve_friction_levels``), load and the stage's servo target (as an aim relative to the true Coulomb
   equilibrium), then the apex the kick reached (coupling torque / K above the preload) and the valve's move;
   compared with the model's rise and its predicted move at that excess / overdrive / aim.

3. **grid** (:func:`grid_check`, ``--grid``: only it): the keyed tables (Δp x angle grid, interpolated: the
   default) against the exact per-key tables, and the cost of ``prepare()`` / of a ``move()`` after it.

    python benchmarks/pulse_moves_check.py [--grid] [--pairs 12] [--dp-grid 0,0.25,...] [--angle-grid 0,0.5,1] [--points 150] [--dp-fraction 1] [--runs 40] [--seed 1000] [--jobs 2] [--json PATH]

Last stdout line: one JSON object.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from multiprocessing import Pool
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "benchmarks"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from fuel_valve_control.core.fine_positioning import IDLE, OBSERVE, PULSE  # noqa: E402
from fuel_valve_control.core.params import CONTROLLER_SPEC  # noqa: E402
from fuel_valve_control.core.position_controller import PositionController  # noqa: E402
from fuel_valve_control.core.pulse_moves import PulseMoves  # noqa: E402
from fuel_valve_plant.physics import kernel as KN  # noqa: E402
from fuel_valve_plant.physics.params import PLANT_SPEC  # noqa: E402
from fuel_valve_plant.physics.plant import Plant  # noqa: E402

CS = CONTROLLER_SPEC.defaults()
FINE = PositionController(CS).law.fine
M = FINE.m
P_MAX = M.pressure_max_kpa
K = M.coupling_stiffness_nm_per_rad
FL = M.friction(P_MAX)
X_NOM = (FL.valve_static_nm - FL.valve_coulomb_nm) / K


def model() -> PulseMoves:
    return PulseMoves.for_positioner(FINE, CS)


def plant_doublet(d: int, excess: float, overdrive: float, aim: float, rise: float, p: float = P_MAX) -> float:
    """The valve's move (rad toward ``d``) on the bare nominal plant at Δp ``p`` (see the module docstring)."""
    ps = PLANT_SPEC.defaults()
    fl = M.friction(p)
    ts = fl.valve_coulomb_nm + K * excess
    pl = Plant(ps.replace({"pressure_differential_kpa": p,
                           "friction.valve.static_per_dp_nm": (ts - ps["friction.valve.static_nm"]) / M.pressure_fraction(p)}))
    theta = 0.5 * M.stroke_rad
    pl.hold_at(theta)
    n, kt, cfg = M.gear_ratio, M.torque_constant_nm_per_a, FINE.cfg
    load = M.load_torque(theta, p)
    phi = (load + d * ts) / K + d * (overdrive - rise)
    hold = (K * phi / n + d * fl.motor_coulomb_nm) / kt
    pl.S[KN.S_THM] = (theta + phi) * n
    pl.S[KN.S_IQ] = hold
    pl.S[KN.S_XQ] = ps["motor.resistance_ohm"] * hold
    pl.set_command(hold, True)
    ref = theta + (load + d * fl.valve_coulomb_nm) / K + d * aim / 2.0
    cap, integral, per = cfg.peak_current_a, 0.0, FINE.period
    th1_prev = pl.truth().motor_angle / n
    for k in range(2 + cfg.retreat_full_periods + cfg.observe_periods):
        t = pl.truth()
        th1, thl = t.motor_angle / n, t.valve_angle
        if k == 0:
            iq = hold + d * cfg.kick_current_a
        elif k <= cfg.retreat_full_periods:
            iq = hold - d * cap
        elif k == cfg.retreat_full_periods + 1:
            iq = hold - d * 0.5 * cap
        else:
            e = ref - th1
            integral += e * per
            iq = (K * (ref - thl) / n + (FINE.kp * e - FINE.kd * (th1 - th1_prev) / per + FINE.ki * integral) / n) / kt
        th1_prev = th1
        pl.set_command(min(max(iq, -cap), cap), True)
        pl.advance(per)
    return d * (pl.valve_angle - theta)


def bare_check(points: int, seed: int, dp_fraction: float = 1.0) -> dict:
    pm = model()
    rng = np.random.default_rng(seed)
    p = dp_fraction * P_MAX
    fl = M.friction(p)
    x_nom = (fl.valve_static_nm - fl.valve_coulomb_nm) / K
    rows = []
    for d in (1, -1):
        rise = pm.rise(d, p)
        for _ in range(points):
            x = rng.uniform(0.3, 2.3) * x_nom
            od = float(np.exp(rng.uniform(np.log(5e-6), np.log(2e-3))))
            aim = rng.uniform(0.0, 1.5e-3) * x_nom / X_NOM
            rows.append((d, x, od, aim, plant_doublet(d, x, od, aim, rise, p), float(pm.move(d, p, x, od, aim_rad=aim))))
    a = np.array(rows)
    fin = np.isfinite(a[:, 5])
    e = np.abs(a[fin, 5] - a[fin, 4])
    return {"points": len(a), "model_nan": int((~fin).sum()),
            "plant_move_where_nan_median_rad": float(np.median(a[~fin, 4])) if (~fin).any() else None,
            "abs_err_p50": float(np.median(e)), "abs_err_p95": float(np.percentile(e, 95)), "abs_err_max": float(e.max()),
            "within_10pct_or_1e-4": float(np.mean(e <= np.maximum(0.1 * a[fin, 4], 1e-4))),
            "dp_fraction": dp_fraction, "rise_rad": {str(d): pm.rise(d, p) for d in (1, -1)},
            "build_cpu_s": [pm.table(d, p)["build_s"] for d in (1, -1)]}


def grid_check(pairs: int = 12, points: int = 500, seed: int = 11, dp_grid=None, angle_grid=None,
               dp_range=(0.02, 1.0)) -> dict:
    """The keyed model (tables on the Δp x angle grid, interpolated) against the exact per-key tables (one per
    (direction, Δp, angle)) at ``pairs`` random (Δp, angle) per direction, ``points`` random (excess, overdrive, aim)
    each over the policy's domain at that Δp (excess 0.3-1.6 x the nominal excess, overdrive log 1e-3-1 jump, aim
    0-1 jump); also the cost of ``prepare()`` and of a ``move()`` on a 61 x 40 array after it."""
    kw = {} if dp_grid is None else {"dp_grid": dp_grid}
    if angle_grid is not None:
        kw["angle_grid"] = angle_grid

    keyed = PulseMoves.for_positioner(FINE, CS, **kw)
    # the reference: h33m's tables (one per Δp and angle, every aim simulated)
    exact = PulseMoves.for_positioner(FINE, CS, exact=True, coarse_aims=False)
    prep_s = keyed.prepare()
    runs = keyed.runs
    rng = np.random.default_rng(seed)
    errs, refs, nanmis, lost, n_all, rise_err = [], [], 0, 0, 0, []
    for d in (1, -1):
        for _ in range(pairs):
            p = float(rng.uniform(*dp_range)) * P_MAX
            th = float(rng.uniform(0.0, 1.0)) * M.stroke_rad
            fl = M.friction(p)
            xn = (fl.valve_static_nm - fl.valve_coulomb_nm) / K
            j = 2.0 * xn
            x = rng.uniform(0.3, 1.6, points) * xn
            od = np.exp(rng.uniform(np.log(1e-3 * j), np.log(j), points))
            aim = rng.uniform(0.0, 1.0, points) * j
            a = keyed.move(d, p, x, od, aim_rad=aim, valve_angle_rad=th)
            b = exact.move(d, p, x, od, aim_rad=aim, valve_angle_rad=th)
            fa, fb = np.isfinite(a), np.isfinite(b)
            nanmis += int((fa != fb).sum())
            lost += int((~fa & fb).sum())
            n_all += points
            errs.append(np.abs(a - b)[fa & fb])
            refs.append(np.abs(b)[fa & fb])
            rise_err.append(abs(keyed.rise(d, p, valve_angle_rad=th) - exact.rise(d, p, valve_angle_rad=th)))
    e, r = np.concatenate(errs), np.concatenate(refs)
    # a policy's call after prepare(): 61 draws x 40 candidate apexes, nothing built
    xx = np.linspace(0.5, 1.5, 61)[:, None] * X_NOM
    oo = np.geomspace(1e-5, 2e-3, 40)[None, :]
    t0 = time.process_time()
    for _ in range(50):
        keyed.move(1, 0.83 * P_MAX, xx, oo, aim_rad=4e-4, valve_angle_rad=0.41)
    move_ms = (time.process_time() - t0) / 50 * 1e3
    return {"dp_grid": [float(v) for v in keyed.dp_grid / P_MAX], "angle_grid": [float(v) for v in keyed.angle_grid / M.stroke_rad],
            "tables": keyed.builds, "prepare_cpu_s": prep_s, "points": n_all, "nan_mismatch": nanmis,
            "keyed_nan_exact_finite": lost, "exact_finite": int(sum(len(v) for v in errs)) + lost,
            "abs_err_p50": float(np.median(e)), "abs_err_p95": float(np.percentile(e, 95)),
            "abs_err_max": float(e.max()), "within_5pct_or_5e-5": float(np.mean(e <= np.maximum(0.05 * r, 5e-5))),
            "within_10pct_or_1e-4": float(np.mean(e <= np.maximum(0.1 * r, 1e-4))),
            "rise_abs_err_max": float(max(rise_err)), "move_61x40_ms": move_ms,
            "runs_after_prepare": keyed.runs - runs,
            "table_cpu_s_keyed_vs_reference": [float(np.mean([t["build_s"] for t in keyed._tables.values()])),
                                              float(np.mean([t["build_s"] for t in exact._tables.values()]))]}

def _closed_run(job) -> list[dict]:
    """The stage's doublets on nominal-box run ``seed`` (``job``: a seed, or (seed, controller sets)): per doublet the
    plant's truth at the kick (twist, drawn levels, load, the stage's servo target as an aim) and, with
    ``fine.apex_policy``, what the policy saw: the planned apex and kick, the stage's φe / learned level / scatter,
    its measured twist at the kick and the measured apex (``_kick_apex``), all as absolute twists, rad."""
    import robustness as R
    from fuel_valve_control.tools import sim

    seed, sets = (job, {}) if isinstance(job, int) else job
    plan, plant, driver = R.held_case(R.sample_case(seed, "nominal"), None, sets)
    per = driver.period
    fine = driver.controller.law.fine
    seen = {}
    upd = fine.update

    def update(target, th1, thl, *a, **kw):      # the stage's own readings (measured th1, thl, Δp)
        seen["th1"], seen["thl"] = th1, thl
        seen["p"] = a[-1] if a else kw.get("pressure_kpa")
        return upd(target, th1, thl, *a, **kw)
    fine.update = update
    kk = plan.plant_params["coupling.stiffness_nm_per_rad"]
    n = plan.plant_params["gearbox.ratio"]
    cc = plan.plant_params["coupling.damping_nms"]
    rows, cur, prev = [], None, IDLE
    for k in range(int(round(plan.duration_s / per))):
        t = k * per
        if fine.phase == PULSE and fine._doublet and fine._k == 0 and cur is None:
            # the next output is a doublet's kick: the true state now
            tr = plant.truth()
            d = fine._dir
            tc, ts = plant.valve_friction_levels()
            load = float(plant.O[KN.O_TSPRING] + plant.O[KN.O_TFLOW])
            phi = tr.motor_angle / n - tr.valve_angle
            kick = fine.cfg.kick_current_a * (fine.cfg.first_kick_fraction if fine._first_stair else 1.0)
            cur = {"seed": seed, "d": d, "thl0": tr.valve_angle, "phi0": phi, "x": (ts - tc) / kk,
                   "pre_rel": d * (phi - (load + d * ts) / kk),
                   "aim": 2.0 * d * (fine._final - (load + d * tc) / kk), "apex": -1.0, "kick": kick,
                   "level": (load + d * ts) / kk, "phi_e": (load + d * tc) / kk, "p": plant.params["pressure_differential_kpa"]}
            if fine.cfg.apex_policy and fine._apex_kick is not None and fine._apex_try is not None:
                phi_e_s, phi_b_s, band = fine._twists(seen["thl"], seen["p"], d)
                e0, b0 = fine._nominal(seen["thl"], seen["p"], d)
                cur.update(phi_e0=e0, phi_b0=b0)
                plan_ = fine._apex_plan           # (apex, P(land), P(no move), score, kick, mean move if moved)
                cur.update(kick=fine._apex_kick, policy=True, apex_plan=plan_[0], p_land=plan_[1], p_none=plan_[2],
                           m_mean=plan_[5], pre_plan=fine._pre, rise_plan=fine._apex_rise,
                           phi_m=seen["th1"] - seen["thl"], phi_e_s=phi_e_s, phi_b_s=phi_b_s,
                           sigma_s=fine._scatter(d, band, max(d * (phi_b_s - phi_e_s), 1e-5)),
                           err_s=fine._target - seen["thl"], p_s=seen["p"], thl_s=seen["thl"])
        out, _ = sim.exchange_period(driver, plant, t, plan.demand.value(t))
        plant.set_command(out.current_a, out.enable)
        if cur is None:
            plant.advance(per)
        else:
            for _ in range(plant.steps_for(per)):
                plant.step(1)
                tr = plant.truth()
                tk = kk * (tr.motor_angle / n - tr.valve_angle) + cc * (tr.motor_velocity / n - tr.valve_velocity)
                cur["apex"] = max(cur["apex"], cur["d"] * (tk / kk - cur["phi0"]))
        if cur is not None and ((fine.phase != OBSERVE and prev == OBSERVE) or (fine.phase == IDLE and prev != IDLE)):
            cur["move"] = cur["d"] * (plant.valve_angle - cur["thl0"])
            cur["apex_meas"] = fine._kick_apex    # the highest twist the stage read (a stale value if it left early)
            rows.append(cur)
            cur = None
        prev = fine.phase
    return rows


def _policy_rows(rows: list[dict], pm: PulseMoves, tol: float) -> dict:
    """(``fine.apex_policy``) The policy's doublets per kick: the measured move against the model's, read
    (T) at the plant's true excess and overdrive (the true preload + the model's rise above the true level: §80.3's
    check), (A) at the true excess but the overdrive of the *planned* apex over the true level, the level taken into
    the stage's measured coordinates (its twist reading's offset at the kick), (S) at the stage's φe too (excess
    from it), and (L) the policy's own expectation given a move (its law's mean).  Ratios measured / predicted are
    over the tries that moved (> tol / 2) with a finite, non-zero prediction; offsets in rad (toward the try)."""
    out = {}
    pol = [r for r in rows if r.get("policy")]
    kset = sorted(FINE.cfg.kick_current_a * 2.0 ** np.arange(0, 4))      # 4 / 8 / 16 / 32 A: the report's bins

    def label(k):            # a continuous kick (fine.apex_kick_continuous) reported with the nearest of 4 / 8 / 16 A
        return float(min(kset, key=lambda v: abs(math.log(k / v))))

    def at(fn, kick, *a, **kw):
        # the model at a kick between the set's: linear in the kick between the neighbouring set kicks (the policy's
        # own reading, FinePositioner._continuous_kick), so no table is built per continuous kick
        if any(abs(kick - v) < 1e-9 for v in kset):
            return float(fn(*a, kick_current_a=kick, **kw))
        lo = max(v for v in kset if v < kick)
        hi = min(v for v in kset if v > kick)
        t = (kick - lo) / (hi - lo)
        return (1 - t) * float(fn(*a, kick_current_a=lo, **kw)) + t * float(fn(*a, kick_current_a=hi, **kw))
    for kick in sorted({label(r["kick"]) for r in pol}):
        rs = [r for r in pol if label(r["kick"]) == kick]
        o = {"tries": len(rs)}
        mv = np.array([r["move"] for r in rs])
        moved = mv > 0.5 * tol
        o["moved"] = int(moved.sum())
        o["landed_4e-4"] = int(sum(1 for r, m in zip(rs, moved) if m and abs(abs(r["err_s"]) - r["move"]) <= 4e-4))
        dm = np.array([r["phi_m"] - r["phi0"] for r in rs])           # measured - true twist at the kick
        d = np.array([r["d"] for r in rs])
        lvl_m = np.array([r["level"] for r in rs]) + dm                 # the true level in measured coordinates
        # offsets, toward the try
        o["park_err_med"] = float(np.median(d * (np.array([r["phi_m"] for r in rs]) - np.array([r["pre_plan"] for r in rs]))))
        o["rise_true_med"] = float(np.median([r["apex"] for r in rs]))
        o["rise_plan_med"] = float(np.median([r["rise_plan"] for r in rs]))
        o["apex_true_minus_plan_med"] = float(np.median(d * (np.array([r["phi_m"] + r["d"] * r["apex"] for r in rs])
                                                            - np.array([r["apex_plan"] for r in rs]))))
        o["learned_minus_level_med"] = float(np.median(d * (np.array([r["phi_b_s"] for r in rs]) - lvl_m)))
        o["learned_minus_level_sigmas_med"] = float(np.median(d * (np.array([r["phi_b_s"] for r in rs]) - lvl_m)
                                                               / np.array([r["sigma_s"] for r in rs])))
        o["phi_e_s_minus_true_med"] = float(np.median(d * (np.array([r["phi_e_s"] for r in rs])
                                                          - (np.array([r["phi_e"] for r in rs]) + dm))))
        mr = [r for r, m in zip(rs, moved) if m]
        if mr:
            o["meas_apex_minus_level_moved_med"] = float(np.median([r["d"] * (r["apex_meas"] - r["level"] - (r["phi_m"] - r["phi0"])) for r in mr]))
            o["true_apex_minus_level_moved_med"] = float(np.median([r["pre_rel"] + r["apex"] for r in mr]))
            o["plan_apex_minus_level_moved_med"] = float(np.median([r["d"] * (r["apex_plan"] - r["level"] - (r["phi_m"] - r["phi0"])) for r in mr]))
        preds = {}
        for r in mr:
            dmr = r["phi_m"] - r["phi0"]
            k_r = r["kick"]
            rise = at(pm.rise, k_r, r["d"], r["p"], valve_angle_rad=r["thl0"])
            aim = abs(r["err_s"])
            od_a = r["d"] * (r["apex_plan"] - r["level"] - dmr)
            x_s = r["d"] * (r["level"] + dmr - r["phi_e_s"])
            x_n = r["d"] * (r["level"] + dmr - r.get("phi_e0", r["phi_e_s"]))     # (N) from the stage model's φe
            for key, x, od in (("T", r["x"], r["pre_rel"] + rise), ("A", r["x"], od_a), ("S", x_s, od_a), ("N", x_n, od_a)):
                v = at(pm.move, k_r, r["d"], r["p"], x, od, aim_rad=aim, valve_angle_rad=r["thl0"]) if od > 0 else 0.0
                preds.setdefault(key, []).append(v)
            preds.setdefault("L", []).append(r["m_mean"])
        mvm = mv[moved]
        for key, v in preds.items():
            v = np.array(v)
            ok = np.isfinite(v) & (v > 0)
            o[f"ratio_{key}_median"] = float(np.median(mvm[ok] / v[ok])) if ok.any() else None
            o[f"ratio_{key}_n"] = int(ok.sum())
            o[f"err_{key}_median_rad"] = float(np.median(v[ok] - mvm[ok])) if ok.any() else None
        o["move_median"] = float(np.median(mvm)) if len(mvm) else None
        out[f"{kick:g}"] = o
    return out


def closed_check(runs: int, seed: int, jobs: int, sets: dict | None = None, rows_out: list | None = None) -> dict:
    """The closed-loop check (module docstring, 2.) on ``runs`` nominal-box runs from ``seed`` with the controller
    ``sets`` (e.g. ``{"fine.apex_policy": True, "fine.apex_kick_max_a": 16.0}``: then also the policy's tries per
    kick, :func:`_policy_rows`); ``rows_out``: a list that receives every doublet's row."""
    sets = dict(sets or {})
    jobs_ = [(s, sets) for s in range(seed, seed + runs)]
    if jobs > 1:
        with Pool(jobs) as pool:
            parts = pool.map(_closed_run, jobs_, chunksize=1)
    else:
        parts = [_closed_run(j) for j in jobs_]
    rows = [r for part in parts for r in part]
    if rows_out is not None:
        rows_out.extend(rows)
    if sets:
        from fuel_valve_control.core.fine_positioning import _pulse_moves
        cs = CONTROLLER_SPEC.load(None, sets)
        pm = _pulse_moves(PositionController(cs).law.fine)
    else:
        pm = model()
    tol = FINE.cfg.tolerance_rad
    rise = {d: pm.rise(d, P_MAX) for d in (1, -1)}
    d_ = np.array([r["d"] for r in rows])
    mv = np.array([r["move"] for r in rows])
    od = np.array([r["pre_rel"] + rise[r["d"]] for r in rows])
    apex = np.array([r["apex"] for r in rows])
    kset = FINE.cfg.kick_current_a * 2.0 ** np.arange(0, 4)
    kick_of = (lambda k: float(min(kset, key=lambda v: abs(math.log(k / v)))))   # a continuous kick: nearest of the set
    pred = np.array([float(pm.move(r["d"], P_MAX, r["x"], o, kick_current_a=kick_of(r["kick"]) if r.get("policy") else r["kick"],
                                   aim_rad=max(r["aim"], 0.0)))
                     for r, o in zip(rows, od)])
    moved = np.abs(mv) > 0.5 * tol
    nan = np.isnan(pred)
    pmoved = ~nan & (pred > 0.5 * tol)
    both = moved & pmoved
    e = pred[both] - mv[both]
    out = {"doublets": len(rows), "plant_moved": int(moved.sum()), "model_nan": int(nan.sum()),
           "model_nan_plant_moved": int((nan & moved).sum()),
           "moved_both": int(both.sum()), "plant_moved_model_still": int((moved & ~pmoved & ~nan).sum()),
           "plant_still_model_moved": int((~moved & pmoved).sum()),
           "plant_still_model_moved_overdrive_max_rad": float(od[~moved & pmoved].max()) if (~moved & pmoved).any() else None,
           "move_err_median_rad": float(np.median(e)), "move_err_p10_rad": float(np.percentile(e, 10)),
           "move_err_p90_rad": float(np.percentile(e, 90)), "move_abs_err_p90_rad": float(np.percentile(np.abs(e), 90)),
           "plant_move_median_rad": float(np.median(mv[both]))}
    for d in (1, -1):
        s = ~moved & (d_ == d)
        out[f"rise_measured_median_rad_{d:+d}"] = float(np.median(apex[s])) if s.any() else None
        out[f"rise_model_rad_{d:+d}"] = rise[d]
    if any(r.get("policy") for r in rows):
        out["policy_by_kick"] = _policy_rows(rows, pm, tol)
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=150, help="random points per direction (bare check)")
    ap.add_argument("--runs", type=int, default=40, help="nominal-box runs (closed check; 0: skip)")
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--dp-fraction", type=float, default=1.0, help="Δp of the bare check, x max (the closed check: the nominal box's max Δp)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--grid", action="store_true", help="only the keyed grid against the exact per-key tables")
    ap.add_argument("--pairs", type=int, default=12, help="random (Δp, angle) per direction (grid check)")
    ap.add_argument("--dp-grid", type=str, default=None, help="comma-separated Δp grid, x max (grid check)")
    ap.add_argument("--angle-grid", type=str, default=None, help="comma-separated angle grid, x stroke (grid check)")
    ap.add_argument("--dp-range", type=str, default="0.02,1.0", help="Δp range of the grid check's random points, x max")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="controller.KEY=VALUE",
                    help="controller parameter of the closed check's runs (e.g. controller.fine.apex_policy=true)")
    ap.add_argument("--closed-only", action="store_true", help="only the closed-loop check")
    ap.add_argument("--rows", type=Path, help="write the closed check's doublets (one row each) here as JSON")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    t0 = time.time()
    from fuel_valve_control.common.paramspec import parse_overrides
    sets = parse_overrides(a.overrides, ("controller",))["controller"] if a.overrides else {}
    if a.closed_only:
        rows = []
        res = {"closed": closed_check(a.runs, a.seed, a.jobs, sets, rows), "controller_sets": sets,
               "wall_s": round(time.time() - t0, 1)}
        if a.rows:
            a.rows.write_text(json.dumps(rows))
        if a.json:
            a.json.write_text(json.dumps(res, indent=1))
        print(json.dumps(res))
        return
    fl = (lambda v: None if v is None else [float(u) for u in v.split(",")])
    res = {"grid": grid_check(a.pairs, dp_grid=fl(a.dp_grid), angle_grid=fl(a.angle_grid),
                              dp_range=fl(a.dp_range))}
    print("grid:", json.dumps(res["grid"]), flush=True)
    if a.grid:
        print(json.dumps(res))
        return
    res["bare"] = bare_check(a.points, 7, a.dp_fraction)
    print("bare:", json.dumps(res["bare"]), flush=True)
    if a.runs > 0:
        res["closed"] = closed_check(a.runs, a.seed, a.jobs, sets)
        print("closed:", json.dumps(res["closed"]), flush=True)
    res["wall_s"] = round(time.time() - t0, 1)
    if a.json:
        a.json.write_text(json.dumps(res, indent=1))
    print(json.dumps(res))


if __name__ == "__main__":
    main()

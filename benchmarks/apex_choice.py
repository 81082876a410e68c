#!/usr/bin/env python3
"""CPU time of the apex policy's choice per try (task h37a, docs §94).

``fine.apex_policy`` plans each doublet's apex and kick in :meth:`FinePositioner._choose_apex`, once per try *inside*
the control period's callback (1 ms at 1 kHz).  This benchmark runs nominal-box campaign cases
(``benchmarks/robustness.py --box nominal``'s :func:`run_case`, the same construction: seeds ``--seed``...) with the
C1 build (the apex policy and its companions, docs §2) and the level law(s) asked, and times every ``_choose_apex``
call with the calling thread's CPU clock (``time.thread_time``).  A call during which the move model built a table
(~0.12 s of simulation, once per key and process: the stage builds them ahead where a period's budget matters) is
counted apart ("built"), not in the per-try distribution.  Prints per law: tries, median / p95 / max (ms) and, with
``--profile``, the cProfile of the choice calls (top functions by total time; its overhead then counts in the times:
profile and time in separate runs).  Each call's outcome (apex, kick, rise) is kept in ``--json``: two builds choose
alike when their lists are equal.  Last line: one JSON object.

    python benchmarks/apex_choice.py [--runs 3] [--seed 1000] [--law normal|mixture|both] [--profile] [--compare]
                                     [--replay R] [--set controller.KEY=VALUE ...] [--json PATH]

``--replay R`` (task h40m, docs §106): every recorded try re-run R times, the laws alternating; each try's minimum CPU.
"""
from __future__ import annotations

import argparse
import copy
import cProfile
import io
import json
import pstats
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for _p in (ROOT, ROOT / "benchmarks"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

from fuel_valve_control.common.paramspec import parse_overrides  # noqa: E402
from fuel_valve_control.core import fine_positioning as F  # noqa: E402

#: the C1 build (docs §2, stop 25): the apex policy with its companions
C1 = {"fine.apex_policy": True, "fine.apex_kick_max_a": 16.0, "fine.apex_retreat_periods": 2,
      "fine.retreat_cap": True, "fine.observe_hold_moved": True, "fine.apex_excess_nominal": True}
LAWS = ("normal", "mixture")


def reference_choose_apex(self, err: float, d: int, phi_e: float, phi_b: float, sigma: float, pressure_kpa: float,
                 short: float, thl: float) -> float | None:
    """The apex policy's choice as main built it (``FinePositioner._choose_apex`` at commit f293bde: its set-up
    verbatim but for the module prefix ``F.``, its scoring loop the one the stage keeps as ``_score_tables``; since task
    h38x (docs §99) the weighted sums through ``F._wsum`` / ``F._beyond_best``:
    main's BLAS products for the "normal" law, the fixed-order sums for the others): the reference the fast choice must
    equal bit for bit (``--compare``, and test/test_apex_policy.py).  ``self``: the :class:`FinePositioner`; arguments and effects as the method's."""
    cfg = self.cfg
    if self._moves is None:
        self._moves = F._pulse_moves(self)
    lv, w = self._apex_law(d, phi_b, sigma, pressure_kpa)
    # the model's tables are keyed by Δp and angle: read at 1 % of the rated Δp (the measured Δp's noise would
    # build a new table at every try, 0.15 s of CPU each; the levels change < 1 % over it) and 0.01 rad
    step = F.APEX_DP_STEP * self.m.pressure_max_kpa
    pressure_kpa = round(pressure_kpa / step) * step
    top = lv[-1] if d * (lv[-1] - lv[0]) > 0 else lv[0]
    cand = np.concatenate([lv, top + d * sigma * np.linspace(0.1, 1.5, 8)])
    fl = self._floor(d)
    if fl is not None:
        cand = cand[d * (cand - fl[1]) > 0.0]
    if len(cand) == 0:
        return None
    if cfg.apex_excess_nominal:
        # (task h34m, docs §85) the move model's excess is the level above the Coulomb equilibrium of the model
        # it was built from (load + T_c)/K; the learned φe is the swing centre of the stage's own moves
        # (φ_final - move / 2), which lies 0.14-0.21e-3 rad further toward the try (nominal box), and read the
        # moves 1.3-1.4 x short
        phi_e = self._nominal(thl, pressure_kpa, d)[0]
    od = d * (cand[:, None] - lv[None, :])               # [a, k] overdrive, rad
    excess = np.broadcast_to(np.maximum(d * (lv - phi_e), 0.0)[None, :], od.shape)   # the level above φe
    moved = od > 0.0
    e, s, tol = abs(err), max(cfg.apex_move_sd_rad, 1e-9), cfg.apex_land_rad
    lo = 0.0 if short > 0.0 else -tol
    worse_edge = 0.0 if short > 0.0 else -e
    # (task h38x, docs §99) the weighted sums of every law but "normal" without BLAS, in a fixed order
    # (F._wsum / F._beyond_best, FinePositioner._fixed_sums; "normal": main's BLAS products, as f293bde had them)
    p_none = F._wsum((~moved).astype(float), w, self._fixed_sums())
    beyond = d * (lv[None, :] - cand[:, None]) > 0.0
    break_limit = float(F._norm_cdf(-cfg.doublet_sigmas)) + 1e-9
    # main's scoring loop over whole [candidate, level] tables, kept in the stage as _score_tables (the continuous
    # kick's path): the reference the fast _score_points must equal bit for bit
    best = self._score_tables(d, pressure_kpa, thl, self._apex_kicks(), cand, fl, od, excess, moved, w, beyond, p_none,
                              e, s, tol, lo, worse_edge, break_limit)
    self._apex_plan = (best[1], best[4], best[5], best[0], best[2], best[6])
    if not best[0] > cfg.apex_min_chance:
        return None
    self._apex_kick, self._apex_rise = best[2], best[3]
    self._apex_last = (d, best[1])
    self._apex_try = (d, best[6])          # the model's mean move, if this try moves (traced in §81)
    return best[1]


def draw_try(fine, rng, n: int, d: int, pressure_kpa: float, thl: float, phi_e: float, phi_b: float) -> tuple:
    """A random try of the policy for the identity checks (test/test_apex_policy.py, benchmarks/apex_threads.py): the
    learned scatter, the error (either sign of the crossing guard by ``n``) and the stage's floor (none, inside the
    law, beyond it: the far tail, by ``n``) drawn from ``rng``; the floor is set on ``fine``.  Returns the arguments
    of ``fine._choose_apex``."""
    sigma = float(rng.uniform(1.5e-4, 9e-4))
    err = d * float(rng.uniform(2e-4, 2.5e-3))
    short = 0.0 if n % 3 else 1e-4
    kind = n % 4
    fine._apex_floor = (None if kind == 0 else
                        (d, phi_b + d * float(rng.uniform(-2.0, 2.0)) * sigma) if kind < 3 else
                        (d, phi_b + d * 3.5 * sigma))
    return (err, d, phi_e, phi_b, sigma, pressure_kpa, short, thl)


def timed_runs(seed: int, runs: int, sets: dict, profile: bool = False, record: bool = False) -> dict:
    """Run ``runs`` nominal cases from ``seed`` with controller ``sets``; every ``_choose_apex`` call timed.
    Returns {"ms": [per try, no table built], "built_ms": [...], "choices": [[run, apex, kick, rise] ...],
    "stats": the calls' cProfile (those that built no table; ``profile``) or None, "tries": with ``record`` the
    stage as each call found it (a deep copy sharing the move model) and the call's arguments}."""
    import robustness as R  # noqa: PLC0415 (the campaign's cases; not needed by the reference alone)
    original = F.FinePositioner._choose_apex
    out = {"ms": [], "built_ms": [], "choices": [], "stats": None, "tries": []}
    run = [0]

    def wrapper(self, *args, **kw):
        builds = 0 if self._moves is None else self._moves.builds
        if record:
            out["tries"].append((_copy(self), args, kw))
        prof = cProfile.Profile() if profile else None
        t0 = time.thread_time()
        if prof is not None:                   # (its overhead then counts in the times: profile and time apart)
            prof.enable()
        apex = original(self, *args, **kw)
        if prof is not None:
            prof.disable()
        dt = (time.thread_time() - t0) * 1e3
        built = self._moves.builds != builds
        if prof is not None:
            if not built:
                if out["stats"] is None:
                    out["stats"] = pstats.Stats(prof)
                else:
                    out["stats"].add(prof)
        (out["built_ms"] if built else out["ms"]).append(dt)
        out["choices"].append([run[0], None if apex is None else float(apex),
                               None if apex is None else float(self._apex_kick),
                               None if apex is None else float(self._apex_rise)])
        return apex

    F.FinePositioner._choose_apex = wrapper
    try:
        for i in range(runs):
            run[0] = seed + i
            R.run_case((R.sample_case(seed + i, "nominal"), None, sets))
    finally:
        F.FinePositioner._choose_apex = original
    return out


def _copy(fine):
    """A deep copy of the stage ``fine`` sharing its move model (tables read-only once built)."""
    return copy.deepcopy(fine, {} if fine._moves is None else {id(fine._moves): fine._moves})


#: what a choice sets on the stage besides its return value
EFFECTS = ("_apex_plan", "_apex_kick", "_apex_rise", "_apex_last", "_apex_try")


def _outcome(fine, apex) -> tuple:
    return (apex, *(getattr(fine, name, None) for name in EFFECTS))


def compare(tries: list, repeats: int = 3) -> dict:
    """Replay each recorded try (``timed_runs(record=True)``) through :func:`reference_choose_apex` and the current
    ``FinePositioner._choose_apex``, alternately ``repeats`` times each on fresh copies of the stage: the per-try CPU
    time of each (the median of its repeats, ms) and the tries whose outcomes (return value and :data:`EFFECTS`)
    differ in any bit."""
    ref_ms, new_ms, differ = [], [], []
    for fine, args, kw in tries:      # a first untimed pass: every table either needs is built
        reference_choose_apex(_copy(fine), *args, **kw)
        F.FinePositioner._choose_apex(_copy(fine), *args, **kw)
    for n, (fine, args, kw) in enumerate(tries):
        tr, tn = [], []
        for _ in range(repeats):
            for fn, times, tag in ((reference_choose_apex, tr, "ref"), (F.FinePositioner._choose_apex, tn, "new")):
                st = _copy(fine)
                t0 = time.thread_time()
                apex = fn(st, *args, **kw)
                times.append((time.thread_time() - t0) * 1e3)
                if tag == "ref":
                    a = _outcome(st, apex)
                else:
                    b = _outcome(st, apex)
        ref_ms.append(float(np.median(tr)))
        new_ms.append(float(np.median(tn)))
        if repr(a) != repr(b):
            differ.append({"try": n, "reference": repr(a), "current": repr(b)})
    return {"reference": _dist(ref_ms), "current": _dist(new_ms), "tries": len(tries), "differ": len(differ),
            "differences": differ[:5], "ratio_median": round(float(np.median(ref_ms) / np.median(new_ms)), 2)}


def replay(tries_by_law: dict, repeats: int) -> dict:
    """(task h40m, docs §106) Re-run every recorded try (``timed_runs(record=True)``) of each law ``repeats`` times on
    fresh copies of its stage, the laws alternating per round: per law the distribution of each try's **minimum** CPU
    time (ms; the quiet-core estimate on a loaded machine) and of its median, and each law's median over the first's."""
    times = {law: [[] for _ in tries] for law, tries in tries_by_law.items()}
    for _ in range(repeats):
        for law, tries in tries_by_law.items():
            for i, (fine, args, kw) in enumerate(tries):
                st = _copy(fine)
                t0 = time.thread_time()
                F.FinePositioner._choose_apex(st, *args, **kw)
                times[law][i].append((time.thread_time() - t0) * 1e3)
    out = {}
    for law, per in times.items():
        if not per:
            continue
        mins = np.array([min(v) for v in per])
        out[law] = {**_dist(list(mins)), "p99_ms": round(float(np.percentile(mins, 99)), 4),
                    "median_of_medians_ms": round(float(np.median([np.median(v) for v in per])), 4)}
    laws = [law for law in out]
    if len(laws) > 1:
        for law in laws[1:]:
            out[law]["ratio_to_" + laws[0]] = round(out[law]["median_ms"] / out[laws[0]]["median_ms"], 3)
    return out


def _dist(ms: list[float]) -> dict:
    if not ms:
        return {"tries": 0}
    v = np.asarray(ms)
    return {"tries": len(v), "median_ms": round(float(np.median(v)), 4),
            "p95_ms": round(float(np.percentile(v, 95)), 4), "max_ms": round(float(v.max()), 4),
            "mean_ms": round(float(v.mean()), 4)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="nominal cases per law (default 3)")
    ap.add_argument("--seed", type=int, default=1000, help="seed of the first case (run i: seed + i)")
    ap.add_argument("--law", choices=(*LAWS, "both"), default="both", help="fine.apex_level_law (default both)")
    ap.add_argument("--profile", action="store_true", help="cProfile the choice calls, print the top functions")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="controller.KEY=VALUE",
                    help="controller parameter on top of C1")
    ap.add_argument("--compare", action="store_true", help="also replay every try through main's choice (the "
                    "reference) and the current one, timing both and checking their outcomes are identical")
    ap.add_argument("--replay", type=int, default=0, metavar="R", help="also re-run every recorded try R times "
                    "(the laws alternating) and report each try's minimum CPU (the quiet-core estimate)")
    ap.add_argument("--json", metavar="PATH", help="also write the JSON (with every call's time and choice) here")
    args = ap.parse_args(argv)
    extra = parse_overrides(args.overrides, ("controller",))["controller"]
    doc = {"command": "python benchmarks/apex_choice.py " + " ".join(argv if argv is not None else sys.argv[1:]),
           "seed": args.seed, "runs": args.runs, "laws": {}}
    full = {}
    recorded = {}
    for law in (LAWS if args.law == "both" else (args.law,)):
        res = timed_runs(args.seed, args.runs, {**C1, "fine.apex_level_law": law, **extra}, args.profile,
                         args.compare or args.replay > 0)
        dist = _dist(res["ms"])
        doc["laws"][law] = {**dist, "built_calls": len(res["built_ms"]),
                            "built_max_ms": round(max(res["built_ms"]), 1) if res["built_ms"] else None}
        stats = res.pop("stats")
        tries = res.pop("tries")
        if args.replay > 0:
            recorded[law] = tries
        if args.compare:
            cmp_ = doc["laws"][law]["compare"] = compare(tries)
            print(f"{law:8s} replayed {cmp_['tries']} tries: reference median {cmp_['reference']['median_ms']:.3f} / "
                  f"p95 {cmp_['reference']['p95_ms']:.3f} / max {cmp_['reference']['max_ms']:.3f} ms, current median "
                  f"{cmp_['current']['median_ms']:.3f} / p95 {cmp_['current']['p95_ms']:.3f} / max "
                  f"{cmp_['current']['max_ms']:.3f} ms (x{cmp_['ratio_median']}); outcomes differing: {cmp_['differ']}")
        full[law] = res
        print(f"{law:8s} tries {dist.get('tries', 0):4d}  median {dist.get('median_ms', float('nan')):.3f} ms  "
              f"p95 {dist.get('p95_ms', float('nan')):.3f} ms  max {dist.get('max_ms', float('nan')):.3f} ms  "
              f"({len(res['built_ms'])} calls building tables apart)")
        if stats is not None:
            s = io.StringIO()
            stats.stream = s
            stats.sort_stats("tottime").print_stats(22)
            print(s.getvalue())
    if recorded:
        doc["replay"] = replay(recorded, args.replay)
        for law, r in doc["replay"].items():
            print(f"{law:8s} replayed x{args.replay}: per-try minimum median {r['median_ms']:.3f} / p95 {r['p95_ms']:.3f} / "
                  f"p99 {r['p99_ms']:.3f} / max {r['max_ms']:.3f} ms over {r['tries']} tries"
                  + "".join(f"; {k} {v}" for k, v in r.items() if k.startswith("ratio_to_")))
    if args.json:
        Path(args.json).write_text(json.dumps({**doc, "calls": full}, indent=1) + "\n")
    print(json.dumps(doc))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

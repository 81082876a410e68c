"""A run's first step from rest (shared by the cold-start and the breakaway-relief tests): the nominal plant
at max Δp, no breakaway scatter, its friction x ``friction_scale`` (the controller told the nominal), held
at rest at ``START_PCT``; one step of ``step_rad`` (rad, + opens) at 0.3 s held 0.7 s."""
from __future__ import annotations

import numpy as np

from fuel_valve_control.common.contract import PRESSURE_MAX_KPA, STROKE_RAD
from fuel_valve_control.tools import metrics as M
from fuel_valve_control.tools import sim
from fuel_valve_control.tools.scenarios import parse_scenario

START_PCT = 40.0


def first_step(step_rad: float, friction_scale: float = 1.0, **controller):
    """``(plateau results, the run's log)`` of the step in ``observer_fp`` with ``controller`` overrides."""
    pct = START_PCT + 100.0 * step_rad / STROKE_RAD
    sc = parse_scenario({"name": "first_step", "duration_s": 1.0, "initial_percent": START_PCT,
                         "pressure_differential_kpa": PRESSURE_MAX_KPA,
                         "demand": {"type": "points", "interpolation": "previous",
                                    "points": [[0.0, START_PCT], [0.3, START_PCT], [0.3, pct], [1.0, pct]]}})
    p, c = sim.build(sc, {"friction_scale": friction_scale}, controller, 0, "observer_fp")
    res = sim.simulate(sc, p, c)
    log = res.log
    tr = M.Trace(log[:, 0], log[:, 1], log[:, 2], np.hypot(log[:, 7], log[:, 8]), log[:, 9], res.stroke_rad)
    return M.plateau_results(tr), log

"""The run's time series as CSV: ``fuel_valve_sim --trace`` and ``fuel_valve_report --trace``.

One row per control period (offline run) or per plant sample (bag), one header row whose names
carry the unit, so a run can be analysed in any tool and every metric recomputed from raw data
(e.g. ``metrics.Trace(t_s, demand_rad, valve_rad, current_a, enable)``).  Columns, in order
(:data:`TRACE_COLUMNS`):

=========================  ================================================================
``t_s``                    time from the start of the run, s
``demand_rad``             demanded valve angle (percent demand x stroke / 100), rad
``valve_rad``              true valve angle (plant ground truth; a bag without
                           ``joint_states``: the best measured angle it has), rad
``valve_measured_rad``     valve resolver reading, rad (empty: no sample that period)
``motor_rad``              motor shaft angle (true), rad
``valve_velocity_rad_s``   true valve angular velocity, rad/s
``current_cmd_a``          q-current command from the controller, A
``current_a``              measured motor current magnitude ``|(i_d, i_q)|``, A
``i_q_a`` / ``i_d_a``      measured q / d current, A
``friction_valve_nm``      true valve friction torque, N*m } sign: the torque resisting
``friction_valve_est_nm``  controller's valve friction estimate }  motion, as the estimate
``friction_motor_nm``      true motor friction torque, N*m }  (minus the torque friction
``friction_motor_est_nm``  controller's motor friction estimate }  applies to the shaft)
``enable``                 drive enable, 1 / 0
``fault``                  1: the driver holds a latched fault, 0: none (empty: unknown --
                           a bag has the fault state only at the /diagnostics rate)
=========================  ================================================================

Angles: 0 = closed, positive opening.  A value the source does not have is an empty field
(``numpy.genfromtxt`` and pandas read it as NaN).
"""
from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Mapping

import numpy as np

#: (series key, CSV header name with unit): the series vocabulary is that of :mod:`.plotting`
TRACE_COLUMNS = (
    ("t", "t_s"),
    ("demand", "demand_rad"),
    ("position", "valve_rad"),
    ("measured", "valve_measured_rad"),
    ("motor", "motor_rad"),
    ("velocity", "valve_velocity_rad_s"),
    ("current_cmd", "current_cmd_a"),
    ("current", "current_a"),
    ("i_q", "i_q_a"),
    ("i_d", "i_d_a"),
    ("friction_valve", "friction_valve_nm"),
    ("friction_valve_est", "friction_valve_est_nm"),
    ("friction_motor", "friction_motor_nm"),
    ("friction_motor_est", "friction_motor_est_nm"),
    ("enable", "enable"),
    ("fault", "fault"),
)
HEADER = tuple(name for _, name in TRACE_COLUMNS)


def write_trace(path: str | Path, series: Mapping[str, np.ndarray]) -> Path:
    """Write ``series`` (arrays on the common time base ``series["t"]``) as the trace CSV.
    Keys the series lacks, and NaN values, become empty fields.  Returns the path."""
    t = np.asarray(series["t"], dtype=float)
    n = len(t)
    cols = []
    for key, name in TRACE_COLUMNS:
        values = series.get(key)
        if values is None or len(values) != n:
            if values is not None:
                raise ValueError(f"trace column {name}: {len(values)} values for {n} samples")
            values = np.full(n, math.nan)
        cols.append(np.asarray(values, dtype=float))
    path = Path(path)
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(HEADER)
        for row in zip(*cols):
            writer.writerow(["" if not math.isfinite(v) else repr(float(v)) for v in row])
    return path


def read_trace(path: str | Path) -> dict[str, np.ndarray]:
    """A trace CSV back as ``{header name: float array}`` (empty fields NaN)."""
    data = np.genfromtxt(path, delimiter=",", names=True, dtype=float, ndmin=1)
    return {name: np.asarray(data[name], dtype=float) for name in data.dtype.names}

"""The fine stage on other valves (docs/control_results.md section 37, task h23s).

* a 500 Hz loop (the nominal valve): the stage's gear-output servo (a PD at ``fine.servo_hz`` on
  the gear output's inertia) loses its phase margin to one loop period's lag (-4 deg at 2 ms) and
  rang +-3e-3 rad of twist about the preload reference, breaking the valve loose while
  preloading: the 2 % step overshot 23 % (fails on main).  The stage now stays out where the
  margin is not positive; the main law's hold keeps the plateau;
* a soft coupling (K 200 N*m/rad): the main law stops ~half a 1.1e-2 rad jump short and the
  servo-blended pulse's preload broke the valve loose a whole jump across (27.6 %).  Traced (task
  h24s, section 42): the pulse's rise and fall times, set for the nominal valve, asked the 30 A-capped
  gear output for 2.4x the acceleration on the 2.4x wider twist band; they now grow by sqrt(K_default / K)
  on a softer told coupling (default; the nominal valve's pulse bit for bit).
  ``fine.doublet_jump_fraction`` 0.5, off by default, closes it too, with the doublet's staircase;
* the nominal valve keeps its stage (the margin is positive on 1 and 2 kHz loops).
"""
from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from conftest import load_benchmark
from fuel_valve_control.core.fine_positioning import FinePositioner
from fuel_valve_control.core.model import NominalModel
from fuel_valve_control.core.params import CONTROLLER_SPEC
from fuel_valve_control.tools import metrics as M
from fuel_valve_control.tools import sim

OV = load_benchmark("other_valves")


@functools.lru_cache(maxsize=None)
def _step(valve: str, **extra):
    plant, ctrl = OV.overrides(OV.VALVES[valve])
    return sim.run("step_small", mode="observer_fp", plant_overrides=plant,
                   controller_overrides={**ctrl, **extra}, seed=0)


def _hunts(res) -> bool:
    log = res.log
    tr = M.Trace(log[:, 0], log[:, 1], log[:, 2], np.hypot(log[:, 7], log[:, 8]), log[:, 9], res.stroke_rad)
    return any(pl["hunts"] for pl in M.plateau_results(tr))


def _margin_deg(rate_hz: float) -> float:
    d = CONTROLLER_SPEC.defaults()
    m = NominalModel.from_params(d)
    w = 2.0 * math.pi * d["fine.servo_hz"]
    return math.degrees(FinePositioner.servo_margin_rad(m.j1, m.j1 * w * w, 1.6 * w * m.j1, 1.0 / rate_hz))


def test_servo_margin_sign_by_loop_rate():
    """The stage's servo keeps a positive phase margin on the nominal 1 kHz loop (33 deg) and a
    2 kHz one (51 deg), none on a 500 Hz loop (-4 deg)."""
    assert _margin_deg(1000.0) > 25.0
    assert _margin_deg(2000.0) > _margin_deg(1000.0)
    assert _margin_deg(500.0) < 0.0


def test_loop500_step_does_not_overshoot():
    """Nominal valve on a 500 Hz loop, 2 % step: < 10 % overshoot, within 1e-3 rad, no hunting
    (on main: 23.1 %, 4.8e-3 rad off -- the stage's preload broke the valve loose)."""
    res = _step("loop500")
    assert res.metrics["overshoot_pct"] < 10.0
    assert res.metrics["steady_state_error_rad"] < 1e-3
    assert not _hunts(res)


def test_nominal_step_keeps_the_stage():
    """The nominal valve's 2 % step is the stage's: within the issue's plateau target (5e-4 rad), < 2 % overshoot, no
    hunting.  (Measured: main's staircase until stop 24 1.1 % / 2.29e-4 rad; C1, the default since stop 25, 1.76 % /
    3.69e-4 rad -- one step of one seed, against C1's nominal-box p95 0.94e-3 vs main's 1.04e-3, docs §91; the
    bound was main's 3e-4 until then.)"""
    res = _step("nominal")
    assert res.metrics["overshoot_pct"] < 2.0
    assert res.metrics["steady_state_error_rad"] < 5e-4
    assert not _hunts(res)


def test_soft_coupling_step_default():
    """K 200 (told), 2 % step with the defaults: <= 10 % overshoot, within 8e-4 rad, no hunting.  On
    main 27.6 %: the servo-blended pulse, timed for the nominal valve, could not
    drive the 2.4x wider twist band within its 30 A cap; each pulse that fell short raised the
    learned breakaway and a preload planned from it broke the valve loose a whole 1.1e-2 rad jump.
    Its rise and fall times now grow by sqrt(K_default / K) on a softer told coupling (docs §42)."""
    res = _step("soft_coupling")
    assert res.metrics["overshoot_pct"] <= 10.0
    assert res.metrics["steady_state_error_rad"] < 8e-4
    assert not _hunts(res)


def test_soft_coupling_step_with_the_seconds_as_given_overshoots():
    """``fine.swing_scaled_pulse`` false (the nominal valve's seconds on K 200): the whole-jump
    overshoot is back (27.6 %) -- the mechanism located."""
    assert _step("soft_coupling", **{"fine.swing_scaled_pulse": False}).metrics["overshoot_pct"] > 20.0


def test_pulse_times_lengthen_on_a_softer_coupling():
    """The pulse's times grow by sqrt(K_default / K) on a softer coupling, never shrink: exactly 1 on
    the nominal valve (its pulse bit for bit), on a stiffer coupling, a heavier valve, another gear or
    more friction; sqrt(480/200) on the soft coupling."""
    d = CONTROLLER_SPEC.defaults()
    ref = NominalModel.from_params(d)

    def scale(**over):
        return FinePositioner.swing_scale(NominalModel.from_params({**d, **over}), ref)

    assert scale() == 1.0
    assert scale(**{"model.gear_ratio": 80.0}) == 1.0
    assert scale(**{"model.coupling_stiffness_nm_per_rad": 1500.0}) == 1.0
    assert scale(**{"model.valve_inertia_kgm2": 3 * d["model.valve_inertia_kgm2"]}) == 1.0
    assert scale(**{k: 2.0 * d[k] for k in ("model.valve_static_nm", "model.valve_static_per_dp_nm")}) == 1.0
    assert scale(**{"model.coupling_stiffness_nm_per_rad": 200.0}) == pytest.approx(math.sqrt(480.0 / 200.0))


def test_soft_coupling_step_with_doublet_jump_fraction():
    """K 200 with ``fine.doublet_jump_fraction`` 0.5: the doublet's staircase closes the half-jump
    error: <= 10 % overshoot (0.5 %), within 8e-4 rad, no hunting."""
    res = _step("soft_coupling", **{"fine.doublet_jump_fraction": 0.5})
    assert res.metrics["overshoot_pct"] <= 10.0
    assert res.metrics["steady_state_error_rad"] < 8e-4
    assert not _hunts(res)

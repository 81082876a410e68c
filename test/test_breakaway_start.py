"""observer_ff's move started on breakaway (issue 14, Deliver 2): the building blocks.

* :class:`TrajectoryShaper` with ``breakaway_wait``: a planned move waits at its start until
  the valve resolver shows breakaway the move's way (or the wait runs out), then runs its
  planned profile from the start;
* :class:`ReferenceFeedforward`: while a move waits, the valve feed-forward ramps up from a
  fraction of the breakaway level; when the valve lets go, the drive torque read then becomes
  the friction scale of both levels, and the valve's static-Coulomb twist is taken back.

The closed-loop figures (2 % step over friction x inertia x Δp) are in test_closed_loop.py.
"""
import math

import pytest

from fuel_valve_control.common.contract import RESOLVER_COUNT_RAD
from fuel_valve_control.core.compensation import Context, ReferenceFeedforward
from fuel_valve_control.core.friction_observer import FrictionObserver
from fuel_valve_control.core.model import NominalModel
from fuel_valve_control.core.params import CONTROLLER_SPEC
from fuel_valve_control.core.trajectory import TrajectoryShaper

PS = CONTROLLER_SPEC.defaults()
MODEL = NominalModel.from_params(PS)
T = 1e-3
P_MAX = 6206.0
START, TARGET = 0.2, 0.22


def _shaper(wait=0.1):
    return TrajectoryShaper(T, 5.0, 500.0, 0.005, min_move_time=0.02, breakaway_wait=wait,
                            breakaway_rad=3 * RESOLVER_COUNT_RAD)


def test_a_move_waits_at_its_start_until_the_valve_breaks_away_its_way():
    sh = _shaper()
    sh.reset(START)
    for _ in range(30):                      # the valve stays stuck (or creeps the other way)
        ref = sh.update(TARGET, START - 1e-3)
        assert ref.moving and ref.armed == 1.0 and not ref.broke_away
        assert ref.position == START and ref.velocity == 0.0 and ref.acceleration == 0.0
    ref = sh.update(TARGET, START + 4 * RESOLVER_COUNT_RAD)       # broke away toward open
    assert ref.broke_away and ref.armed == 0.0 and ref.moving and ref.velocity > 0.0
    # from there the planned profile runs to the target on its clock, whatever the valve does
    n = 1
    while ref.moving:
        ref = sh.update(TARGET, START)
        n += 1
    assert ref.position == TARGET and n * T == pytest.approx(0.02, abs=2 * T)


def test_a_closing_move_waits_for_breakaway_toward_closed():
    sh = _shaper()
    sh.reset(TARGET)
    assert sh.update(START, TARGET + 1e-3).armed == -1.0          # moved, but the wrong way
    assert sh.update(START, TARGET - 4 * RESOLVER_COUNT_RAD).broke_away


def test_a_valve_that_never_breaks_away_gets_the_clocked_move_after_the_wait():
    sh = _shaper(wait=0.05)
    sh.reset(START)
    waited = 0
    while sh.update(TARGET, START).armed:
        waited += 1
        assert waited < 1000
    assert waited * T == pytest.approx(0.05, abs=1.5 * T)


def test_without_a_wait_or_a_valve_reading_the_move_starts_on_the_clock():
    for sh, valve in ((_shaper(wait=0.0), START), (_shaper(), None)):
        sh.reset(START)
        ref = sh.update(TARGET, valve)
        assert ref.armed == 0.0 and ref.velocity > 0.0


def _comp():
    n = MODEL.gear_ratio
    fps = (FrictionObserver(PS["fp.motor.alpha"], PS["fp.motor.beta"], PS["fp.motor.gain_cap"],
                            PS["fp.motor.freeze_velocity_rad_s"], T, max_level=1e9, boundary_velocity=n * 0.1),
           FrictionObserver(PS["fp.valve.alpha"], PS["fp.valve.beta"], PS["fp.valve.gain_cap"],
                            PS["fp.valve.freeze_velocity_rad_s"], T, max_level=1e9, boundary_velocity=0.1))
    c = ReferenceFeedforward(*fps, 0.01, 0.03, False, 1.0, T, ramp_time=0.05, ramp_start=0.4,
                             retreat_periods=12)
    c.reset(MODEL, P_MAX)
    return c


def _ctx(applied_motor_nm, armed, broke=False, ref_velocity=0.0):
    return Context(P_MAX, START, 0.0, START, 0.0, 0.0, applied_motor_nm, ref_velocity, 0.0, True, 0.0, False,
                   armed, broke)


@pytest.mark.parametrize("scale", [0.5, 1.0, 3.0])
def test_breakaway_ramp_and_learned_friction_scale(scale):
    """Ramp while armed; the breakaway torque read from the applied drive sets the scale."""
    c = _comp()
    n = MODEL.gear_ratio
    fl = MODEL.friction(P_MAX)
    breakaway = fl.valve_static_nm + n * fl.motor_coulomb_nm          # drivetrain, valve side
    load = MODEL.load_torque(START, P_MAX)
    levels = [c.update(_ctx(load / n, 1.0))[2] for _ in range(20)]
    assert levels[0] == pytest.approx((0.4 + T / 0.05) * breakaway, rel=1e-6)    # one period in
    assert all(b > a for a, b in zip(levels, levels[1:]))             # rising toward breakaway
    # the valve lets go with the drive at scale x the nominal breakaway level
    c.update(_ctx((load + scale * breakaway) / n, 0.0, broke=True, ref_velocity=0.05))
    assert c.breakaway_ratio == pytest.approx(scale, rel=1e-6)
    assert c.scale(P_MAX)[1] == pytest.approx(scale, rel=1e-6)        # the Coulomb level follows
    # the stored static-Coulomb twist is taken back for one period of the valve on the
    # coupling, then the sliding feed-forward is the learned Coulomb level
    gap = scale * (fl.valve_static_nm - fl.valve_coulomb_nm)
    fv = [c.update(_ctx(0.0, 0.0, ref_velocity=1.0))[2] for _ in range(13)]
    assert fv[0] == pytest.approx(scale * fl.valve_coulomb_nm - gap, rel=1e-3)
    assert fv[-1] == pytest.approx(scale * fl.valve_coulomb_nm, rel=1e-3)


def test_learned_scale_is_bounded_and_forgotten_on_reset():
    c = _comp()
    n = MODEL.gear_ratio
    load = MODEL.load_torque(START, P_MAX)
    c.update(_ctx(load / n, 1.0))
    c.update(_ctx((load + 1e4) / n, 0.0, broke=True))                 # a wild reading
    assert c.breakaway_ratio == c.scale_bounds[1]
    c.reset(MODEL, P_MAX)
    assert c.breakaway_ratio is None and c.scale(P_MAX)[1] == pytest.approx(1.0)
    c.update(_ctx(load / n, 1.0))
    c.update(_ctx((load - 1e4) / n, 0.0, broke=True))
    assert c.breakaway_ratio == c.scale_bounds[0]
    assert math.isfinite(c.update(_ctx(0.0, 0.0, ref_velocity=1.0))[0])

"""``fine.apex_stop_rad`` (task h39t, docs §102; 4.8e-4 rad, the default since stop 27, docs §104): with the apex
policy the stage is done once the valve rests within this of the demand (when larger than ``fine.tolerance_rad``). The
policy aims its tries into ``fine.apex_land_rad`` (4e-4 rad) and scores no value for the rest it already has; with the
tolerance (3 counts, 2.9e-4 rad) as its done-test it tried on from rests already inside the 5e-4 rad target (traced,
C2 + F, nominal box seeds 1000 / 2000 / 4000: of 85 moves from rests at 2.9-4e-4 rad, 75 % left |e| larger, 59 % >
5e-4).

Stage only (no plant, no move tables: the next try is a stub)."""
import pytest

from test_engage_gear_rest import _engage_period
from test_fine_positioning import MAIN_DOUBLET, _stage


def _after_doublet(err_after, **changes):
    """The stage engaged on a 2e-3 rad error (its servo-blended pulse, no tables), then judged as after a policy
    doublet that left the valve at rest ``err_after`` (rad) short of the target; returns (stage, next try started)."""
    fine, m = _stage(**{"fine.engage_inside_deadband": True, **changes})
    p = m.pressure_max_kpa
    assert _engage_period(fine, 2.0e-3, p, 0.0, 0) is not None
    tries = []
    fine._start_pulse = lambda th1, thl, pk, after_command=False: (tries.append(fine._target - thl),
                                                                    setattr(fine, "phase", "park"))
    fine._doublet, fine._pulsed = True, True
    fine._peak_seen = fine._twists(fine._thl0, p, fine._dir)[1]      # it let go at the learned level
    thl = fine._target - err_after
    move = thl - fine._thl0
    th1 = fine._thl0 + fine._nominal(fine._thl0, p, fine._dir)[0] + 0.5 * move     # it swung about the nominal φe
    fine._after_move(th1, thl, p, pulsed=True)
    return fine, tries


@pytest.mark.parametrize("sign", [1, -1])
def test_holds_a_rest_within_the_stop_radius(sign):
    err = sign * 3.5e-4                                  # outside the tolerance (2.9e-4), inside 4e-4
    off, tries = _after_doublet(err, **{"fine.apex_stop_rad": 0.0})
    assert off.phase == "park" and tries == [pytest.approx(err)]      # off: the policy tries again
    on, tries = _after_doublet(err, **{"fine.apex_stop_rad": 4e-4})
    assert on.phase == "hold" and tries == []


def test_tries_on_beyond_the_stop_radius():
    on, tries = _after_doublet(4.5e-4, **{"fine.apex_stop_rad": 4e-4})
    assert on.phase == "park" and tries == [pytest.approx(4.5e-4)]


def test_radius_only_with_the_policy_and_above_the_tolerance():
    fine, _ = _stage(**{"fine.apex_stop_rad": 4e-4})
    assert fine._done_rad() == 4e-4
    staircase, _ = _stage(**{**MAIN_DOUBLET, "fine.apex_stop_rad": 4e-4})
    assert staircase._done_rad() == staircase.cfg.tolerance_rad
    small, _ = _stage(**{"fine.apex_stop_rad": 1e-4})
    assert small._done_rad() == small.cfg.tolerance_rad


def test_no_engagement_within_the_stop_radius():
    # 4.5e-4 rad: above the prior's smallest-move gate (4.35e-4 at max dp), so the tolerance alone lets it engage
    err = 4.5e-4
    for changes, engages in (({"fine.apex_stop_rad": 0.0}, True), ({"fine.apex_stop_rad": 5e-4}, False)):
        fine, m = _stage(**{"fine.engage_inside_deadband": True, **changes})
        fine._start_pulse = lambda th1, thl, pk, after_command=False, f=fine: setattr(f, "phase", "park")
        fine._run = lambda *a: 0.0
        k = _engage_period(fine, err, m.pressure_max_kpa, 0.0, 0)
        assert (k is not None) == engages


def test_default_and_off():
    """4.8e-4 rad by default (stop 27, docs §104); 0 is the tolerance."""
    from fuel_valve_control.core.params import CONTROLLER_SPEC
    assert CONTROLLER_SPEC.defaults()["fine.apex_stop_rad"] == 4.8e-4
    fine, _ = _stage()
    assert fine._done_rad() == 4.8e-4
    off, _ = _stage(**{"fine.apex_stop_rad": 0.0})
    assert off._done_rad() == off.cfg.tolerance_rad

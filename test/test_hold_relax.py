"""``fine.hold_relax`` (+ ``fine.hold_relax_time_s``; task h39h, docs §101, off by default): while the fine stage holds
the valve (HOLD, the plateau done) the gear output moves the held twist that fraction of the way to the static band's
middle (between the two learned breakaway twists), slowly, and stops where it is should the valve move.  Held next to
the breakaway its last doublet pushed toward (`startup` seed 0 with C2: 2.8e-3 rad of twist short of the opening
breakaway), the next small step that way broke the valve loose at once and its stick-slip jump ran 14.6 % past.

Stage only (no plant), no move tables built: the hold's servo reference is read each period (the gear output follows
it exactly, the valve at rest unless moved)."""
import pytest

from test_handover_settle import _held


def _refs(fine, p, thl, th1, periods, move_at=None, move=0.0):
    """The hold servo's reference each period for ``periods`` periods on the same demand; the gear output at the last
    reference; the valve moved by ``move`` rad from period ``move_at`` on."""
    refs = []
    servo = fine._servo

    def spy(th1_ref, *args, **kwargs):
        refs.append(th1_ref)
        return servo(th1_ref, *args, **kwargs)

    fine._servo = spy
    for k in range(1, periods + 1):
        valve = thl + (move if move_at is not None and k >= move_at else 0.0)
        torque = fine.update(fine._plateau, th1, valve, True, 0.3, p)
        assert torque is not None and fine.phase == "hold"
        th1 = refs[-1]
    return refs


@pytest.mark.parametrize("side", [1, -1])
@pytest.mark.parametrize("fraction", [1.0, 0.5])
def test_relax_moves_the_held_twist_toward_the_middle_slowly(side, fraction):
    fine, p, thl, th1, mid = _held(side, **{"fine.hold_relax": fraction})
    n = fine.cfg.hold_relax_periods
    assert n == 60                                               # 0.06 s at 1 kHz
    refs = _refs(fine, p, thl, th1, n + 10)
    goal = th1 + fraction * (thl + mid - th1)
    assert abs(refs[-1] - goal) < 1e-12 and refs[n - 1:] == [refs[-1]] * (len(refs) - n + 1)
    steps = [b - a for a, b in zip([th1] + refs, refs)]
    assert all(-side * s >= 0.0 for s in steps)                 # only ever toward the middle, never past it
    assert max(abs(s) for s in steps) < 3.0 * abs(goal - th1) / n   # slow: no period moves 3 x the mean step


def test_relax_stops_where_the_valve_moves():
    fine, p, thl, th1, mid = _held(1, **{"fine.hold_relax": 1.0})
    n = fine.cfg.hold_relax_periods
    refs = _refs(fine, p, thl, th1, n + 10, move_at=n // 3, move=fine.cfg.tolerance_rad)
    assert refs[n // 3:] == [refs[n // 3 - 1 + 1]] * (len(refs) - n // 3)   # frozen from the move on
    assert th1 > refs[-1] > thl + mid + 0.5 * (th1 - thl - mid)           # well short of the middle


def test_relax_a_new_hold_plans_anew():
    fine, p, thl, th1, mid = _held(1, **{"fine.hold_relax": 1.0})
    n = fine.cfg.hold_relax_periods
    _refs(fine, p, thl, th1, n + 2)
    other = thl + mid - 0.4 * (th1 - thl - mid)                  # a new hold on the other side
    fine._hold_ref = other
    refs = _refs(fine, p, thl, other, n + 2)
    assert abs(refs[-1] - (thl + mid)) < 1e-12 and refs[0] > other


def test_relax_off_holds_where_it_stopped():
    fine, p, thl, th1, _ = _held(1)
    assert fine.cfg.hold_relax == 0.0
    assert _refs(fine, p, thl, th1, 30) == [th1] * 30
    assert fine._relax is None


def test_relax_off_by_default():
    from fuel_valve_control.core.params import CONTROLLER_SPEC
    defaults = CONTROLLER_SPEC.defaults()
    assert defaults["fine.hold_relax"] == 0.0 and defaults["fine.hold_relax_time_s"] == 0.06


# ---- fine.handover_unwind_max_jumps (task h39h): h38s's unwind only for a step within that many stick-slip jumps, and
# given up once the demand moves on (a ramp's start)

def _jump(fine, p):
    return fine.m.friction(p).stick_slip_jump_rad(fine.m.coupling_stiffness_nm_per_rad)


def _handover_period(fine, p, demand):
    """Periods until the stage hands over (returns None) to a demand ``demand(k)`` (rad) in period k, the gear output
    and the valve still."""
    thl, th1 = fine._last_valve, fine._hold_ref
    for k in range(1, 200):
        if fine.update(demand(k), th1, thl, False, 0.3, p) is None:
            assert fine.phase == "idle"
            return k
    return None


@pytest.mark.parametrize("direction", [1, -1])
def test_unwind_gated_by_the_step_size(direction):
    on = {"fine.handover_unwind": True, "fine.handover_unwind_max_jumps": 2.0}
    fine, p, thl, _, _ = _held(direction, **on)
    n = fine.cfg.observe_periods
    small = direction * 1.0 * _jump(fine, p)
    assert _handover_period(fine, p, lambda k: thl + small) == n + 4      # unwound first, as h38s's prototype
    fine, p, thl, _, _ = _held(direction, **on)
    large = direction * 3.0 * _jump(fine, p)
    assert _handover_period(fine, p, lambda k: thl + large) == 1          # a step beyond 2 jumps: at once
    fine, p, thl, _, _ = _held(direction, **{"fine.handover_unwind": True})
    assert _handover_period(fine, p, lambda k: thl + large) == n + 4      # ungated (0): unwound whatever the step


def test_unwind_given_up_when_the_demand_moves_on():
    on = {"fine.handover_unwind": True, "fine.handover_unwind_max_jumps": 2.0}
    fine, p, thl, _, _ = _held(1, **on)
    step = 0.5 * _jump(fine, p)
    assert _handover_period(fine, p, lambda k: thl + step + (k >= 4) * 1e-5) == 4   # a ramp: handed over as it moves
    fine, p, thl, _, _ = _held(1, **{"fine.handover_unwind": True})
    assert _handover_period(fine, p, lambda k: thl + step + (k >= 4) * 1e-5) == fine.cfg.observe_periods + 4


def test_unwind_max_jumps_off_by_default():
    from fuel_valve_control.core.params import CONTROLLER_SPEC
    assert CONTROLLER_SPEC.defaults()["fine.handover_unwind_max_jumps"] == 0.0


def test_unwind_only_near_the_breakaway():
    """``fine.handover_unwind_near``: unwound only with the twist within that many (T_s - T_c)/K of the new move's
    breakaway; farther, handed over at once."""
    base = {"fine.handover_unwind": True, "fine.handover_unwind_max_jumps": 2.0}
    fine, p, thl, th1, _ = _held(1, **base)
    fl = fine.m.friction(p)
    unit = (fl.valve_static_nm - fl.valve_coulomb_nm) / fine.m.coupling_stiffness_nm_per_rad
    gap = (fine._twists(thl, p, 1)[1] - (th1 - thl)) / unit
    assert gap > 0.0
    step = 0.5 * _jump(fine, p)
    n = fine.cfg.observe_periods
    fine, p, thl, _, _ = _held(1, **base, **{"fine.handover_unwind_near": 1.01 * gap})
    assert _handover_period(fine, p, lambda k: thl + step) == n + 4
    fine, p, thl, _, _ = _held(1, **base, **{"fine.handover_unwind_near": 0.99 * gap})
    assert _handover_period(fine, p, lambda k: thl + step) == 1
    from fuel_valve_control.core.params import CONTROLLER_SPEC
    assert CONTROLLER_SPEC.defaults()["fine.handover_unwind_near"] == 0.0

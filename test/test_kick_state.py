"""The doublet's kick state and the apex policy's floor on an untold valve (task h37t, docs §96).

C1's full-box losers (runs 1027, 1050, 1069) traced: on 1069 (Δp 0.98 MPa, coupling x0.91, resolver delay 0.62 ms) the move
model's trough of a one-period retreat lay 3.3-4.2e-3 rad shallower than the plant's -- 1.2-1.5e-3 of it the resolver delay
the model leaves out (``fine.retreat_trough_delay``), and the kick started on a park still ringing (``fine.park_settle``);
on 1027 (coupling x0.81) the kick's apex read 0.45e-3 rad below its plan and the policy repeated one unmoved try 15, 15 and
141 times (``fine.apex_unraised_plan``).  All three off by default.

Stage-alone tests, no plant (< 1 s each)."""
import numpy as np
import pytest

from fuel_valve_control.core.params import CONTROLLER_SPEC
from fuel_valve_control.core.pulse_moves import PulseMoves
from test_fine_positioning import _break_loose, _rest_twist, _stage

NEW = ("fine.park_settle", "fine.retreat_trough_delay", "fine.apex_unraised_plan")


def test_the_options_are_off_by_default():
    ps = CONTROLLER_SPEC.defaults()
    assert all(ps[k] is False for k in NEW)
    fine, _ = _stage()
    assert fine.cfg.park_settle is False and fine.cfg.apex_unraised_plan is False and fine.cfg.trough_delay_s == 0.0


def test_the_trough_delay_reads_the_told_resolver_delay():
    fine, _ = _stage(**{"resolver_delay_s": 6e-4, "fine.retreat_trough_delay": True})
    assert fine.cfg.trough_delay_s == pytest.approx(6e-4)
    fine, _ = _stage(**{"resolver_delay_s": 6e-4})
    assert fine.cfg.trough_delay_s == 0.0


@pytest.mark.parametrize("direction", [1, -1])
def test_a_late_servo_lets_the_retreat_swing_deeper(direction):
    """:meth:`PulseMoves.trough` with ``servo_delay_s``: 0 is the model as before (bit for bit); the observe servo reading
    the gear output 0.6 ms late brakes the retreat's swing later -- a deeper trough (docs §96: 1.2-1.5e-3 rad on run
    1069's one-period retreats)."""
    fine, m = _stage(**{"fine.retreat_cap": True, "fine.observe_hold_moved": True})
    mv = PulseMoves.for_positioner(fine, retreat_full_periods=2, retreat_cap=True, retreat_cap_full=True,
                                   observe_hold_moved=True)
    p, th = m.pressure_max_kpa, 0.5
    k = m.coupling_stiffness_nm_per_rad
    pre = (m.load_torque(th, p) + direction * m.friction(p).valve_static_nm) / k - direction * 1e-3
    kw = dict(retreat_periods=1, retreat_scale=np.array([1.0, 0.5]))
    base = mv.trough(direction, p, np.full(2, pre), 4.0, th, **kw)
    assert np.array_equal(mv.trough(direction, p, np.full(2, pre), 4.0, th, servo_delay_s=0.0, **kw), base)
    late = mv.trough(direction, p, np.full(2, pre), 4.0, th, servo_delay_s=6e-4, **kw)
    depth, depth_late = direction * (pre - base), direction * (pre - late)
    assert np.all(depth_late > depth + 1e-4)
    # a delay of more than a period reads as one period (the stage's own clamp; the model's too)
    full = mv.trough(direction, p, np.full(2, pre), 4.0, th, servo_delay_s=fine.period, **kw)
    assert np.array_equal(mv.trough(direction, p, np.full(2, pre), 4.0, th, servo_delay_s=5 * fine.period, **kw), full)


def _park_periods(fine, error_rad, pressure_kpa, ring_rad, periods=200):
    """Periods the stage parks before its doublet's kick, the gear output held on the preload reference (``ring_rad`` > 0:
    alternating +-ring_rad about it -- a gear output still ringing at 2 ring_rad / period)."""
    thl = 0.5
    th1 = thl + _rest_twist(fine, thl, pressure_kpa)
    _break_loose(fine, thl, pressure_kpa)
    n = 0
    for i in range(periods):
        if fine.phase == "park":
            n += 1
            th1 = thl + fine._pre + ring_rad * (-1) ** i
        fine.update(thl + error_rad, th1, thl, True, 0.3, pressure_kpa)
        if fine.phase == "pulse":
            return n, fine._park_n
    raise AssertionError("the stage never kicked")


@pytest.mark.parametrize("direction", [1, -1])
def test_the_kick_waits_for_a_ringing_park_to_settle_but_not_forever(direction):
    ps = CONTROLLER_SPEC.defaults()
    err = direction * 0.5 * ps["fine.doublet_max_error_rad"]
    main = {"fine.apex_policy": False}           # the staircase's doublet: no move tables needed
    p = 0.9 * CONTROLLER_SPEC.defaults()["model.pressure_max_kpa"]
    # a settled park: the same kick period with the option on and off
    off, n_off = _park_periods(_stage(**main)[0], err, p, 0.0)
    on, n_on = _park_periods(_stage(**main, **{"fine.park_settle": True})[0], err, p, 0.0)
    assert on == off and n_on == n_off
    # a gear output ringing at 0.2 rad/s (4x the settle bound of sqrt(K / J1) x 3 counts, ~0.05 rad/s): off, the kick
    # comes at the park's planned end; on, it waits -- at most as many periods again as the park planned
    ring = 1e-4
    off_r, _ = _park_periods(_stage(**main)[0], err, p, ring)
    fine, _ = _stage(**main, **{"fine.park_settle": True})
    assert not fine._park_settled(2 * ring / fine.period) and fine._park_settled(0.0)
    on_r, n = _park_periods(fine, err, p, ring)
    assert off_r == off and on_r > off_r and on_r <= 2 * n + 2


def test_an_unraised_floor_is_the_last_tries_plan():
    """``fine.apex_unraised_plan``: after an unmoved try whose reading raised the floor by less than a count, the law is
    truncated at that try's planned apex, not at the reading (which gave the same try again, run 1027)."""
    for on in (False, True):
        # the floor at the reading (fine.apex_floor_plan, C2's, takes the higher of the reading and the plan at once)
        fine, _ = _stage(**{"fine.apex_unraised_plan": on, "fine.apex_floor_plan": False})
        fine._apex_floor = (1, 30.0e-3)
        fine._apex_last = (1, 30.45e-3)
        assert fine._floor(1) == (1, 30.0e-3)                 # the reading raised the floor: the reading
        fine._floor_unraised = fine._apex_floor
        assert fine._floor(1) == ((1, 30.45e-3) if on else (1, 30.0e-3))
        assert fine._floor(-1) is None
        fine._apex_last = (1, 29.9e-3)                        # a plan below the reading: the reading
        assert fine._floor(1) == (1, 30.0e-3)
        fine._apex_floor = (1, 30.1e-3)                       # a floor since raised: not the stale one
        fine._apex_last = (1, 30.45e-3)
        assert fine._floor(1) == (1, 30.1e-3)


@pytest.mark.parametrize("p_none, retreat", [(1.0, (1, 0.0)), (0.99, (1, 0.0)), (0.5, (1, 0.6)), (0.0, (1, 0.6))])
def test_a_try_expected_not_to_move_the_valve_retreats_at_the_hold(p_none, retreat):
    """``fine.apex_probe_hold``: where ``fine.retreat_trough_bound`` cut the retreat (low Δp: the deep trough passes the
    other way's level), a policy try with P(no move) within Phi(-fine.doublet_sigmas) of 1 (a pure probe, run 1069 #7:
    1.000) retreats one period at the hold torque; any other try keeps the bound's plan; at max Δp (the bound keeps C1's
    two periods at -cap) every try keeps them; off, the bound's plan."""
    c1 = {"fine.apex_policy": True, "fine.apex_kick_max_a": 16.0, "fine.apex_retreat_periods": 2,
          "fine.retreat_cap": True, "fine.observe_hold_moved": True, "fine.apex_excess_nominal": True}
    for on in (False, True):
        for cut in (False, True):
            fine, m = _stage(**c1, **{"fine.apex_probe_hold": on, "fine.retreat_trough_bound": True})
            cap = fine.cfg.peak_current_a * m.torque_constant_nm_per_a
            # the bound's plan stood in for (its own tests: test_retreat_trough.py): cut to one period at 0.6, or kept
            fine._retreat_plan = lambda p, kick, periods, cut=cut: (1, 0.6) if cut else (periods, 1.0)
            fine.phase, fine._doublet, fine._dir, fine._first_stair = "pulse", True, 1, False
            fine._hold_torque, fine._apex_kick = 0.1, 4.0
            fine._apex_try, fine._apex_plan = (1, 0.0), (30e-3, 0.0, p_none, 0.05, 4.0, 0.0)
            fine._k = 1
            kick = fine._doublet_torque(m.pressure_max_kpa)
            assert kick == pytest.approx(0.1 + 4.0 * m.torque_constant_nm_per_a)
            want = (retreat if on else (1, 0.6)) if cut else (2, 1.0)
            # planned after the kick's command (fine.retreat_plan_after_command, docs §111): the node's after_period
            assert fine._retreat is None and fine._retreat_pending is not None
            assert fine.run_pending() is True and fine._retreat_pending is None
            assert fine._retreat == want
            fine._k = 2
            assert fine._doublet_torque(m.pressure_max_kpa) == pytest.approx(0.1 + want[1] * (-cap - 0.1))

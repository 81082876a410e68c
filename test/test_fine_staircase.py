"""The doublet staircase's climb where the breakaway level seldom lies (task h27s, docs §55).

``fine.stair_far_sigmas`` (off by default: measured no better on the nominal box, §55): while a
staircase's apex lies more than that many learned scatters below the learned breakaway, a stair that
did not move the valve is followed by one up to ``fine.kick_rise_rad`` higher instead of
``fine.doublet_probe_step`` x the band -- never past that bound, and nearer the learned level the
fixed stairs again.  The stage runs on a valve that never moves (a stiff servo: the gear output is
where the stage wants it), so each test costs a few thousand stage periods, no plant."""

import pytest

# the staircase and main's doublet: C1 (the default since stop 25, docs §91) off -- these options act on the staircase
from test_fine_positioning import _main_stage as _stage, _torques_until_observe


def _stuck_staircase(fine, err, p, stairs):
    """The stage's doublet staircase on a valve that never moves, ``err`` short of a steady target:
    (periods spent, the staircase's depth ``_stair`` below the learned level at its first stair and after
    each stair, rad of twist)."""
    _torques_until_observe(fine, err, p)
    assert fine._doublet
    thl, periods, depths = 0.5, 0, [fine._stair]
    while len(depths) <= stairs:
        th1 = thl + (fine._pre if fine.phase == "park" else fine._final)
        fine.update(thl + err, th1, thl, True, 0.3, p)
        periods += 1
        # (a stage that climbs no staircase -- the apex policy, C1's default -- would never end this loop)
        assert periods < 2000 * (stairs + 1), (periods, depths)
        if fine._stair != depths[-1]:
            depths.append(fine._stair)
        assert fine.phase not in ("hold", "idle")
    return periods, depths


@pytest.mark.parametrize("direction", [1, -1])
def test_far_stairs_climb_up_to_the_kick_rise_and_fixed_stairs_near_the_learned_level(direction):
    sigmas = 1.0
    fixed, m = _stage()
    p = m.pressure_max_kpa
    far, _ = _stage(**{"fine.stair_far_sigmas": sigmas})
    err = direction * 0.6e-3
    n_fixed, d_fixed = _stuck_staircase(fixed, err, p, stairs=10)
    n_far, d_far = _stuck_staircase(far, err, p, stairs=10)
    c_fixed = [a - b for a, b in zip(d_fixed, d_fixed[1:])]
    c_far = [a - b for a, b in zip(d_far, d_far[1:])]
    floor = c_fixed[0]
    assert all(c == pytest.approx(floor) for c in c_fixed)
    cfg = far.cfg
    band = far.learn.band(m.pressure_fraction(p))
    e0, b0 = far._nominal(0.5, p, direction)
    bound = sigmas * far._scatter(direction, band, abs(b0 - e0))
    # both start at the same depth, fine.doublet_sigmas (2) scatters below the learned level: below the bound
    assert d_far[0] == pytest.approx(d_fixed[0]) and d_far[0] > bound + cfg.kick_rise_rad
    # far below: stairs of the kick's rise (larger than the floor), the last one cut at the bound, never
    # past it; from within a floor of the bound on, the fixed stairs
    k = next(i for i, c in enumerate(c_far) if c == pytest.approx(floor))
    assert k >= 2
    assert all(c == pytest.approx(cfg.kick_rise_rad) for c in c_far[:k - 1])
    assert floor < c_far[k - 1] <= cfg.kick_rise_rad + 1e-12
    assert bound - 1e-12 <= d_far[k] < bound + floor
    assert all(c == pytest.approx(floor) for c in c_far[k:])
    # the same ten stairs climb further, each taking about as long
    assert d_far[0] - d_far[-1] > d_fixed[0] - d_fixed[-1] + (k - 1) * (cfg.kick_rise_rad - floor)
    assert n_far <= 1.1 * n_fixed


@pytest.mark.parametrize("direction", [1, -1])
def test_unmoved_doublet_observe_holds_the_gear_output_near_the_preload(direction):
    """``fine.retreat_stop_unmoved`` (task h28r, §58; off by default): once a doublet's valve is seen not to
    have moved, the observe servo's twist reference is the preload less ``fine.park_approach_rad``, not the
    move's final twist (off: the final twist, the retreat's deep trough)."""
    for on in (False, True):
        fine, m = _stage(**{"fine.retreat_stop_unmoved": on})
        p = m.pressure_max_kpa
        err = direction * 0.6e-3
        refs = []
        servo = fine._servo

        def spy(ref, *a, **k):
            if fine.phase == "observe" and fine._doublet and fine._pulsed:
                want = fine._pre - fine._dir * fine.cfg.park_approach_rad if on else fine._final
                refs.append((ref - fine._thl0, want, abs(fine._pre - fine._final)))
            return servo(ref, *a, **k)

        fine._servo = spy
        _stuck_staircase(fine, err, p, stairs=2)
        assert refs
        for ref, want, apart in refs:
            assert ref == pytest.approx(want, abs=1e-12)
            assert apart > 2.0 * fine.cfg.park_approach_rad   # the two references differ


@pytest.mark.parametrize("direction", [1, -1])
def test_repark_follows_the_rebound_from_the_trough_and_arrives_at_the_preload_at_rest(direction):
    """``fine.repark_from_state`` (task h29r, §61; off by default): after a stair that did not move the valve,
    the next park's twist reference starts on the twist and twist rate the retreat's trough left (here a
    rebound at ~1.75 rad/s toward the preload), in the very period the stair is judged, and climbs
    monotonically to the preload, where it arrives at rest -- in fewer periods than the park planned from rest
    at the trough's twist (off: the observe servo's final-twist reference in that period, at rate 0)."""
    periods, firsts = {}, {}
    for on in (False, True):
        fine, m = _stage(**{"fine.repark_from_state": on})
        p = m.pressure_max_kpa
        d = direction
        _torques_until_observe(fine, d * 0.6e-3, p)
        assert fine._doublet and fine.phase == "observe"
        thl, pre = 0.5, fine._pre
        refs = []
        servo = fine._servo

        def spy(ref, a_ref, th1, w1, thl_, v_ref=0.0):
            refs.append((fine.phase, ref - thl_, v_ref, w1))
            return servo(ref, a_ref, th1, w1, thl_, v_ref)

        fine._servo = spy
        # the retreat's swing: down to 5e-3 rad below the preload, then rebounding at 1 rad/s (backward difference)
        trough = [2.0e-3, 4.5e-3, 5.0e-3, 4.0e-3]
        for depth in trough:
            fine.update(thl + d * 0.6e-3, thl + pre - d * depth, thl, True, 0.3, p)
        assert fine.phase == "park" and fine._pre != pre          # judged unmoved: the next stair's park
        judged = refs[-1]
        x0 = pre - d * trough[-1]
        n, ref_prev = 0, x0
        while fine.phase == "park":
            th1 = thl + ref_prev                                   # a stiff servo: the gear output on its reference
            fine.update(thl + d * 0.6e-3, th1, thl, True, 0.3, p)
            n += 1
            if fine.phase == "park":
                assert d * (refs[-1][1] - ref_prev) >= -1e-12      # never back toward the trough
                ref_prev = refs[-1][1]
            assert n < 200
        periods[on], firsts[on] = n, judged
        if on:
            # in the judging period already: on the measured twist, at the measured rate (no feedback)
            assert judged[0] == "park" and judged[1] == pytest.approx(x0, abs=1e-12)
            assert judged[2] == pytest.approx(judged[3]) and d * judged[2] > 0.5
            # ... and the park ends on the preload planned, at rest
            assert ref_prev == pytest.approx(fine._pre, abs=1e-12)
            assert refs[-2][2] == pytest.approx(0.0, abs=0.05)
    assert firsts[False][2] == 0.0                                 # off: the observe servo, rate reference 0
    assert periods[True] < periods[False]


def _periods_to_engage(fine, err, p, deadband):
    """Periods from a new steady demand ``err`` (rad) off a valve at rest, after the stage saw the main law's
    breakaway on an earlier plateau, until the stage engages; ``deadband``: the main law's integrator deadband
    the law hands it each period (rad, or None)."""
    from test_fine_positioning import _break_loose, _rest_twist
    thl = 0.5
    _break_loose(fine, thl, p)
    th1 = thl + _rest_twist(fine, thl, p)
    for k in range(1, 400):
        fine.main_deadband_rad = deadband
        fine.update(thl + err, th1, thl, True, 0.3, p)
        if fine.phase != "idle":
            return k
    return None


@pytest.mark.parametrize("direction", [1, -1])
def test_engage_inside_the_main_laws_deadband_skips_the_fresh_wait(direction):
    """``fine.engage_inside_deadband`` (task h32d, §76; off by default): on a plateau the main law has not
    broken the valve loose on, the stage waits ``FRESH_WAIT`` engage times for it -- unless the error lies inside
    the main law's deadband by at least the tolerance, where the hold moves nothing: then it engages after the
    engage time.  Off, or an error near the deadband's edge, or no deadband handed over (a probing hold): the
    wait as before."""
    from fuel_valve_control.core.fine_positioning import FRESH_WAIT
    err = direction * 2.0e-3
    off, m = _stage()
    p = m.pressure_max_kpa
    wait = FRESH_WAIT * off.cfg.engage_periods
    assert _periods_to_engage(off, err, p, 4e-3) >= wait
    on, _ = _stage(**{"fine.engage_inside_deadband": True})
    tol = on.cfg.tolerance_rad
    assert _periods_to_engage(on, err, p, 4e-3) <= on.cfg.engage_periods + 2
    for band in (abs(err) + 0.5 * tol, None):
        late, _ = _stage(**{"fine.engage_inside_deadband": True})
        assert _periods_to_engage(late, err, p, band) >= wait


def test_the_law_hands_the_stage_its_deadband_unless_the_hold_probes():
    """The mode's law hands the stage the main law's deadband in force (rad), none where the hold may probe
    inside it (``integral.probe_shown_friction``)."""
    from fuel_valve_control.core.position_controller import PositionController
    from fuel_valve_control.core.params import CONTROLLER_SPEC
    for probe in (False, True):
        ps = CONTROLLER_SPEC.defaults().replace({"mode": "observer_fp", "integral.probe_shown_friction": probe})
        law = PositionController(ps).law
        law.main.deadband = 2.5e-3
        assert law._deadband_held() == (None if probe else 2.5e-3)


@pytest.mark.parametrize("direction", [1, -1])
def test_stairs_grow_after_many_unmoved_ones_bounded_by_the_worst_move(direction):
    """``fine.stair_growth_after`` = N (task h32e, §77; 0 = off, the default): the first N stairs of a staircase
    climb the fixed ``fine.doublet_probe_step`` x the band; the n-th unmoved stair after them climbs the floor x
    n / N, at most as far as the worst move it allows (smallest move + ``fine.stair_growth_slope`` x the stair)
    leaves half the error, never above ``fine.kick_rise_rad``; for an error whose smallest move leaves no room,
    the floor.  Off: every stair the floor (fails with the growth ignored)."""
    big_n, err = 4, direction * 0.9e-3
    fixed, m = _stage()
    p = m.pressure_max_kpa
    grown, _ = _stage(**{"fine.stair_growth_after": big_n})
    _, d_fixed = _stuck_staircase(fixed, err, p, stairs=10)
    _, d_grown = _stuck_staircase(grown, err, p, stairs=10)
    c_fixed = [a - b for a, b in zip(d_fixed, d_fixed[1:])]
    c_grown = [a - b for a, b in zip(d_grown, d_grown[1:])]
    floor = c_fixed[0]
    assert all(c == pytest.approx(floor) for c in c_fixed)
    assert d_grown[0] == pytest.approx(d_fixed[0])
    assert all(c == pytest.approx(floor) for c in c_grown[:big_n])
    cfg = grown.cfg
    cap = min((1.5 * abs(err) - grown._smallest_move(direction, p)) / cfg.stair_growth_slope, cfg.kick_rise_rad)
    assert cap > 1.5 * floor                     # the case leaves room to grow
    for i, c in enumerate(c_grown[big_n:], start=big_n + 1):
        assert c == pytest.approx(min(floor * i / big_n, cap), rel=1e-6)
    assert c_grown[-1] == pytest.approx(cap, rel=1e-6) and c_grown[-1] <= cfg.kick_rise_rad
    # an error the smallest move nearly fills: no room, the floor throughout
    small, _ = _stage(**{"fine.stair_growth_after": big_n})
    _, d_small = _stuck_staircase(small, direction * 0.6e-3, p, stairs=8)
    assert all(a - b == pytest.approx(floor, rel=1e-3) for a, b in zip(d_small, d_small[1:]))

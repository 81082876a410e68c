"""The deep retreat's trough bounded by the other way's breakaway (task h36g, docs §90).

``fine.retreat_trough_bound``: the deep retreat (``fine.retreat_cap``, two whole periods at the 30 A cap, docs §84) swings the
twist 7-17e-3 rad below the doublet's preload.  At max Δp the nominal valve's static band (2 T_s / K, ~23e-3 rad) holds it;
at low Δp (full box run 1069, Δp 0.98 MPa: band ~5.4e-3) or on a narrow band (friction x0.4, stiff coupling, docs §89) the
trough passes the other way's breakaway and the valve breaks loose backwards.  With the bound the stage predicts the trough
with the move model (:meth:`PulseMoves.trough`, a stuck valve from the kick's actual start) and retreats no deeper than
keeps it ``fine.doublet_sigmas`` learned scatters above the other way's learned level: fewer whole periods, then one period
scaled toward the hold.

Stage-alone tests (no plant; each a few move-model runs of ~5 ms, < 1 s per test)."""
import numpy as np
import pytest

from fuel_valve_control.core.params import CONTROLLER_SPEC
from fuel_valve_control.core.pulse_moves import PulseMoves
# main's staircase with the deep retreat (C1, the default since stop 25, off: the stage-alone pulse these tests drive)
from test_fine_positioning import _main_stage as _stage, _torques_until_observe

DEEP = {"fine.retreat_full_periods": 2, "fine.retreat_cap": True}
BOUND = {**DEEP, "fine.retreat_trough_bound": True}
#: a low Δp (fraction of the rated): the nominal valve's static band there is ~5-6e-3 rad of twist, as run 1069's
LOW_DP = 0.15


@pytest.mark.parametrize("direction", [1, -1])
def test_the_bound_keeps_the_deep_retreat_at_max_dp_and_makes_it_shallower_at_low_dp(direction):
    ps = CONTROLLER_SPEC.defaults()
    # the bound is C3's (the default since stop 28, docs §108); the misfit reading off
    assert ps["fine.retreat_trough_bound"] is True and ps["fine.retreat_trough_misfit"] is False
    err = direction * 0.5 * ps["fine.doublet_max_error_rad"]
    fine, m = _stage(**DEEP)
    cap = ps["fine.peak_current_a"] * m.torque_constant_nm_per_a
    # max Δp, the nominal valve: two periods at -cap with or without the bound (the trough stays inside the band)
    off = _torques_until_observe(fine, err, m.pressure_max_kpa)
    fine_b, _ = _stage(**BOUND)
    on = _torques_until_observe(fine_b, err, m.pressure_max_kpa)
    assert fine_b._retreat == (2, 1.0)
    assert on == pytest.approx(off, abs=0.0)
    assert on[-3] == pytest.approx(-direction * cap) and on[-2] == pytest.approx(-direction * cap)
    # low Δp: off, the same two periods at -cap (C1's shape) ...
    low = LOW_DP * m.pressure_max_kpa
    fine, _ = _stage(**DEEP)
    off = _torques_until_observe(fine, err, low)
    assert off[-3] == pytest.approx(-direction * cap) and off[-2] == pytest.approx(-direction * cap)
    assert fine._retreat == (2, 1.0)
    # ... on, shallower: one period, its command between the hold and -cap, the observe servo after it
    fine_b, _ = _stage(**BOUND)
    on = _torques_until_observe(fine_b, err, low)
    n, s = fine_b._retreat
    assert n == 1 and 0.0 <= s <= 1.0
    # the kick, one retreat period (at -cap if s is 1, else between the hold and it), then the observe servo
    assert on[-3] != pytest.approx(-direction * cap) and direction * on[-2] < direction * on[-3]
    assert direction * on[-2] >= -cap - 1e-12 and (s < 1.0 or on[-2] == pytest.approx(-direction * cap))
    assert fine_b._k == 1
    # the trough the model predicts for the chosen retreat stays inside the other way's level less the margin;
    # for the deep one it does not
    mv = fine_b._moves
    thl = fine_b._last_valve
    pre = fine_b._last_th1 - thl
    eo, bo, band = fine_b._twists(thl, low, -direction)
    limit = bo + direction * fine_b.cfg.doublet_sigmas * fine_b._scatter(-direction, band, abs(bo - eo))
    kw = dict(kick_current_a=ps["fine.kick_current_a"], valve_angle_rad=thl, speed0=fine_b._w1_now,
              hold0=fine_b._hold_torque)
    deep = mv.trough(direction, low, pre, retreat_periods=2, **kw)[0]
    assert direction * (deep - limit) < 0.0


def test_the_trough_model_on_a_stuck_valve():
    """:meth:`PulseMoves.trough`: deeper with more retreat periods and with a larger scale; at scale 1 the model's own
    retreat; the tables (the apex policy's moves) do not change with the new keywords' defaults."""
    fine, m = _stage(**DEEP)
    mv = PulseMoves.for_positioner(fine, retreat_full_periods=2, retreat_cap=True, retreat_cap_full=True,
                                   observe_hold_moved=True)
    p, th = m.pressure_max_kpa, 0.5
    pre = (m.load_torque(th, p) + m.friction(p).valve_static_nm) / m.coupling_stiffness_nm_per_rad - 1e-3
    d2, d1, d0 = (pre - mv.trough(1, p, pre, 4.0, th, retreat_periods=n)[0] for n in (2, 1, 0))
    assert d2 > d1 > d0 >= 0.0
    assert d2 > 5e-3                                  # the deep retreat swings several mrad (docs §84)
    scaled = pre - mv.trough(1, p, np.full(3, pre), 4.0, th, retreat_periods=1, retreat_scale=[1.0, 0.5, 0.0])
    assert scaled[0] == pytest.approx(d1) and scaled[0] > scaled[1] > scaled[2]
    # the kick's actual start matters: a gear output still running back from the move (a ringing park) swings deeper
    # (here 21.3e-3 rad against 16.9e-3 from rest); run 1069's park ran +1 rad/s on a decelerating hold of -2 A: 17.9e-3
    # from that state, 15.1e-3 from rest
    assert pre - mv.trough(1, p, pre, 4.0, th, retreat_periods=2, speed0=-1.0)[0] > d2 + 1e-3


@pytest.mark.parametrize("shape", [dict(retreat_full_periods=2, retreat_cap=True, retreat_cap_full=True,
                                        observe_hold_moved=True),
                                   dict(retreat_full_periods=1, retreat_cap=False)])
def test_the_fast_trough_is_the_move_models_to_the_bit(shape):
    """(task h40s, docs §105) :meth:`PulseMoves.trough_fast` -- the bound's trough one lane at a time in floats, ~13x
    less CPU -- gives :meth:`PulseMoves.trough`'s answer exactly: both directions, whole periods and scales, a ringing
    start, the stage's servo offset and final twist, the resolver delay, a low Δp."""
    fine, m = _stage(**DEEP)
    mv = PulseMoves.for_positioner(fine, **shape)
    th = 0.5
    for p in (m.pressure_max_kpa, LOW_DP * m.pressure_max_kpa):
        for d in (1, -1):
            pre = (m.load_torque(th, p) + d * m.friction(p).valve_static_nm) / m.coupling_stiffness_nm_per_rad \
                - d * 1e-3
            for kw in (dict(retreat_periods=2), dict(retreat_periods=1, retreat_scale=[1.0, 0.37, 0.0]),
                       dict(retreat_periods=2, speed0=-0.8 * d, hold0=0.2, servo_offset=0.01, ref_twist=pre + d * 5e-4),
                       dict(retreat_periods=2, servo_delay_s=2e-4, speed0=0.3)):
                pres = np.full(len(np.atleast_1d(kw.get("retreat_scale", [1.0]))), pre)
                slow = mv.trough(d, p, pres, 8.0, th, **kw)
                fast = mv.trough_fast(d, p, pres, 8.0, th, **kw)
                assert np.array_equal(slow, fast), (p, d, kw, slow - fast)


def _batch_scale(one: np.ndarray, room: float, scales: np.ndarray) -> float:
    """The 11-lane batch's answer (the stage's search before docs §111): the first point that fits, linearly."""
    if one[0] <= room:
        return 1.0
    for j in range(1, len(scales)):
        if one[j] <= room:
            f = (one[j - 1] - room) / max(one[j - 1] - one[j], 1e-12)
            return float(scales[j - 1] + f * (scales[j] - scales[j - 1]))
    return 0.0


def test_the_bisection_finds_the_batchs_scale_to_the_bit():
    """(docs §111) :func:`scaled_retreat` -- the retreat period's scale by bisection, 2 + log2(10) lane runs -- gives the
    linear scan's answer to the bit on falling depths (ties included) and any room, and runs no more lanes than that.
    (Fails if the bisection stopped on another grid pair, interpolated between other points or ran the whole grid.)"""
    from fuel_valve_control.core.fine_positioning import TROUGH_SCALES, scaled_retreat
    rng = np.random.default_rng(7)
    scales = np.linspace(1.0, 0.0, TROUGH_SCALES)
    most = 2 + int(np.ceil(np.log2(TROUGH_SCALES - 1)))
    for _ in range(2000):
        steps = rng.exponential(1e-3, TROUGH_SCALES) * (rng.random(TROUGH_SCALES) > 0.2)     # some flat stretches
        one = 12e-3 - np.cumsum(steps)
        room = float(rng.uniform(one[-1] - 1e-3, one[0] + 1e-3))
        if rng.random() < 0.1:
            room = float(one[rng.integers(TROUGH_SCALES)])                                   # exactly on a point
        runs = []
        got = scaled_retreat(lambda j: runs.append(j) or float(one[j]), room, scales)
        assert got == _batch_scale(one, room, scales)
        assert len(runs) <= most and len(set(runs)) == len(runs)


@pytest.mark.parametrize("direction", [1, -1])
def test_the_scaled_retreat_in_the_stage_is_the_eleven_lane_batchs(direction):
    """(docs §111) In the stage (Δp 0.04 x rated: one whole period would pass the other way's level; scaled to ~0.9
    opening, ~0.6 closing) the plan's scale is the batch's for the same state: every lane of an 11-lane batch equals
    the single lane the bisection ran at that scale, and the batch falls with the scale."""
    from fuel_valve_control.core.fine_positioning import TROUGH_SCALES
    ps = CONTROLLER_SPEC.defaults()
    err = direction * 0.5 * ps["fine.doublet_max_error_rad"]
    fine, m = _stage(**BOUND)
    calls = []
    orig = PulseMoves.trough_fast

    def spy(self, *a, **kw):
        out = orig(self, *a, **kw)
        calls.append((a, kw, out))
        return out

    PulseMoves.trough_fast = spy
    try:
        _torques_until_observe(fine, err, 0.04 * m.pressure_max_kpa)
    finally:
        PulseMoves.trough_fast = orig
    n, s = fine._retreat
    assert n == 1 and 0.0 < s < 1.0                 # this case takes the scaled path
    (d, p, pre), kw = calls[-1][0][:3], {k: v for k, v in calls[-1][1].items() if k != "retreat_scale"}
    scales = np.linspace(1.0, 0.0, TROUGH_SCALES)
    batch = orig(fine._moves, d, p, np.full(TROUGH_SCALES, pre), retreat_scale=scales, **kw)
    assert np.all(np.diff(d * (pre - batch)) <= 0.0)
    single = {float(c[1]["retreat_scale"]): float(c[2][0]) for c in calls if "retreat_scale" in c[1]}
    assert len(single) >= 3
    for sc, trough in single.items():
        assert trough == batch[int(np.argmin(np.abs(scales - sc)))]

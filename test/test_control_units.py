"""Unit tests of the control core against closed forms and independent computations.

Discretisation (scipy ``cont2discrete``), pole placement, the PI(D) loop shape, the
Luenberger / Kalman disturbance observers, the Friedland–Park friction observer, the I²t
current limiter and the SPEC §5 metrics on synthetic signals with known answers.
"""
import cmath
import math

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are
from scipy.signal import cont2discrete, lfilter

from fuel_valve_control.core import design
from fuel_valve_control.tools import metrics as M
from fuel_valve_control.core.params import CONTROLLER_SPEC
from fuel_valve_control.core.friction_observer import FrictionObserver
from fuel_valve_control.core.limits import CurrentLimiter
from fuel_valve_control.core.model import NominalModel, zoh
from fuel_valve_control.core.position_controller import design_all

PS = CONTROLLER_SPEC.defaults()
MODEL = NominalModel.from_params(PS)
T = 1.0 / PS["loop_rate_hz"]
LSB = 2.0 * math.pi / 65536


def _stiff_model(**changes) -> NominalModel:
    fields = {k: getattr(MODEL, k) for k in MODEL.__dataclass_fields__}
    fields.update(changes)
    return NominalModel(**fields)


# ----------------------------------------------------------------------------- discretisation
@pytest.mark.parametrize("period", [1e-3, 2.5e-4, 5e-3])
def test_zoh_discretisation_matches_scipy(period):
    a, bu, bd, cm = MODEL.continuous()
    ad, bud, bdd, cmd = MODEL.discrete(period)
    ref = cont2discrete((a, np.hstack([bu, bd]), cm, np.zeros((2, 2))), period, method="zoh")
    np.testing.assert_allclose(ad, ref[0], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.hstack([bud, bdd]), ref[1], rtol=1e-9, atol=1e-15)
    np.testing.assert_array_equal(cmd, cm)


def test_continuous_model_physics():
    a, bu, bd, cm = MODEL.continuous()
    # rigid-body check: a constant motor torque u against no spring accelerates J_total
    m0 = _stiff_model(spring_rate_nm_per_rad=0.0, motor_viscous_nms=0.0, valve_viscous_nms=0.0)
    a0, bu0, _, _ = m0.continuous()
    # coupling mode eigenvalue pair at the two-mass resonance (light damping), one double pole at 0
    ev = np.linalg.eigvals(a0)
    assert np.sum(np.abs(ev) < 1e-3) == 2
    wr = max(abs(ev.imag))
    assert wr == pytest.approx(m0.resonance_rad_s, rel=0.01)
    # static gain with spring: theta_L = N u / ks
    x = np.linalg.solve(-a, bu[:, 0])
    assert x[2] == pytest.approx(MODEL.gear_ratio / MODEL.spring_rate_nm_per_rad, rel=1e-9)
    assert x[0] - x[2] == pytest.approx(MODEL.gear_ratio / MODEL.coupling_stiffness_nm_per_rad, rel=1e-9)


def test_observer_model_disturbance_columns_are_zoh_of_the_load_inputs():
    ao, bo, bdo, co = MODEL.observer_model(T)
    a, _, _, _ = MODEL.continuous()
    dist = np.array([[0, 0], [-1 / MODEL.j1, 0], [0, 0], [0, -1 / MODEL.valve_inertia_kgm2]])
    ref = cont2discrete((a, dist, np.eye(4), np.zeros((4, 2))), T, method="zoh")
    np.testing.assert_allclose(ao[:4, 4:], ref[1], rtol=1e-9, atol=1e-15)
    np.testing.assert_array_equal(ao[4:, :], np.hstack([np.zeros((2, 4)), np.eye(2)]))
    # the valve-side disturbance dL enters exactly like the known valve load input
    np.testing.assert_allclose(ao[:4, 5], bdo[:4, 0], rtol=1e-12)
    np.testing.assert_array_equal(co[:, 4:], 0.0)
    assert bo[4:].tolist() == [[0.0], [0.0]]


def test_equilibrium_is_a_fixed_point_of_the_discrete_model():
    ad, bu, bd, _ = MODEL.discrete(T)
    for angle in (0.1, 0.5, 1.0):
        x, u = MODEL.equilibrium(angle, 6206.0)
        d = MODEL.load_torque(angle, 6206.0) - MODEL.spring_rate_nm_per_rad * angle   # spring is in A
        np.testing.assert_allclose(ad @ x + bu[:, 0] * u + bd[:, 0] * d, x, atol=1e-12)


# ----------------------------------------------------------------------------- pole placement
def test_continuous_poles_have_the_requested_frequencies_and_damping():
    poles = design.continuous_poles(MODEL, 12.0, 0.9, 0.35, 0.2, 1.0)
    wn, wr = 2 * math.pi * 12.0, MODEL.resonance_rad_s
    cplx = sorted([p for p in poles if p.imag > 0], key=abs)
    assert abs(cplx[0]) == pytest.approx(wn) and -cplx[0].real / abs(cplx[0]) == pytest.approx(0.9)
    assert abs(cplx[1]) == pytest.approx(wr) and -cplx[1].real / abs(cplx[1]) == pytest.approx(0.2)
    real = [p for p in poles if abs(p.imag) < 1e-12]
    assert len(real) == 1 and real[0] == pytest.approx(-0.35 * wn)
    # overdamped pair: two real poles with product wn² and sum -2 zeta wn
    od = design.continuous_poles(MODEL, 5.0, 1.5, 0.3, 0.2, 1.0)
    w = 2 * math.pi * 5.0
    r = sorted(p.real for p in od if abs(p.imag) < 1e-12 and abs(p.real + 0.3 * w) > 1e-9)
    assert r[0] * r[1] == pytest.approx(w * w) and r[0] + r[1] == pytest.approx(-3.0 * w)


@pytest.mark.parametrize("bw,zeta,ratio", [(12.0, 0.9, 0.35), (6.0, 0.7, 0.2), (20.0, 1.2, 0.5)])
def test_pole_placement_puts_the_closed_loop_poles_where_asked(bw, zeta, ratio):
    poles_s = design.continuous_poles(MODEL, bw, zeta, ratio, 0.2, 1.0)
    fb = design.place_state_feedback(MODEL, T, poles_s)
    # closed loop built here from the returned gains: x+ = Ad x + Bu u, zeta+ = zeta - T thL,
    # u = -K x + KI zeta
    ad, bu, _, _ = MODEL.discrete(T)
    acl = np.zeros((5, 5))
    acl[:4, :4] = ad - np.outer(bu[:, 0], fb.k)
    acl[:4, 4] = bu[:, 0] * fb.ki
    acl[4, 2] = -T
    acl[4, 4] = 1.0
    got = np.sort_complex(np.linalg.eigvals(acl))
    want = np.sort_complex(np.exp(poles_s * T))
    np.testing.assert_allclose(got, want, atol=1e-7)
    assert fb.ki > 0.0          # integral of r - thL pushes toward the demand


def test_integral_action_gives_zero_steady_state_error_on_the_linear_model():
    fb = design.place_state_feedback(MODEL, T, design.continuous_poles(MODEL, 12.0, 0.9, 0.35, 0.2, 1.0))
    ad, bu, bd, _ = MODEL.discrete(T)
    x, z, r, d = np.zeros(4), 0.0, 0.05, 3.0       # unknown constant load of 3 N*m
    for _ in range(3000):
        u = -fb.k @ x + fb.ki * z
        z += T * (r - x[2])
        x = ad @ x + bu[:, 0] * u + bd[:, 0] * d
    assert x[2] == pytest.approx(r, abs=1e-9)


def test_lqr_gain_is_the_riccati_optimum_and_stabilises():
    q, r = design.bryson_weights(MODEL, 0.002, 2.0, 0.005, 2e-4, 10.0)
    fb = design.lqr_state_feedback(MODEL, T, q, r)
    assert np.all(np.abs(fb.poles) < 1.0)
    ad, bu, _, _ = MODEL.discrete(T)
    aa, ba = design.augmented(ad, bu, T)
    gain = np.hstack([fb.k, [-fb.ki]])
    # the optimal gain minimises the cost: any perturbation of it raises the infinite-horizon
    # cost x0' P x0 (P solved here by iterating the closed-loop Lyapunov sum)
    def cost(kvec, x0):
        acl = aa - ba @ kvec[None, :]
        qq = q + r * np.outer(kvec, kvec)
        p = np.zeros((5, 5))
        for _ in range(20000):
            p = qq + acl.T @ p @ acl
        return float(x0 @ p @ x0)
    x0 = np.array([1e-3, 0.0, 1e-3, 0.0, 0.0])
    best = cost(gain, x0)
    rng = np.random.default_rng(1)
    for _ in range(4):
        assert cost(gain * (1.0 + 0.05 * rng.standard_normal(5)), x0) > best


# ----------------------------------------------------------------------------- PI(D) loop shape
def _drive_voltage(model, valve_speed, current):
    """dq voltage amplitude written out here (not the shared helper): R i + ωe ψ on q,
    ωe Lq i on d, ωe = p N v, ψ = Kt / (1.5 p)."""
    we = model.motor_pole_pairs * model.gear_ratio * valve_speed
    psi = model.torque_constant_nm_per_a / (1.5 * model.motor_pole_pairs)
    return math.hypot(model.motor_resistance_ohm * current + we * psi, we * model.motor_lq_h * current)


@pytest.mark.parametrize("supply", [18.0, 28.0, 32.0])
def test_trajectory_design_plans_within_the_drives_voltage_and_current(supply):
    frac_i, frac_v = PS["trajectory.current_fraction"], PS["trajectory.voltage_fraction"]
    lim = design.design_trajectory(MODEL, supply, PS["limits.peak_current_a"], frac_i, frac_v)
    kt_n = MODEL.torque_constant_nm_per_a * MODEL.gear_ratio
    viscous = MODEL.valve_viscous_nms + MODEL.b1
    circle = supply / math.sqrt(3.0)
    # cruising at the top speed against the worst known load uses the voltage fraction exactly
    cruise = (viscous * lim.max_velocity_rad_s + lim.resisting_torque_nm) / kt_n
    assert _drive_voltage(MODEL, lim.max_velocity_rad_s, cruise) == pytest.approx(frac_v * circle, rel=1e-6)
    # the peak acceleration takes at most the planned current against that load ...
    assert (MODEL.total_inertia * lim.max_acceleration_rad_s2 + lim.resisting_torque_nm) / kt_n \
        <= frac_i * PS["limits.peak_current_a"] * (1 + 1e-9)
    # ... and the whole sin² acceleration phase stays inside the voltage circle
    s = np.linspace(0.0, 1.0, 401)
    v = lim.max_velocity_rad_s * (s - np.sin(2 * np.pi * s) / (2 * np.pi))
    i = (MODEL.total_inertia * lim.max_acceleration_rad_s2 * np.sin(np.pi * s) ** 2 + viscous * v
         + lim.resisting_torque_nm) / kt_n
    assert max(_drive_voltage(MODEL, vk, ik) for vk, ik in zip(v, i)) <= circle * (1 + 1e-3)


def test_trajectory_top_speed_follows_the_supply():
    speeds = [design.design_trajectory(MODEL, u, PS["limits.peak_current_a"], PS["trajectory.current_fraction"],
                                       PS["trajectory.voltage_fraction"]).max_velocity_rad_s for u in (18, 24, 28, 32)]
    assert speeds == sorted(speeds) and speeds[0] < 0.7 * speeds[2]


def test_trajectory_design_refuses_a_current_budget_below_the_load():
    with pytest.raises(design.ConfigError, match="cannot move the worst known load"):
        design.design_trajectory(MODEL, 28.0, PS["limits.peak_current_a"], 0.2, 0.95)


def test_pi_design_gives_crossover_and_phase_margin_on_the_nominal_plant():
    g = design.design_pid(MODEL, T, PS["pi.crossover_hz"], PS["pi.phase_margin_deg"],
                          PS["pi.integral_corner_ratio"], PS["pi.derivative_filter_ratio"])

    # continuous loop with the design's 1.5-period sample/compute delay, computed here
    def loop(w):
        s = 1j * w
        c = g.kp * (1 + g.wi / s) * (1 + s / g.wz) / (1 + s / g.wp)
        return c * design.valve_response(MODEL, w) * cmath.exp(-s * 1.5 * T)

    wc = _crossover(loop, 2 * math.pi * 1.0, 2 * math.pi * 50.0)
    assert wc / (2 * math.pi) == pytest.approx(PS["pi.crossover_hz"], rel=0.01)
    assert 180.0 + math.degrees(cmath.phase(loop(wc))) == pytest.approx(PS["pi.phase_margin_deg"], abs=0.5)

    # the law as implemented (Tustin lead, rectangular integral) on the ZOH plant, one period of
    # computation delay: the discrete loop still has ~10 Hz / ~45 deg
    ad, bu, _, _ = MODEL.discrete(T)
    k = 2.0 / T
    den = 1.0 + k / g.wp
    b0, b1, a1 = (1 + k / g.wz) / den, (1 - k / g.wz) / den, (1 - k / g.wp) / den

    def dloop(w):
        z = cmath.exp(1j * w * T)
        plant = np.linalg.solve(z * np.eye(4) - ad, bu[:, 0])[2]
        ctrl = g.kp * (b0 + b1 / z) / (1 + a1 / z) * (1 + g.wi * T / (z - 1))
        return ctrl * plant / z

    wcd = _crossover(dloop, 2 * math.pi * 1.0, 2 * math.pi * 50.0)
    assert wcd / (2 * math.pi) == pytest.approx(10.0, abs=0.5)
    assert 180.0 + math.degrees(cmath.phase(dloop(wcd))) == pytest.approx(45.0, abs=5.0)


def _crossover(loop, lo, hi):
    """Unique |L| = 1 crossing in [lo, hi] (bisection in log frequency)."""
    assert abs(loop(lo)) > 1.0 > abs(loop(hi))
    for _ in range(80):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if abs(loop(mid)) > 1.0 else (lo, mid)
    return math.sqrt(lo * hi)


# ----------------------------------------------------------------------------- Luenberger / Kalman
DESIGNS = design_all(PS, MODEL)
AO, BO, BDO, CO = MODEL.observer_model(T)


def test_luenberger_observer_poles_are_placed():
    poles = design.observer_poles(MODEL, PS["design.bandwidth_hz"], PS["observer.bandwidth_ratio"], T)
    got = np.sort_complex(np.linalg.eigvals(AO - DESIGNS.observer_gain @ CO @ AO))
    np.testing.assert_allclose(got, np.sort_complex(np.exp(poles * T)), atol=1e-7)
    assert np.all(np.abs(poles) <= 0.45 * math.pi / T + 1e-9)


def _run_observer(gain, steps, noise_counts=0.0, seed=0):
    """Plant = the 4-state model with unknown constant loads; observer = current estimator with
    disturbance states.  Returns the estimation error history (states 0..5)."""
    rng = np.random.default_rng(seed)
    ad, bu, bd, _ = MODEL.discrete(T)
    d1, dl = 0.3, 4.0                                        # unknown loads, N*m
    x = np.array([0.2 + 4.0 / MODEL.coupling_stiffness_nm_per_rad, 0.0, 0.2, 0.0])
    xo = np.zeros(6)
    dist = np.array([0.0, -d1 / MODEL.j1, 0.0, -dl / MODEL.valve_inertia_kgm2])
    load = zoh(MODEL.continuous()[0], dist[:, None], T)[1][:, 0]    # exact effect of the loads
    errs = []
    u_prev = 0.0
    for k in range(steps):
        y = np.array([x[0], x[2]]) + noise_counts * LSB * rng.standard_normal(2) * np.array([1 / 48.0, 1.0])
        x_bar = AO @ xo + BO[:, 0] * u_prev                     # predicted with last period's torque
        xo = x_bar + gain @ (y - CO @ x_bar)
        errs.append(np.concatenate([x, [d1, dl]]) - xo)
        u = u_prev = 0.2 * math.sin(2 * math.pi * 3.0 * k * T)   # persistent, moderate excitation
        x = ad @ x + bu[:, 0] * u + load
    return np.array(errs)


@pytest.mark.parametrize("which", ["luenberger", "kalman"])
def test_observer_estimation_error_decays(which):
    gain = DESIGNS.observer_gain if which == "luenberger" else DESIGNS.kalman_gain
    rho = max(abs(np.linalg.eigvals(AO - gain @ CO @ AO)))
    assert rho < 1.0
    steps = int(min(2000, max(200, 30 / -math.log(rho))))
    e = _run_observer(gain, steps)
    e0 = np.abs(e[0])
    assert e0[5] > 1.0                               # started 4 N*m wrong on the valve load
    tail = np.abs(e[-20:]).max(axis=0)
    assert tail[2] < 1e-9 and tail[3] < 1e-6         # valve angle and velocity exact
    assert tail[5] < 1e-4 * 4.0 and tail[4] < 1e-3   # unknown loads identified
    # and the decay follows the error dynamics: no slower than the slowest pole allows
    for k in (10, 20, 30):
        assert np.abs(e[k]).max() <= 1e2 * rho ** k * np.abs(e[0]).max()


def _kalman_noise():
    """Process (random-walk load torques) and measurement noise of the design, built here."""
    qn = np.diag([(PS["kalman.motor_torque_noise_nm"] * MODEL.gear_ratio) ** 2, PS["kalman.torque_noise_nm"] ** 2])
    rn = np.diag([(PS["kalman.measurement_counts"] * LSB / MODEL.gear_ratio) ** 2,
                  (PS["kalman.measurement_counts"] * LSB) ** 2])
    return qn, rn, np.vstack([np.zeros((4, 2)), np.eye(2)])


def test_kalman_gain_is_the_steady_state_of_the_riccati_recursion():
    qn, rn, g = _kalman_noise()
    # iterate the filter covariance recursion (predict / update) to convergence
    p = np.eye(6) * 1e-2
    for _ in range(20000):
        pp = AO @ p @ AO.T + g @ qn @ g.T
        kk = pp @ CO.T @ np.linalg.inv(CO @ pp @ CO.T + rn)
        p_new = (np.eye(6) - kk @ CO) @ pp
        if np.allclose(p_new, p, rtol=1e-12, atol=1e-30):
            break
        p = p_new
    np.testing.assert_allclose(DESIGNS.kalman_gain, kk, rtol=1e-5, atol=1e-9)
    # and the dual DARE solution is the a-priori covariance
    pa = solve_discrete_are(AO.T, CO.T, g @ qn @ g.T, rn)
    np.testing.assert_allclose(pa, pp, rtol=1e-5, atol=1e-18)


def test_kalman_filter_error_covariance_matches_its_design_noise():
    """Driven by exactly the noise it was designed for (random-walk loads, resolver noise),
    the filter's empirical error variance equals its own a-posteriori covariance."""
    qn, rn, g = _kalman_noise()
    pa = solve_discrete_are(AO.T, CO.T, g @ qn @ g.T, rn)
    p_post = pa - DESIGNS.kalman_gain @ CO @ pa
    rng = np.random.default_rng(7)
    x, xo, n, errs = np.zeros(6), np.zeros(6), 40000, []
    lw, lv = np.linalg.cholesky(qn), np.linalg.cholesky(rn)
    for k in range(n):
        x = AO @ x + g @ (lw @ rng.standard_normal(2))
        x_bar = AO @ xo
        xo = x_bar + DESIGNS.kalman_gain @ (CO @ x + lv @ rng.standard_normal(2) - CO @ x_bar)
        errs.append(x - xo)
    var = np.var(np.array(errs)[1000:], axis=0)
    np.testing.assert_allclose(var, np.diag(p_post), rtol=0.1)
    # and it does better than the raw valve resolver on the valve angle
    assert var[2] < rn[1, 1]


# ----------------------------------------------------------------------------- Friedland-Park
def _shaft(fp: FrictionObserver, a_true: float, v_of_t, steps: int, period: float = T):
    """Shaft with Coulomb friction a_true (per unit inertia) forced to follow v_of_t: the
    non-friction acceleration is what the motion needs plus the friction."""
    hist = []
    for k in range(steps):
        t = k * period
        v = v_of_t(t)
        dv = (v_of_t(t + period) - v) / period
        w = dv + a_true * math.copysign(1.0, v) if v != 0 else dv
        hist.append(fp.update(v, w))
    return np.array(hist)


@pytest.mark.parametrize("alpha,beta,cap", [(2.0, 1.5, 200.0), (5.0, 1.0, 100.0), (1.1, 3.0, 200.0)])
def test_friedland_park_converges_to_the_true_coulomb_level(alpha, beta, cap):
    a_true = 2500.0                        # rad/s² (4.4 N*m on the 1.76e-3 kg*m² valve)
    fp = FrictionObserver(alpha, beta, cap, 0.05, T, initial_level=0.0)
    # persistent motion in one direction, with varying speed
    lv = _shaft(fp, a_true, lambda t: 1.0 + 0.5 * math.sin(2 * math.pi * 0.7 * t), 5000)
    assert lv[-1] == pytest.approx(a_true, rel=1e-3)
    # and back from an overestimate, with reversals (frozen while crossing zero speed)
    fp.reset(2.0 * a_true)
    lv = _shaft(fp, a_true, lambda t: 1.5 * math.sin(2 * math.pi * 0.5 * t + 0.3), 8000)
    assert lv[-1] == pytest.approx(a_true, rel=1e-3)


def test_friedland_park_error_decays_at_the_closed_form_rate():
    """Constant speed v: e[k+1] = (1 - T alpha beta |v|^(beta-1)) e[k] exactly."""
    alpha, beta, v, a_true = 2.0, 1.5, 4.0, 1000.0
    fp = FrictionObserver(alpha, beta, 200.0, 0.05, T, initial_level=200.0)
    g = alpha * beta * v ** (beta - 1.0)
    assert fp.gain(v) == pytest.approx(g)
    levels = _shaft(fp, a_true, lambda t: v, 50)
    e = a_true - levels
    k = np.arange(1, 51)
    np.testing.assert_allclose(e, (a_true - 200.0) * (1.0 - T * g) ** k, rtol=1e-9)


def test_friedland_park_gain_cap_freeze_and_limits():
    fp = FrictionObserver(2.0, 3.0, 150.0, 0.5, T, initial_level=10.0, max_level=50.0)
    assert fp.gain(100.0) == 150.0                           # αβ|v|^(β-1) = 60000 capped
    assert fp.gain(1.0) == pytest.approx(6.0)
    # below the freeze speed the estimate does not move, whatever the acceleration says
    for _ in range(100):
        assert fp.update(0.3, 1e6) == 10.0
    # never negative, never above max_level
    for _ in range(200):
        fp.update(10.0, 1e9)
    assert fp.level == 50.0
    for _ in range(200):
        fp.update(10.0, -1e9)
    assert fp.level == 0.0
    # smooth sign: fades linearly to zero inside the freeze speed
    fp.reset(20.0)
    assert fp.compensation(0.25) == pytest.approx(10.0) and fp.compensation(-5.0) == -20.0
    with pytest.raises(ValueError):
        FrictionObserver(2.0, 1.5, 1000.0, 0.05, 1e-3)       # T * cap >= 1: unstable update


# ----------------------------------------------------------------------------- I²t limiter
def test_i2t_limiter_allows_peak_for_peak_time_then_continuous():
    lim = CurrentLimiter(37.0, 0.02, 15.0, T)
    budget = (37.0 ** 2 - 15.0 ** 2) * 0.02
    assert lim.budget == pytest.approx(budget)
    out = np.array([lim.apply(50.0) for _ in range(100)])
    full = np.flatnonzero(out == 37.0)
    assert len(full) == round(budget / ((37.0 ** 2 - 15.0 ** 2) * T))   # 20 periods at the peak
    assert np.all(np.diff(out) <= 1e-12)                     # never increases while overloaded
    assert np.all(out[25:] == 15.0)
    assert lim.saturated
    i2t = np.sum((out ** 2 - 15.0 ** 2) * T)
    assert i2t == pytest.approx(budget, rel=1e-9)           # the budget is spent exactly
    # overload time counts the periods asking for more than continuous with no budget left
    n_exhausted = len(out) - np.flatnonzero(out > 15.0 + 1e-9)[-1] - 1
    assert lim.overload_time == pytest.approx(n_exhausted * T)


def test_i2t_limiter_recovers_and_is_symmetric():
    lim = CurrentLimiter(37.0, 0.02, 15.0, T)
    per_period = (37.0 ** 2 - 15.0 ** 2) * T                  # budget one period at the peak uses
    for _ in range(60):
        lim.apply(-60.0)
    assert lim.apply(-60.0) == -15.0 and lim.saturated
    # at zero current the budget drains at I_cont² A²/s: after 50 ms, 11.25 A²s are back,
    # i.e. 9 full periods at the peak and one partial one
    for _ in range(50):
        lim.apply(0.0)
    assert lim.overload_time == 0.0
    out = np.array([lim.apply(-60.0) for _ in range(30)])
    back = 15.0 ** 2 * 0.050
    assert np.count_nonzero(out == -37.0) == math.floor(back / per_period)
    assert -37.0 < out[math.floor(back / per_period)] < -15.0
    # the whole budget is back after (37²-15²)*0.02/15² = 0.1017 s: 20 periods at the peak again
    for _ in range(102):
        lim.apply(0.0)
    out = np.array([lim.apply(60.0) for _ in range(30)])
    assert np.count_nonzero(out == 37.0) == 20
    # requests within the continuous rating are never touched
    lim.reset()
    assert all(lim.apply(x) == x for x in np.linspace(-15, 15, 301)) and not lim.saturated


# ----------------------------------------------------------------------------- metrics
DT = 1e-4


def _trace(t, demand, position, current=None, enable=None, stroke=1.0472):
    n = len(t)
    return M.Trace(t, demand, position, np.zeros(n) if current is None else current,
                   np.ones(n) if enable is None else enable, stroke)


def _step_trace(response, t_step=0.5, duration=3.0, r0=0.2, r1=0.7):
    t = np.arange(0.0, duration, DT)
    tau = np.clip(t - t_step, 0.0, None)
    demand = np.where(t < t_step, r0, r1)
    pos = r0 + (r1 - r0) * response(tau)
    return _trace(t, demand, pos)


def test_metrics_first_order_step_rise_settling_no_overshoot():
    tau = 0.05
    m, _ = M.compute(_step_trace(lambda s: 1.0 - np.exp(-s / tau)))
    assert m["rise_time_s"] == pytest.approx(tau * math.log(9.0), abs=2 * DT)
    assert m["settling_time_s"] == pytest.approx(tau * math.log(50.0), abs=2 * DT)   # 2 % band
    assert m["overshoot_pct"] == 0.0
    assert m["steady_state_error_rad"] < 1e-12
    # IAE of a first-order step = step * tau
    assert m["iae_rad_s"] == pytest.approx(0.5 * tau, abs=0.5 * DT)


@pytest.mark.parametrize("zeta", [0.2, 0.5, 0.7])
def test_metrics_second_order_overshoot(zeta):
    wn = 2 * math.pi * 5.0
    wd = wn * math.sqrt(1 - zeta ** 2)
    phi = math.acos(zeta)

    def resp(s):
        return 1.0 - np.exp(-zeta * wn * s) * np.sin(wd * s + phi) / math.sqrt(1 - zeta ** 2)

    m, _ = M.compute(_step_trace(resp))
    assert m["overshoot_pct"] == pytest.approx(100 * math.exp(-math.pi * zeta / math.sqrt(1 - zeta ** 2)), rel=1e-3)


def test_metrics_settling_band_is_a_tenth_degree_for_small_steps():
    # 2 mrad step: the band is max(2 % of the step, 0.1 deg = 1.745e-3 rad), so an offset of
    # 1.6e-3 rad (far outside 2 % of the step, inside 0.1 deg) counts as settled; 1.9e-3 does not
    t = np.arange(0.0, 2.0, DT)
    demand = np.where(t < 0.5, 0.3, 0.302)
    pos = np.where(t < 0.6, 0.3, 0.302 - 1.6e-3)
    m, _ = M.compute(_trace(t, demand, pos))
    assert m["settling_time_s"] == pytest.approx(0.1, abs=2 * DT)
    assert m["steady_state_error_rad"] == pytest.approx(1.6e-3, rel=1e-6)
    pos = np.where(t < 0.6, 0.3, 0.302 - 1.9e-3)              # outside: never settles
    m, _ = M.compute(_trace(t, demand, pos))
    assert m["settling_time_s"] is None


@pytest.mark.parametrize("amp,freq", [(5e-3, 0.2), (1e-2, 1.25), (1e-3, 3.0)])
def test_metrics_limit_cycle_of_a_synthetic_sine(amp, freq):
    t = np.arange(0.0, 30.0, 1e-3)
    demand = np.full_like(t, 0.2)
    pos = 0.2 + 1e-4 + amp * np.sin(2 * math.pi * freq * t)
    m, _ = M.compute(_trace(t, demand, pos))
    assert m["limit_cycle_amplitude_rad"] == pytest.approx(amp, rel=1e-3)
    window = 15.0                                              # settled half of the 30 s hold
    assert m["limit_cycle_frequency_hz"] == pytest.approx(freq, abs=1.0 / window)
    assert m["steady_state_error_rad"] == pytest.approx(1e-4, abs=amp / 50)


def test_metrics_limit_cycle_within_one_count_has_no_frequency():
    t = np.arange(0.0, 10.0, 1e-3)
    pos = 0.2 + 0.9 * M.RESOLVER_COUNT_RAD * np.sin(2 * math.pi * 2.0 * t)
    m, _ = M.compute(_trace(t, np.full_like(t, 0.2), pos))
    assert m["limit_cycle_amplitude_rad"] <= M.RESOLVER_COUNT_RAD
    assert m["limit_cycle_frequency_hz"] == 0.0


@pytest.mark.parametrize("fc", [3.0, 8.0])
def test_metrics_bandwidth_of_a_first_order_lag(fc):
    """A first-order lag with corner fc, driven by the sine_sweep chirp, has -3 dB at fc."""
    dt = 1e-3
    t = np.arange(0.0, 17.0, dt)
    f0, f1, t0, dur = 0.5, 20.0, 0.5, 16.0
    s = np.clip(t - t0, 0.0, dur)
    k = math.log(f1 / f0) / dur
    phase = 2 * math.pi * f0 * (np.exp(k * s) - 1.0) / k
    demand = 0.5 + 0.02 * np.where((t >= t0) & (t <= t0 + dur), np.sin(phase), 0.0)
    a = math.exp(-2 * math.pi * fc * dt)                       # exact discretisation of the lag
    pos = lfilter([1 - a], [1, -a], demand - 0.5, zi=[0.0])[0] + 0.5
    m, segs = M.compute(_trace(t, demand, pos))
    assert any(s["kind"] == "sweep" for s in segs)
    assert m["bandwidth_hz"] == pytest.approx(fc, rel=0.08)


def test_metrics_bandwidth_is_the_top_frequency_when_never_below_3db():
    t = np.arange(0.0, 5.0, 1e-3)
    demand = np.where(t > 0.5, 0.5 + 0.02 * np.sin(2 * math.pi * 4.0 * (t - 0.5)), 0.5)
    m, _ = M.compute(_trace(t, demand, demand.copy()))
    assert m["bandwidth_hz"] == pytest.approx(4.0, rel=0.01)


def test_metrics_stroke_close_and_currents():
    stroke, speed = 1.0472, 10.0                               # rad, rad/s
    t = np.arange(0.0, 1.5, DT)
    demand = np.where(t < 0.3, 0.0, stroke)
    pos = np.clip((t - 0.3) * speed, 0.0, stroke)
    cur = 20.0 * np.sin(2 * math.pi * 7.0 * t)
    m, _ = M.compute(_trace(t, demand, pos, current=cur, stroke=stroke))
    assert m["stroke_time_s"] == pytest.approx(0.98 * stroke / speed, abs=2 * DT)
    assert m["peak_current_a"] == pytest.approx(20.0, rel=1e-4)
    assert m["rms_current_a"] == pytest.approx(20.0 / math.sqrt(2), rel=1e-3)
    # trip at 0.5 s from full open, the spring closes at constant speed
    t = np.arange(0.0, 1.0, DT)
    pos = np.where(t < 0.5, stroke, np.clip(stroke - (t - 0.5) * 12.0, 0.0, None))
    en = (t < 0.5).astype(float)
    m, _ = M.compute(_trace(t, np.full_like(t, stroke), pos, enable=en, stroke=stroke))
    assert m["close_time_s"] == pytest.approx(0.98 * stroke / 12.0, abs=2 * DT)

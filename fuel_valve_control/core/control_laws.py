"""Position control laws (SPEC §3).  Each turns a demand and a resolver sample into a motor
torque request once per loop period; :class:`~.position_controller.PositionController` picks
one, converts torque to current and applies the current limits.

Conventions: angles rad (valve side unless named motor), velocities rad/s, torques N*m at the
motor shaft unless a name says valve; ``θ1 = θm / N``.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from .compensation import Compensator, Context
from .design import PIDGains, StateFeedback
from .model import NominalModel
from .trajectory import Reference, TrajectoryShaper


@dataclass(frozen=True)
class Measurement:
    """One resolver sample: motor shaft angle (multi-turn, rad) and valve angle (rad)."""

    motor_rad: float
    valve_rad: float


@dataclass(frozen=True)
class Estimate:
    """What the law believes: angles/velocities of both shafts (motor side in motor units) and
    estimated friction torques (N*m, motor at the motor shaft, valve at the valve shaft)."""

    motor_angle: float
    motor_velocity: float
    valve_angle: float
    valve_velocity: float
    motor_friction_nm: float = 0.0
    valve_friction_nm: float = 0.0


class ControlLaw:
    """Interface of a control law."""

    name = "base"

    def reset(self, meas: Measurement, torque_nm: float, pressure_kpa: float) -> None:
        """(Re)start from a measurement so that the first output equals ``torque_nm`` (bumpless)."""
        raise NotImplementedError

    def update(self, t: float, demand_rad: float, meas: Measurement, pressure_kpa: float) -> float:
        """Torque request for this period, N*m at the motor."""
        raise NotImplementedError

    def applied(self, torque_nm: float, saturated: bool) -> None:
        """The torque actually applied after limits (for observers and anti-windup)."""

    def estimate(self) -> Estimate:
        raise NotImplementedError


class PIDLaw(ControlLaw):
    """The existing analog driver: series PI(D) on the valve resolver, linear tuning.

    ``C(s) = kp (1 + wi/s) (1 + s/wz)/(1 + s/wp)``: the lead part is discretised with Tustin,
    the integral is conditional (frozen while the current is limited).  ``dither`` adds the
    field workaround: a sine of ``dither_amplitude`` rad at ``dither_hz`` on the demand.
    """

    def __init__(self, gains: PIDGains, model: NominalModel, period_s: float,
                 dither_amplitude: float = 0.0, dither_hz: float = 25.0):
        self.name = "pi_dither" if dither_amplitude > 0 else "pi"
        self.g = gains
        self.model = model
        self.period = period_s
        self.dither_amplitude = dither_amplitude
        self.dither_hz = dither_hz
        # Tustin of (1 + s/wz)/(1 + s/wp): y[k] = b0 e[k] + b1 e[k-1] - a1 y[k-1]
        k = 2.0 / period_s
        den = 1.0 + k / gains.wp
        self._b0 = (1.0 + k / gains.wz) / den
        self._b1 = (1.0 - k / gains.wz) / den
        self._a1 = (1.0 - k / gains.wp) / den
        self._e1 = 0.0
        self._y1 = 0.0
        self._integral = 0.0
        self._pending = 0.0
        self._last_valve = None
        self._valve_velocity = 0.0
        self._motor_last = None
        self._motor_velocity = 0.0
        self._meas = Measurement(0.0, 0.0)

    def reset(self, meas, torque_nm, pressure_kpa):
        self._e1 = self._y1 = 0.0
        self._integral = torque_nm / (self.g.kp * self.g.wi)
        self._last_valve = meas.valve_rad
        self._motor_last = meas.motor_rad
        self._valve_velocity = self._motor_velocity = 0.0
        self._meas = meas

    def update(self, t, demand_rad, meas, pressure_kpa):
        if self._last_valve is not None:
            self._valve_velocity = (meas.valve_rad - self._last_valve) / self.period
            self._motor_velocity = (meas.motor_rad - self._motor_last) / self.period
        self._last_valve, self._motor_last, self._meas = meas.valve_rad, meas.motor_rad, meas
        r = demand_rad
        if self.dither_amplitude > 0.0:
            r += self.dither_amplitude * math.sin(2.0 * math.pi * self.dither_hz * t)
        e = r - meas.valve_rad
        y = self._b0 * e + self._b1 * self._e1 - self._a1 * self._y1
        self._e1, self._y1 = e, y
        self._pending = self.period * y
        return self.g.kp * (y + self.g.wi * self._integral)

    def applied(self, torque_nm, saturated):
        if not saturated:
            self._integral += self._pending

    def estimate(self):
        return Estimate(self._meas.motor_rad, self._motor_velocity, self._meas.valve_rad, self._valve_velocity)


@dataclass(frozen=True)
class IntegralPolicy:
    """Integral action near the target (the anti-hunting measure of SPEC §6).

    With stiction above Coulomb friction every breakaway jumps ~2 (Ts - Tc)/K; an integrator
    that keeps pushing inside that distance can only hunt.  The integrator is therefore frozen
    while the error is inside ``max(min_rad, jump_fraction * jump(Δp))`` and during planned moves.
    Outside it, a valve that is stuck gets its torque ramped (at least) at ``Ts(Δp) /
    stuck_ramp_time_s`` until it breaks away: quasi-static, so the jump stays the physical
    minimum, but much quicker than the integrator alone (whose rate shrinks with the error).
    Inside it, once the valve is at rest, the drive relaxes toward the middle of the static
    band (valve torque = known load) with time constant ``relax_time_s``.
    """

    jump_fraction: float
    min_rad: float
    stuck_speed: float = 0.03          # rad/s: at or below, the valve counts as stuck
    stuck_ramp_time_s: float = math.inf  # time to ramp through Ts while stuck outside the deadband
    relax_time_s: float = 0.0          # time constant of relaxing a settled drive (0 = off)

    def deadband(self, model: NominalModel, pressure_kpa: float, jump_ratio: float = 1.0) -> float:
        """``max(min_rad, jump_fraction * jump)``, the jump being the nominal one times the
        measured/nominal ratio learned by :class:`JumpLearner`."""
        jump = model.friction(pressure_kpa).stick_slip_jump_rad(model.coupling_stiffness_nm_per_rad)
        return max(self.min_rad, self.jump_fraction * jump * jump_ratio)


class JumpLearner:
    """Measures the breakaway jumps the valve actually makes while holding.

    The nominal jump ``2 (Ts - Tc)/K`` assumes nominal friction and coupling; a worn valve or
    a soft coupling (x 0.1 stiffness) jumps much further, and a deadband sized for the
    nominal jump would then hunt.  Each hold-phase breakaway (stuck -> sliding -> stuck) gives
    a measured jump; the ratio measured/nominal is tracked with gain ``gain``.  Moves shorter
    than ``min_jump`` (three resolver counts) are reading noise and are ignored.

    The upper limit must cover the robustness box of SPEC §6: friction x 3 on a coupling
    x 0.1 jumps 30x the nominal jump at any Δp (a cap of 20 left that corner hunting at
    Δp = 0); 50 gives margin.
    """

    def __init__(self, gain: float = 0.5, limits: tuple[float, float] = (0.5, 50.0), min_jump: float = 3e-4):
        self.gain = gain
        self.min_jump = min_jump          # rad: smaller "jumps" are resolver noise, not breakaways
        self.limits = limits
        self.ratio = 1.0
        self._stuck_at: float | None = None
        self._start: float | None = None

    def update(self, valve: float, stuck: bool, holding: bool, nominal_jump: float) -> None:
        if not holding:
            self._start = None
        elif not stuck and self._stuck_at is not None and self._start is None:
            self._start = self._stuck_at                      # broke away while holding
        elif stuck and self._start is not None:
            jump = abs(valve - self._start)
            if jump >= self.min_jump:
                self.ratio += self.gain * (jump / nominal_jump - self.ratio)
            self.ratio = min(max(self.ratio, self.limits[0]), self.limits[1])
            self._start = None
        self._stuck_at = valve if stuck else None


@dataclass(frozen=True)
class Seating:
    """Demands within ``margin`` of a stop mean "on the stop": the reference is aimed
    ``overtravel`` beyond it so the valve arrives at speed, and once it rests there the loop
    holds it with the known load plus ``torque`` (valve side) instead of fighting the stop
    with an integrator that could only wind up."""

    margin: float
    overtravel: float
    torque_nm: float
    stroke: float

    def target(self, demand: float) -> tuple[float, int]:
        if demand >= self.stroke - self.margin:
            return self.stroke + self.overtravel, 1
        if demand <= self.margin:
            return -self.overtravel, -1
        return demand, 0

    def seated(self, shaper: TrajectoryShaper, target: float, valve: float) -> bool:
        stop = self.stroke if target > self.stroke else 0.0
        arrived = shaper.arrived(target) or shaper.at(stop)
        return arrived and abs(valve - stop) <= self.margin

    def torque(self, model: NominalModel, stop: float, side: int, pressure_kpa: float) -> float:
        load = model.load_torque(stop, pressure_kpa)
        return max(load + side * self.torque_nm, 0.0) / model.gear_ratio


class StateFeedbackLaw(ControlLaw):
    """Discrete observer-based state feedback with integral action (modes ``observer``,
    ``observer_fc``, ``kalman_fc``, ``fc_gain``, ``observer_ff``).

    Per period: the disturbance observer ``x̂ = x̄ + L (y - C x̄)`` (``x̄`` predicted from the
    applied torque, the known loads and the compensator's friction belief), then

        u = u_ff(ref) - K (x̂ - x_ref) + K_I ζ + compensation

    where ``x_ref``/``u_ff`` hold the shaped reference against the known loads (spring,
    nominal flow torque, inertia and viscous feed-forward) and ``ζ += T (r - θ̂L)`` only
    outside the friction-sized deadband, outside planned moves and while the current is not
    limited.  The compensation strategy is a :class:`~.compensation.Compensator`.
    """

    def __init__(self, name: str, model: NominalModel, period_s: float, feedback: StateFeedback,
                 observer_gain: np.ndarray, shaper: TrajectoryShaper, integral: IntegralPolicy,
                 compensator: Compensator, seating: "Seating", speed_window: int = 4):
        self.name = name
        self.model = model
        self.period = period_s
        self.fb = feedback
        self.ao, self.bu, self.bd, self.co = model.observer_model(period_s)
        self.obs_gain = observer_gain
        self.shaper = shaper
        self.integral = integral
        self.compensator = compensator
        self.seating = seating
        self.jumps = JumpLearner()
        self.xo = np.zeros(6)      # observer state [θ1, ω1, θL, ωL, d1, dL]
        self.zeta = 0.0
        self._valve_history: deque = deque(maxlen=max(speed_window, 1) + 1)
        self._u_net = 0.0          # motor torque of the last period net of estimated motor friction
        self._d = 0.0              # known valve load of the last period (toward closed)
        self._applied = 0.0
        self._pending = 0.0
        self._fm = 0.0
        self._fl = 0.0
        self.deadband = 0.0
        self.reference: Reference | None = None

    def reset(self, meas, torque_nm, pressure_kpa):
        m = self.model
        self.xo = np.array([meas.motor_rad / m.gear_ratio, 0.0, meas.valve_rad, 0.0, 0.0, 0.0])
        self.shaper.reset(meas.valve_rad)
        self._valve_history.clear()
        self.compensator.reset(m, pressure_kpa)
        self._fm = self._fl = 0.0
        x_ref, u_ff = m.equilibrium(meas.valve_rad, pressure_kpa)
        # bumpless: the integral state makes the first output equal the present torque
        self.zeta = (torque_nm - u_ff + float(self.fb.k @ (self.xo[:4] - x_ref))) / self.fb.ki
        self._applied = self._u_net = torque_nm
        self._d = m.load_torque(meas.valve_rad, pressure_kpa) - m.spring_rate_nm_per_rad * meas.valve_rad

    def update(self, t, demand_rad, meas, pressure_kpa):
        m = self.model
        n = m.gear_ratio
        self._pressure = pressure_kpa
        # ---- disturbance observer (current estimator)
        x_bar = self.ao @ self.xo + self.bu[:, 0] * self._u_net + self.bd[:, 0] * self._d
        self.xo = x_bar + self.obs_gain @ (np.array([meas.motor_rad / n, meas.valve_rad]) - self.co @ x_bar)
        th1, w1, thl, wl = self.xo[:4]
        hist = self._valve_history
        hist.append(meas.valve_rad)
        valve_speed = (hist[-1] - hist[0]) / (self.period * (len(hist) - 1)) if len(hist) > 1 else 0.0
        # ---- seating: demands at a stop drive the valve onto it and hold it there
        target, seat = self.seating.target(demand_rad)
        if seat and self.seating.seated(self.shaper, target, thl):
            stop = 0.0 if seat < 0 else m.stroke_rad
            self.shaper.reset(stop)
            self.reference = Reference(stop, 0.0, 0.0, False)
            self._pending, self._fm, self._fl = 0.0, 0.0, 0.0
            self._d = m.load_torque(stop, pressure_kpa) - m.spring_rate_nm_per_rad * stop
            return self.seating.torque(m, stop, seat, pressure_kpa)
        # ---- reference, deadband
        was_moving = self.reference is not None and self.reference.moving
        ref = self.shaper.update(target)
        if ref.moving and not was_moving:
            # a move starts: uncock the drive first (valve torque back to the known load) so the
            # move's feed-forward starts from neutral, not from a drive wound up to breakaway
            net = n * self._applied - m.load_torque(thl, pressure_kpa)
            self.zeta -= net / n / self.fb.ki
        self.reference = ref
        stuck = abs(valve_speed) <= self.integral.stuck_speed
        nominal_jump = m.friction(pressure_kpa).stick_slip_jump_rad(m.coupling_stiffness_nm_per_rad)
        self.jumps.update(meas.valve_rad, stuck, not ref.moving, max(nominal_jump, self.integral.min_rad))
        self.deadband = self.integral.deadband(m, pressure_kpa, self.jumps.ratio)
        error = ref.position - thl
        outside = abs(target - thl) > self.deadband and not ref.moving
        # ---- friction compensation
        comp, self._fm, self._fl = self.compensator.update(Context(
            pressure_kpa, th1, w1, thl, wl, valve_speed, self._applied, ref.velocity, ref.acceleration, ref.moving,
            error, outside))
        # ---- state feedback around the dynamically consistent reference state
        x_ref, u_ff = m.reference_state(ref.position, ref.velocity, ref.acceleration, pressure_kpa,
                                        0.0, self._fl)
        u = u_ff + (comp - self._fl / n) - float(self.fb.k @ (self.xo[:4] - x_ref)) + self.fb.ki * self.zeta
        self._pending = 0.0
        if not outside and not ref.moving and stuck and self.integral.relax_time_s > 0.0:
            # settled: relax the drive to the middle of the static-friction band.  The valve
            # torque is the applied motor torque times N less the known load (robust to the
            # coupling stiffness, which may be far from nominal); shrinking it cannot break the
            # valve loose, and the next move starts from a neutral drive, not a cocked one
            net = n * self._applied - m.load_torque(thl, pressure_kpa)
            self._pending = -net / n * self.period / self.integral.relax_time_s / self.fb.ki
        if outside:
            self._pending = self.period * error
            if stuck:
                # stuck short of the target: ramp the torque quasi-statically to breakaway
                # instead of waiting for the slow integrator (the jump is the same either way)
                rate = m.friction(pressure_kpa).valve_static_nm / self.integral.stuck_ramp_time_s
                ramp = rate / n * self.period / self.fb.ki
                self._pending = math.copysign(max(abs(self._pending), ramp), error)
        known_load = m.load_torque(thl, pressure_kpa) - m.spring_rate_nm_per_rad * thl   # preload + flow
        self._d = known_load + self._fl
        return u

    def applied(self, torque_nm, saturated):
        self._applied = torque_nm
        self._u_net = torque_nm - self._fm
        if not saturated:
            self.zeta += self._pending

    def friction_trend(self) -> float | None:
        """Learned valve friction / nominal friction at the present pressure (None if the
        compensation does not learn): the wear and contamination trend of the valve."""
        scale = getattr(self.compensator, "scale", None)
        return scale(self._pressure)[1] if scale is not None and self._pressure is not None else None

    _pressure: float | None = None

    def estimate(self):
        n = self.model.gear_ratio
        th1, w1, thl, wl = self.xo[:4]
        return Estimate(th1 * n, w1 * n, thl, wl, self._fm, self._fl)

"""The actuator plant: a ROS-free object the offline simulator and the plant node both drive.

Typical use (one control period at a time)::

    plant = Plant(load_plant_params())
    plant.set_command(iq_ref_a=3.0, enabled=True)
    plant.advance(1e-3)                 # integrates 20 physics steps at 20 kHz
    sample = plant.resolver()           # ResolverSample or None (dropout)
    dp = plant.pressure_sample()        # measured Δp, kPa, when the transducer samples, else None
    plant.valve_angle, plant.telemetry()

All angles in rad (0 = closed), velocities rad/s, torques N*m, currents A, time s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import kernel as K
from .friction import flow_torque_peak_nm, friction_levels
from .motor import MotorConstants, current_pi_gains, dq_to_abc, voltage_limit
from fuel_valve_control.common.paramspec import ParamSet
from .params import check_consistency, load_plant_params
from .resolver import Resolver, ResolverSample, ValveResolverFaults


#: largest current reference the inverter accepts, A (hardware clamp; the controller's own
#: limits are tighter)
DRIVE_HARDWARE_LIMIT_A = 40.0

#: friction scatter: draws generated per block, and the generator stream (beside the seed)
SCATTER_BLOCK = 4096
SCATTER_STREAM = 1
#: random stream of the Δp transducer's noise (its own, like the scatter's)
PRESSURE_STREAM = 2


@dataclass(frozen=True)
class Truth:
    """Ground-truth state. Motor angle/velocity are motor-shaft values (not divided by N)."""

    motor_angle: float
    motor_velocity: float
    valve_angle: float
    valve_velocity: float
    electromagnetic_torque: float
    coupling_torque: float


def pack_parameters(ps: ParamSet, P: np.ndarray) -> None:
    """Fill the kernel parameter array from a validated parameter set."""
    dt = 1.0 / ps["physics_rate_hz"]
    m = MotorConstants.from_params(ps)
    bw = ps["drive.current_loop_bandwidth_hz"]
    kpd, kid = current_pi_gains(m.ld_h, m.resistance_ohm, bw)
    kpq, kiq = current_pi_gains(m.lq_h, m.resistance_ohm, bw)
    fl = friction_levels(ps)
    P[K.P_DT] = dt
    P[K.P_POLES] = m.pole_pairs
    P[K.P_R] = m.resistance_ohm
    P[K.P_LD] = m.ld_h
    P[K.P_LQ] = m.lq_h
    P[K.P_PSI] = m.flux_linkage_wb
    P[K.P_KPD], P[K.P_KID], P[K.P_KPQ], P[K.P_KIQ] = kpd, kid, kpq, kiq
    P[K.P_VLIM] = voltage_limit(ps["supply_voltage_v"])
    P[K.P_DECOUPLE] = 1.0 if ps["drive.decoupling"] else 0.0
    # exact step response of L di/dt = u - R i over dt, u held: i+ = a i + b u
    for a_idx, b_idx, ind in ((K.P_AD, K.P_BD, m.ld_h), (K.P_AQ, K.P_BQ, m.lq_h)):
        if m.resistance_ohm > 0.0:
            a = math.exp(-m.resistance_ohm * dt / ind)
            P[a_idx], P[b_idx] = a, (1.0 - a) / m.resistance_ohm
        else:
            P[a_idx], P[b_idx] = 1.0, dt / ind
    P[K.P_JM] = ps["motor.inertia_kgm2"]
    P[K.P_BM] = ps["motor.viscous_nms"]
    P[K.P_N] = ps["gearbox.ratio"]
    P[K.P_BACKLASH_HALF] = 0.5 * ps["gearbox.backlash_rad"]
    P[K.P_K] = ps["coupling.stiffness_nm_per_rad"]
    P[K.P_C] = ps["coupling.damping_nms"]
    P[K.P_JL] = ps["valve.inertia_kgm2"]
    P[K.P_BL] = ps["valve.viscous_nms"]
    P[K.P_STROKE] = ps["valve.stroke_rad"]
    lugre = ps["friction.model"] == "lugre"
    P[K.P_LUGRE] = 1.0 if lugre else 0.0
    P[K.P_TCM], P[K.P_TSM] = fl.motor_coulomb_nm, fl.motor_static_nm
    P[K.P_TCL], P[K.P_TSL] = fl.valve_coulomb_nm, fl.valve_static_nm
    if lugre:
        P[K.P_VSM] = ps["friction.lugre.motor_stribeck_velocity_rad_s"]
        P[K.P_VSL] = ps["friction.lugre.valve_stribeck_velocity_rad_s"]
    else:
        P[K.P_VSM] = ps["friction.motor.stribeck_velocity_rad_s"]
        P[K.P_VSL] = ps["friction.valve.stribeck_velocity_rad_s"]
    zeta = ps["friction.lugre.damping_ratio"]
    s0m = ps["friction.lugre.motor_stiffness_nm_per_rad"]
    s0l = ps["friction.lugre.valve_stiffness_nm_per_rad"]
    P[K.P_SIG0M], P[K.P_SIG1M] = s0m, 2.0 * zeta * math.sqrt(s0m * P[K.P_JM])
    P[K.P_SIG0L], P[K.P_SIG1L] = s0l, 2.0 * zeta * math.sqrt(s0l * P[K.P_JL])
    P[K.P_SPRING0] = ps["spring.preload_nm"]
    P[K.P_SPRINGK] = ps["spring.rate_nm_per_rad"]
    P[K.P_FLOWMAX] = flow_torque_peak_nm(ps)
    P[K.P_LOAD] = ps["load_torque_nm"]
    P[K.P_SCATTER] = ps["friction.valve.static_scatter"]
    P[K.P_RIPPLE] = ps["friction.valve.ripple"]
    P[K.P_RIPPLE_K] = 2.0 * math.pi / ps["friction.valve.ripple_period_rad"]
    P[K.P_RIPPLE_PHASE] = ps["friction.valve.ripple_phase_rad"]


class Plant:
    """Motor, drive, drivetrain, valve and resolvers integrated at ``physics_rate_hz``."""

    def __init__(self, params: ParamSet | None = None):
        self._ps = params if params is not None else load_plant_params()
        check_consistency(self._ps)
        self.dt = 1.0 / self._ps["physics_rate_hz"]
        self._delay_steps = int(round(self._ps["resolver.delay_s"] / self.dt))
        self.S, self.O, self.P, self._ring = K.new_arrays(self._delay_steps + 1)
        self._motor = MotorConstants.from_params(self._ps)
        rng = np.random.default_rng(self._ps["seed"])
        bits = self._ps["resolver.bits"]
        self._valve_resolver = Resolver(bits, self._ps["resolver.valve_noise_counts"], rng)
        self._motor_resolver = Resolver(bits, self._ps["resolver.motor_noise_counts"], rng)
        self._faults = ValveResolverFaults()
        # friction scatter: its own stream, so switching it on leaves the resolver noise alone
        self._scatter_rng = np.random.default_rng([self._ps["seed"], SCATTER_STREAM])
        self._scatter = self._scatter_rng.standard_normal(SCATTER_BLOCK)
        # the Δp transducer has a generator of its own: its noise leaves the resolvers' unchanged
        self._dp_rng = np.random.default_rng([self._ps["seed"], PRESSURE_STREAM])
        self._dp_every = max(int(round(1.0 / (self._ps["pressure_sensor.rate_hz"] * self.dt))), 1)
        self._dp_next_step = 0
        self._steps = 0
        self._iq_ref = 0.0
        self._enabled = 0.0
        self._apply(self._ps)
        theta0 = self._ps["initial_position_rad"]
        self.S[K.S_THL] = theta0
        self.S[K.S_THM] = theta0 * self._ps["gearbox.ratio"]
        self._ring[:, 0] = self.S[K.S_THM]
        self._ring[:, 1] = theta0
        self._first_scatter()

    def _first_scatter(self) -> None:
        """Static-level factor of the first breakaway (uses one draw)."""
        self.S[K.S_SCAT], self.S[K.S_SCAT_IDX], self.S[K.S_SCAT_ARMED] = 1.0, 0.0, 0.0
        self.S[K.S_SCAT] = K._draw_scatter(self.S, self._scatter, self.P[K.P_SCATTER])

    @property
    def static_friction_factor(self) -> float:
        """Factor on the valve static level for the next breakaway (1 without scatter)."""
        return float(self.S[K.S_SCAT]) if self.P[K.P_SCATTER] > 0.0 else 1.0

    def valve_friction_levels(self, valve_angle_rad: float | None = None) -> tuple[float, float]:
        """(Coulomb, static) valve friction in force now at ``valve_angle_rad`` (default: the
        present angle), ripple and scatter included, N*m."""
        th = self.valve_angle if valve_angle_rad is None else valve_angle_rad
        tc, ts = float(self.P[K.P_TCL]), float(self.P[K.P_TSL])
        if self.P[K.P_RIPPLE] > 0.0:
            r = 1.0 + self.P[K.P_RIPPLE] * math.sin(self.P[K.P_RIPPLE_K] * th + self.P[K.P_RIPPLE_PHASE])
            tc, ts = tc * r, ts * r
        if self.P[K.P_SCATTER] > 0.0:
            ts = max(ts * self.static_friction_factor, tc)
        return tc, ts

    # ---------------------------------------------------------------- parameters
    @property
    def params(self) -> ParamSet:
        return self._ps

    def check_params(self, changes) -> ParamSet:
        """The parameter set ``changes`` would give; raises (``ConfigError``/``ValueError``) if a
        value is invalid or not changeable at run time.  Changes nothing."""
        new = self._ps.replace(changes)
        check_consistency(new)
        fixed = [k for k in changes if not new.spec.params[k].runtime and new[k] != self._ps[k]]
        if fixed:
            raise ValueError(f"plant: {', '.join(fixed)} cannot change at run time; restart the plant")
        return new

    def set_params(self, changes) -> None:
        """Apply run-time parameter changes (validated first; on error nothing changes).

        Structural parameters (rates, inertias, resolver bits...) need a new Plant; changing
        them here raises ``ValueError``.
        """
        self._apply(self.check_params(changes))

    def _apply(self, ps: ParamSet) -> None:
        pack_parameters(ps, self.P)
        self._valve_resolver.noise_counts = ps["resolver.valve_noise_counts"]
        self._motor_resolver.noise_counts = ps["resolver.motor_noise_counts"]
        self._faults.set_mode(ps["fault_injection"])
        self._ps = ps

    def hold_at(self, valve_angle_rad: float) -> float:
        """Put the actuator at rest at ``valve_angle_rad``, held there by the drive.

        The coupling is twisted to carry the return spring, flow and load torque, the motor
        current is the matching holding current (also set as the command, drive enabled) and
        the current regulator's integrator is preloaded, so the plant starts in static
        equilibrium.  Returns the holding current, A.
        """
        ps = self._ps
        stroke = ps["valve.stroke_rad"]
        if not 0.0 <= valve_angle_rad <= stroke:
            raise ValueError(f"valve angle {valve_angle_rad!r} outside the stroke 0..{stroke}")
        load = (ps["spring.preload_nm"] + ps["spring.rate_nm_per_rad"] * valve_angle_rad
                + self.P[K.P_FLOWMAX] * math.sin(math.pi * valve_angle_rad / stroke) + ps["load_torque_nm"])
        n = ps["gearbox.ratio"]
        twist = load / ps["coupling.stiffness_nm_per_rad"]
        twist += math.copysign(0.5 * ps["gearbox.backlash_rad"], load)
        iq = load / (n * self._motor.torque_constant)
        S = self.S
        scat = S[K.S_SCAT], S[K.S_SCAT_IDX], S[K.S_SCAT_ARMED]
        S[:] = 0.0
        S[K.S_SCAT], S[K.S_SCAT_IDX], S[K.S_SCAT_ARMED] = scat
        S[K.S_THL] = valve_angle_rad
        S[K.S_THM] = (valve_angle_rad + twist) * n
        S[K.S_IQ] = iq
        S[K.S_XQ] = ps["motor.resistance_ohm"] * iq      # steady state: vq = R iq (decoupled)
        self._ring[:, 0] = S[K.S_THM]
        self._ring[:, 1] = valve_angle_rad
        self.set_command(iq, True)
        return iq

    # ---------------------------------------------------------------- inputs
    def set_command(self, iq_ref_a: float, enabled: bool) -> None:
        """Set the q-current reference (A) and drive enable held until the next call.

        Non-finite references raise ``ValueError`` (the caller decides how to fail safe); finite
        ones are clamped to the inverter's hardware limit.
        """
        if not math.isfinite(iq_ref_a):
            raise ValueError(f"current reference must be finite, got {iq_ref_a!r}")
        self._iq_ref = min(max(float(iq_ref_a), -DRIVE_HARDWARE_LIMIT_A), DRIVE_HARDWARE_LIMIT_A)
        self._enabled = 1.0 if enabled else 0.0

    # ---------------------------------------------------------------- time
    @property
    def time(self) -> float:
        """Plant time, s (an exact multiple of the physics step)."""
        return self._steps * self.dt

    def steps_for(self, duration_s: float) -> int:
        return max(int(round(duration_s / self.dt)), 0)

    def advance(self, duration_s: float) -> None:
        """Integrate ``duration_s`` (rounded to whole physics steps) with the held command."""
        self.step(self.steps_for(duration_s))

    def step(self, n: int) -> None:
        """Integrate ``n`` physics steps."""
        if n > 0:
            K.advance(self.S, self.O, self.P, self._ring, n, self._iq_ref, self._enabled, self._scatter)
            self._steps += n
            if self.S[K.S_SCAT_IDX] >= SCATTER_BLOCK:
                # fresh draws: the scatter never repeats (the kernel wraps only within one call)
                self._scatter = self._scatter_rng.standard_normal(SCATTER_BLOCK)
                self.S[K.S_SCAT_IDX] = 0.0

    # ---------------------------------------------------------------- outputs
    def resolver(self) -> ResolverSample | None:
        """Both resolvers read now (delayed by ``resolver.delay_s``); ``None`` on dropout."""
        idx = (int(self.S[K.S_RING]) - self._delay_steps) % self._ring.shape[0]
        true_motor, true_valve = self._ring[idx, 0], self._ring[idx, 1]
        burst = self._ps["fault_noise_burst_rad"] if self._faults.mode == "resolver_noise_burst" else 0.0
        valve = self._faults.apply(self._valve_resolver.quantise(true_valve, burst))
        if valve is None:
            return None
        motor = self._motor_resolver.quantise(true_motor)
        return ResolverSample(self.time - self._delay_steps * self.dt, motor, valve)

    def pressure_differential(self) -> float:
        """The Δp transducer read now, kPa: the true differential times ``1 + gain_error`` plus
        ``bias_kpa`` plus seeded Gaussian noise of ``pressure_sensor.noise_kpa`` rms (not clamped:
        a real transducer reads a little below zero or above full scale too)."""
        ps = self._ps
        noise = ps["pressure_sensor.noise_kpa"]
        dp = ps["pressure_differential_kpa"] * (1.0 + ps["pressure_sensor.gain_error"]) + ps["pressure_sensor.bias_kpa"]
        return float(dp + noise * self._dp_rng.standard_normal()) if noise > 0.0 else float(dp)

    def pressure_sample(self) -> float | None:
        """The measured Δp (kPa) if the transducer samples now (every 1/``pressure_sensor.rate_hz``
        of plant time, the first at the first call), else ``None``.  Call once per control
        period: the offline simulator and the plant node both do, so both see the same samples."""
        if self._steps < self._dp_next_step:
            return None
        nxt = self._dp_next_step + self._dp_every
        # behind schedule (a stalled real-time loop): resynchronise instead of a burst of samples
        self._dp_next_step = nxt if nxt > self._steps else self._steps + self._dp_every
        if self._ps["pressure_sensor.silent"]:
            return None
        return self.pressure_differential()

    @property
    def valve_angle(self) -> float:
        return float(self.S[K.S_THL])

    @property
    def valve_velocity(self) -> float:
        return float(self.S[K.S_WL])

    @property
    def currents(self) -> tuple[float, float]:
        """(i_d, i_q), A."""
        return float(self.S[K.S_ID]), float(self.S[K.S_IQ])

    def truth(self) -> Truth:
        S, O = self.S, self.O
        return Truth(float(S[K.S_THM]), float(S[K.S_WM]), float(S[K.S_THL]), float(S[K.S_WL]),
                     float(O[K.O_TE]), float(O[K.O_TCOUPLING]))

    def friction_torques(self) -> tuple[float, float]:
        """True friction torques acting on (motor, valve) shafts in the last step, N*m."""
        return float(self.O[K.O_TFM]), float(self.O[K.O_TFL])

    def telemetry(self) -> tuple[float, ...]:
        """Values for :data:`TELEMETRY_LABELS`."""
        S, O = self.S, self.O
        i_d, i_q = float(S[K.S_ID]), float(S[K.S_IQ])
        theta_e = self._motor.pole_pairs * float(S[K.S_THM])
        i_a, i_b, i_c = dq_to_abc(i_d, i_q, theta_e)
        return (i_d, i_q, float(O[K.O_VD]), float(O[K.O_VQ]), i_a, i_b, i_c,
                float(O[K.O_TFM]), float(O[K.O_TFL]), float(O[K.O_TSPRING]), float(O[K.O_TFLOW]),
                float(O[K.O_TE]), float(O[K.O_TCOUPLING]))

    @property
    def electrical_energy_in(self) -> float:
        """Electrical energy delivered by the inverter since start, J (for energy audits)."""
        return float(self.O[K.O_EIN])

    def stored_energy(self) -> float:
        """Magnetic + kinetic + coupling + return-spring energy, J (reference: valve closed)."""
        ps, S = self._ps, self.S
        n = ps["gearbox.ratio"]
        mag = 0.75 * (ps["motor.ld_h"] * S[K.S_ID] ** 2 + ps["motor.lq_h"] * S[K.S_IQ] ** 2)
        kin = 0.5 * ps["motor.inertia_kgm2"] * S[K.S_WM] ** 2 + 0.5 * ps["valve.inertia_kgm2"] * S[K.S_WL] ** 2
        twist = S[K.S_THM] / n - S[K.S_THL]
        half = 0.5 * ps["gearbox.backlash_rad"]
        twist = math.copysign(max(abs(twist) - half, 0.0), twist)
        coupling = 0.5 * ps["coupling.stiffness_nm_per_rad"] * twist ** 2
        th = S[K.S_THL]
        spring = ps["spring.preload_nm"] * th + 0.5 * ps["spring.rate_nm_per_rad"] * th ** 2
        return float(mag + kin + coupling + spring)

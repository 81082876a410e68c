"""The controller's nominal linear model of the actuator: a two-mass drivetrain (SPEC §2, §3).

States (valve-side coordinates, rad and rad/s)::

    x = [θ1, ω1, θL, ωL]     θ1 = θm / N  (gear output angle), θL = valve angle

Inputs: motor torque ``u`` (N*m at the motor shaft) and a valve-side load torque ``d``
(N*m, positive toward closed: return spring preload, flow torque, friction).  Outputs: the two
resolvers, ``y = [θ1, θL]`` (the motor resolver divided by N, and the valve resolver)::

    J1 ω1' = N u - B1 ω1 - K (θ1 - θL) - c (ω1 - ωL)          J1 = Jm N², B1 = Bm N²
    JL ωL' = K (θ1 - θL) + c (ω1 - ωL) - BL ωL - ks θL - d

``ks`` is the return-spring rate.  Everything a controller needs is derived from the nominal
physical parameters in ``config/controller.yaml`` (``model.*``), never typed in as gains.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from ..common.friction import FrictionCoefficients, FrictionLevels, pressure_fraction


@dataclass(frozen=True)
class NominalModel:
    """Nominal physical parameters the controller designs with (units in the names)."""

    motor_inertia_kgm2: float
    motor_viscous_nms: float
    torque_constant_nm_per_a: float
    gear_ratio: float
    coupling_stiffness_nm_per_rad: float
    coupling_damping_nms: float
    valve_inertia_kgm2: float
    valve_viscous_nms: float
    spring_preload_nm: float
    spring_rate_nm_per_rad: float
    flow_torque_max_nm: float
    stroke_rad: float
    pressure_max_kpa: float
    motor_coulomb_nm: float
    motor_static_nm: float
    valve_coulomb_nm: float
    valve_coulomb_per_dp_nm: float
    valve_static_nm: float
    valve_static_per_dp_nm: float
    motor_pole_pairs: float
    motor_resistance_ohm: float
    motor_lq_h: float

    @classmethod
    def from_params(cls, ps) -> "NominalModel":
        """Build from a controller parameter set (its ``model.*`` entries)."""
        return cls(**{name: ps[f"model.{name}"] for name in cls.__dataclass_fields__})

    # ---- derived quantities -----------------------------------------------------------
    @property
    def j1(self) -> float:
        """Motor inertia reflected to the gear output, kg*m²."""
        return self.motor_inertia_kgm2 * self.gear_ratio ** 2

    @property
    def b1(self) -> float:
        return self.motor_viscous_nms * self.gear_ratio ** 2

    @property
    def total_inertia(self) -> float:
        """Rigid-body inertia at the valve, kg*m²."""
        return self.j1 + self.valve_inertia_kgm2

    @property
    def resonance_rad_s(self) -> float:
        """Natural frequency of the coupling mode, rad/s."""
        k = self.coupling_stiffness_nm_per_rad
        return math.sqrt(k / self.j1 + k / self.valve_inertia_kgm2)

    def pressure_fraction(self, pressure_kpa: float) -> float:
        return pressure_fraction(pressure_kpa, self.pressure_max_kpa)

    @functools.cached_property          # frozen fields: built once (cached in the instance dict)
    def friction_coefficients(self) -> FrictionCoefficients:
        """The nominal friction schedule (the same law the plant integrates)."""
        return FrictionCoefficients(self.motor_coulomb_nm, self.motor_static_nm, self.valve_coulomb_nm,
                                    self.valve_coulomb_per_dp_nm, self.valve_static_nm,
                                    self.valve_static_per_dp_nm, self.pressure_max_kpa)

    def friction(self, pressure_kpa: float) -> FrictionLevels:
        """Nominal friction levels at a pressure differential.  The levels of the latest Δp are
        kept (the loop asks for them 2-4 times a period, at a Δp that changes rarely); the
        levels are immutable, so a kept one is the very value a fresh evaluation gives."""
        last = self.__dict__.get("_friction_last")
        if last is not None and last[0] == pressure_kpa:
            return last[1]
        levels = self.friction_coefficients.levels(pressure_kpa)
        # one tuple, set in one step: a reader on another thread sees the old pair or the new one
        self.__dict__["_friction_last"] = (pressure_kpa, levels)
        return levels

    def load_torque(self, valve_angle: float, pressure_kpa: float) -> float:
        """Known load on the valve toward closed: spring + nominal flow torque, N*m."""
        frac = min(max(valve_angle / self.stroke_rad, 0.0), 1.0)
        return (self.spring_preload_nm + self.spring_rate_nm_per_rad * valve_angle
                + self.flow_torque_max_nm * min(max(pressure_kpa / self.pressure_max_kpa, 0.0), 1.0)   # pressure_fraction, inlined
                * math.sin(math.pi * frac))

    # ---- state space --------------------------------------------------------------------
    def continuous(self):
        """(A, Bu, Bd, C): ``x' = A x + Bu u + Bd d``, ``y = C x``."""
        n, k, c = self.gear_ratio, self.coupling_stiffness_nm_per_rad, self.coupling_damping_nms
        j1, jl = self.j1, self.valve_inertia_kgm2
        a = np.array([
            [0.0, 1.0, 0.0, 0.0],
            [-k / j1, -(self.b1 + c) / j1, k / j1, c / j1],
            [0.0, 0.0, 0.0, 1.0],
            [k / jl, c / jl, -(k + self.spring_rate_nm_per_rad) / jl, -(c + self.valve_viscous_nms) / jl],
        ])
        bu = np.array([[0.0], [n / j1], [0.0], [0.0]])
        bd = np.array([[0.0], [0.0], [0.0], [-1.0 / jl]])
        cm = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
        return a, bu, bd, cm

    def discrete(self, period_s: float):
        """ZOH discretisation at the loop period: (Ad, Bu_d, Bd_d, C)."""
        a, bu, bd, cm = self.continuous()
        ad, b = zoh(a, np.hstack([bu, bd]), period_s)
        return ad, b[:, :1], b[:, 1:], cm

    def observer_model(self, period_s: float):
        """Disturbance-augmented ZOH model for the observers: states
        ``[θ1, ω1, θL, ωL, d1, dL]`` with constant unknown load torques ``d1`` (at the gear
        output) and ``dL`` (at the valve), both positive toward closed.  Friction reactions,
        stop reactions and flow-torque errors all land in them, so the velocity estimates stay
        unbiased while the valve is stuck (a 4-state observer of this very light valve would
        read ~2 rad/s of phantom velocity per N*m of unmodelled friction).

        Returns (A, Bu, Bd, C) with ``Bd`` the known valve-load input (as in :meth:`discrete`).
        Computed once per (model, period) and cached (fresh copies each call): a law rebuilt at
        run time (mode or parameter change) then costs no matrix exponential; uncached, the two
        ``expm`` calls took 12-36 ms on a loaded machine, 12-36 loop periods (issue 13, defect 6).
        """
        return tuple(m.copy() for m in _observer_model(self, float(period_s)))

    def _observer_model(self, period_s: float):
        """:meth:`observer_model`, uncached."""
        ad, bu, bd, cm = self.discrete(period_s)
        a, _, _, _ = self.continuous()
        dist = np.array([[0.0, 0.0], [-1.0 / self.j1, 0.0], [0.0, 0.0], [0.0, -1.0 / self.valve_inertia_kgm2]])
        _, bdist = zoh(a, dist, period_s)
        ao = np.eye(6)
        ao[:4, :4] = ad
        ao[:4, 4:] = bdist
        bo = np.vstack([bu, np.zeros((2, 1))])
        bdo = np.vstack([bd, np.zeros((2, 1))])
        co = np.hstack([cm, np.zeros((2, 2))])
        return ao, bo, bdo, co

    def reference_state(self, position: float, velocity: float, acceleration: float, pressure_kpa: float,
                        motor_friction: float = 0.0, valve_friction: float = 0.0) -> tuple[np.ndarray, float]:
        """State and motor torque that make the valve follow (position, velocity, acceleration).

        The inverse of the two-mass model (it is differentially flat in θL): the coupling must
        carry ``T_k = JL a + BL v + load(θL) + F_valve``, so the gear output leads the valve by
        ``T_k / K``; the motor adds ``J1 a + B1 v`` and its own friction.  Friction arguments are
        signed torques opposing motion (positive toward closed), N*m at their own shaft.
        """
        tk = (self.valve_inertia_kgm2 * acceleration + self.valve_viscous_nms * velocity
              + self.load_torque(position, pressure_kpa) + valve_friction)
        x = np.array([position + tk / self.coupling_stiffness_nm_per_rad, velocity, position, velocity])
        torque = (self.j1 * acceleration + self.b1 * velocity + tk) / self.gear_ratio + motor_friction
        return x, torque

    def equilibrium(self, valve_angle: float, pressure_kpa: float) -> tuple[np.ndarray, float]:
        """Static state holding the valve at ``valve_angle`` against the known load, and the
        motor torque (N*m) that holds it."""
        return self.reference_state(valve_angle, 0.0, 0.0, pressure_kpa)


@functools.lru_cache(maxsize=16)
def _observer_model(model: NominalModel, period_s: float):
    """Cache of :meth:`NominalModel.observer_model` (the model is frozen, so hashable)."""
    return model._observer_model(period_s)


def observer_model_builds() -> int:
    """Uncached discretisations for law builds so far (tests count the loop thread's work)."""
    return _observer_model.cache_info().misses


def zoh(a: np.ndarray, b: np.ndarray, period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation via the block matrix exponential."""
    n, m = b.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n] = a
    block[:n, n:] = b
    e = expm(block * period_s)
    return e[:n, :n], e[:n, n:]

"""The interface of a position control law.

Conventions: angles rad (valve side unless named motor), velocities rad/s, torques N*m at the
motor shaft unless a name says valve; ``θ1 = θm / N``.
"""
from __future__ import annotations

from abc import ABC, abstractmethod

from ..signals import Estimate, Measurement


class ControlLaw(ABC):
    """Interface of a control law, called once per loop period by the position controller:
    :meth:`update` for the torque request, then :meth:`applied` with what the limits let
    through.  The diagnostic queries default to "not available" (None) for laws without
    such a notion."""

    name: str = "base"

    @abstractmethod
    def reset(self, meas: Measurement, torque_nm: float, pressure_kpa: float) -> None:
        """(Re)start from a measurement so that the first output equals ``torque_nm`` (bumpless)."""

    def handover_torque(self, meas: Measurement) -> float | None:
        """Motor torque (N*m) a law replacing this one (a run-time parameter change) continues
        from, or ``None``: the torque this law commands (the default)."""
        return None

    @abstractmethod
    def update(self, t: float, demand_rad: float, meas: Measurement, pressure_kpa: float) -> float:
        """Torque request for this period, N*m at the motor."""

    def forget(self) -> None:
        """Forget what the law learned about the valve (back to the nominal model): a fault
        reset calls it, so a value learned from a disturbance cannot outlive the fault."""

    def friction_rescheduled(self, pressure_kpa: float) -> None:
        """The Δp the friction terms are scheduled for jumped to ``pressure_kpa`` (kPa): the
        driver found the Δp reading implausible against the friction met (or agreeing again).
        Friction levels seeded from the old schedule are re-seeded from the new one."""

    def stand_aside(self, on: bool) -> None:
        """``on``: a valve test (signature, partial stroke) owns the demand and measures the
        valve's friction from the drive torque, or the real-time loop was late (a late period
        stretches a timed pulse: :meth:`~..driver.ValveDriver.loop_timing`); a law that adds
        torque of its own beyond the position loop's (the fine stage's preloads and pulses)
        leaves the valve to the loop until called with ``False``.  Called by the driver every
        period; the default: nothing."""

    def loop_late(self) -> None:
        """The real-time loop was late within ``fine.late_loop_holdoff_s`` (a stalled period held the last command
        beyond its period: :meth:`~..driver.ValveDriver.loop_timing`): what the valve did meanwhile is not the law's
        own doing and must not be learned as the valve's (docs §111.5b).  Called by the driver every such period
        (never offline or in lockstep, whose timing is exact); the default: nothing."""

    def fallback_torques(self) -> tuple[float, ...]:
        """The motor torques (N*m) a drive should apply in the first, second, ... period in a row whose command is
        late (the last one in every later), or ``()``: the drive holds this period's command (a feedback law's command
        held one period more is one period of delay).  Asked after :meth:`update`.  A timed open-loop sequence (the
        fine stage's doublet: a one-period kick, then the retreat that stops the valve it broke loose) says its next
        step and then the torque that holds the valve: held over a late answer, a kick is a longer kick, and a retreat
        held over several breaks the valve loose backwards (docs §113; the driver passes them on as the drive's
        fallback schedule, ``contract.CURRENT_FALLBACK``).  The default: ``()``."""
        return ()

    def applied(self, torque_nm: float, saturated: bool) -> None:
        """The torque actually applied after limits (for observers and anti-windup)."""

    def after_period(self) -> bool:
        """Work the law left for after the period's command has gone out (the ROS node calls it once the command
        is published; nobody else need: the law then does it at its next period's start, with the same result).
        Returns whether there was any.  The default: none."""
        return False

    @abstractmethod
    def estimate(self) -> Estimate:
        """What the law believes about both shafts and the friction this period."""

    # ------------------------------------------------------------------ diagnostics
    def reference_position(self) -> float | None:
        """The shaped reference tracked this period, rad (None: the law tracks the demand)."""
        return None

    def deadband_rad(self) -> float | None:
        """Error band inside which the integrator is frozen, rad (None: no deadband)."""
        return None

    def learned_state(self) -> dict | None:
        """What the law has learned about this valve (for diagnostics; None: nothing)."""
        return None

    def friction_trend(self) -> float | None:
        """Learned valve friction / nominal friction at the present Δp (None: not learned):
        the wear and contamination trend of the valve."""
        return None

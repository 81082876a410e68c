"""Mode ``observer_fp``: the reference-feed-forward state feedback (``observer_ff``) for moves,
and the fine-positioning stage (:mod:`..fine_positioning`) that ends each move within a few
resolver counts once the valve has stopped near its target (issue 14).

The main law moves the valve; when its reference has arrived and the valve has been at rest
for a few periods outside the tolerance, the fine positioner takes over the torque (stiff
gear-output hold, preloaded twist, shaped pulse) until the demand changes; then the main law
restarts bumplessly from the torque last applied.
"""
from __future__ import annotations

from ..fine_positioning import HOLD, FinePositioner
from ..signals import Estimate, Measurement
from .base import ControlLaw
from .state_feedback import StateFeedbackLaw


class FinePositioningLaw(ControlLaw):
    def __init__(self, name: str, main: StateFeedbackLaw, fine: FinePositioner, min_jump_rad: float = 0.0):
        """``min_jump_rad``: the stage engages only where the nominal stick-slip jump at the Δp
        scheduled is at least this (rad, ``fine.min_jump_rad``; see :meth:`_worth_it`)."""
        self.name = name
        self.main = main
        self.fine = fine
        self.min_jump_rad = min_jump_rad
        self._fine_active = False
        self._main_updated = False
        self._holding = False
        self._applied = 0.0
        self._stand_down = False      # skip the stage for one period: hand the plateau back
        self._aside = False           # a valve test measures: the stage stays out (stand_aside)
        self._worth_at, self._worth = None, False     # _worth_it's last Δp (kPa) and verdict

    def reset(self, meas: Measurement, torque_nm: float, pressure_kpa: float) -> None:
        self.main.reset(meas, torque_nm, pressure_kpa)
        # the last breakaway seen stays: it is evidence about this valve, which a re-arm does not change (cleared,
        # a re-arm after the drive's watchdog trip left a 0.5 % step inside the main law's deadband with no
        # evidence for the stage to engage on: 5.4e-3 rad off for 3 s, stall seed 4 of the start-up profile);
        # forgetting what was learned (a fault's reset) clears it (forget)
        self.fine.reset(keep_breakaway=True)
        self._fine_active = False
        self._holding = False
        self._stand_down = False
        self._applied = torque_nm

    def update(self, t, demand_rad, meas, pressure_kpa):
        target, seat = self.main.seating.target(demand_rad)
        th1 = meas.motor_rad / self.main.model.gear_ratio
        torque = None
        if not seat:
            worth = self._worth_it(pressure_kpa)
            if not worth:
                self._stop_stage()
            if not self._stand_down:      # (stood down: the main law takes the plateau back now)
                self.fine.hold_static_nm = self.main.band_static_nm   # (fine.cold_band_gate)
                self.fine.main_deadband_rad = self._deadband_held()  # (fine.engage_inside_deadband)
                torque = self.fine.update(target, th1, meas.valve_rad, self._holding and worth and not self._aside,
                                          self._applied, pressure_kpa)
        self._stand_down = False
        if torque is not None:
            self._fine_active = True
            self._main_updated = False
            return torque
        if self._fine_active:
            # hand back: the main law restarts from the torque that holds the present twist (the
            # torque last applied may be a pulse's, up to the whole current: restarted from a
            # doublet's retreat, the main law drove the valve 2e-2 rad away)
            hold = self.fine.hold_torque(th1, meas.valve_rad)
            self._resume_main(meas, self._applied if hold is None else hold, pressure_kpa)
            self._fine_active = False
        torque = self.main.update(t, demand_rad, meas, pressure_kpa)
        self._main_updated = True
        ref = self.main.reference
        self._holding = (not seat and ref is not None and not ref.moving and abs(ref.position - target) < 1e-12)
        return torque

    def _deadband_held(self) -> float | None:
        """The main law's integrator deadband in force (rad, its last period's) where its hold moves no valve
        inside it; None where it may (a bounded probe inside the band: ``integral.probe_soft_floor`` on a
        coupling read softer than told, or ``integral.probe_shown_friction``), for
        :meth:`FinePositioner._main_stays`."""
        main = self.main
        if main.integral.probe_shown_friction:
            return None
        if main.stiffness is not None and main.stiffness.misfit != 1.0:
            return None
        return main.deadband

    def _resume_main(self, meas: Measurement, torque_nm: float, pressure_kpa: float) -> None:
        """Restart the main law bumplessly from ``torque_nm`` (observer, integrator) but keep what
        its hold has learned about this valve: the steady load beyond the known one (N*m, valve
        side, + toward closed) and the slip edges of the static band that taught it.  A full reset
        forgot them at every hand-back, and the restarted hold relaxed toward the known load alone
        (h18g: campaign seed 1071, friction x2.2, Δp missing, hunted 2.6e-3 rad on its final hold;
        seed 3007, 10 N*m load, slid 8e-3 rad off target).  The rest of the main law's learning
        (its compensator) is not kept: measured worse on the nominal box (h18g: 84 vs 70 plateaus
        > 8e-4 rad of 480)."""
        self.main.reset(meas, torque_nm, pressure_kpa, keep_held_load=True)

    def _worth_it(self, pressure_kpa: float) -> bool:
        """Whether the stage can end a plateau closer than the main law at this Δp: only where
        the valve's nominal stick-slip jump 2 (T_s - T_c(Δp)) / K is at least ``min_jump_rad``.
        The doublet's kick is a fixed current: at low Δp it overdrives the small static band
        so far that its smallest move (0.77e-3 rad at Δp 0 on the bare plant, up to 2.2e-3 at
        5 % of max) is larger than the whole jump (0.42e-3 at Δp 0), while the main law's hold
        ends within about half a jump -- with the stage at Δp 0, doublets of 3-5e-3 rad
        overshot the 2 % step 24-38 % (test_closed_loop.py, inertia/friction corners).  The
        stage keeps watching (stands aside as for a valve test) and engages when Δp rises."""
        if pressure_kpa != self._worth_at:     # (the schedule is evaluated once per Δp, not per period)
            m = self.main.model
            self._worth_at = pressure_kpa
            self._worth = m.friction(pressure_kpa).stick_slip_jump_rad(m.coupling_stiffness_nm_per_rad) \
                >= self.min_jump_rad
        return self._worth

    def handover_torque(self, meas: Measurement) -> float | None:
        """While the fine stage is in charge its torque may be a doublet's kick or retreat (up to
        the whole current): a successor continues from the torque that holds the present twist
        (task h17f: a run-time parameter change mid-staircase carried a retreat into the new
        law's transfer and the held valve went 2.1 % of stroke past the demand).  In the stage's hold
        (a plateau done) its command is the hold servo's steady torque, which may differ from the
        static hold of the twist by its integral: the successor continues from that command
        (``None``), not from the static hold (stop 27, docs §104: C3's hold stepped the replaced
        law's second period by 0.41 A)."""
        if not self._fine_active or self.fine.phase == HOLD:
            return None
        return self.fine.hold_torque(meas.motor_rad / self.main.model.gear_ratio, meas.valve_rad)

    @property
    def jumps(self):
        """The main law's breakaway-jump learner (it sizes the hold's integrator deadband):
        the driver's fault reset and its tests read it whichever law holds."""
        return self.main.jumps

    def forget(self) -> None:
        # the fine stage's learned twists live in the controller's FineLearner, which
        # PositionController.reset_learning resets together with this; the friction scale it read
        # (fine.learned_scale_*) goes with them
        self.fine.forget_scale()
        self.main.forget()

    def loop_late(self) -> None:
        self.main.loop_late()

    def stand_aside(self, on: bool) -> None:
        """A valve test measures friction from the drive torque while it moves the valve: the
        stage's preloads and pulses would falsify it (a signature's breakaway read 26.8 vs
        9.1 N*m true with the stage acting on the test's rests).  A stage in charge stops (the
        next period hands the plateau back to the main law from the torque holding the present
        twist), and while the test runs it is told the main law is not holding, so it never
        engages; it still watches the main law's breakaways from rest (the evidence it needs
        to engage on the operator's plateau after the test: cleared, it waited for a
        breakaway that a valve at rest never makes and left the partial-stroke test's 0.17 %
        return error standing)."""
        if on and not self._aside:
            self._stop_stage()
        self._aside = on

    def _stop_stage(self) -> None:
        if self._fine_active:
            self.fine.reset(measurements=False)
            self._stand_down = True

    def friction_rescheduled(self, pressure_kpa: float) -> None:
        """The main law re-seeds its friction terms bumplessly (the integrator takes the change
        of the known flow torque over: without it the drive stepped by the flow torque's share,
        0.7 A at 20 % open, test_friction_check).  A pulse the fine stage has planned from the
        old Δp's twists is not finished: the stage stands down, and the next period hands the
        plateau back to the main law (from the torque holding the present twist); it may engage
        again on the new schedule."""
        self.main.friction_rescheduled(pressure_kpa)
        self._stop_stage()

    def fallback_torques(self) -> tuple[float, ...]:
        return self.fine.fallback_nm if self._fine_active else ()

    def after_period(self) -> bool:
        """The fine stage's try start left for after the command (``fine.apex_choice_after_command``)."""
        return self.fine.run_pending()

    def applied(self, torque_nm, saturated):
        self._applied = torque_nm
        if self._main_updated:
            self.main.applied(torque_nm, saturated)

    def estimate(self) -> Estimate:
        return self.main.estimate()

    def reference_position(self):
        return self.main.reference_position()

    def deadband_rad(self):
        return self.main.deadband_rad()

    def friction_trend(self):
        return self.main.friction_trend()

    def learned_state(self) -> dict | None:
        return {**(self.main.learned_state() or {}), **self.fine.health()}

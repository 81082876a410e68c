"""Position controller: builds the control law of the selected mode from the parameters,
converts its torque to a q-current request and applies the actuator's current limits.

Gains are designed here, at construction, from the nominal model (``model.*``) and the
``design.*``/``observer.*``/``lqr.*``/``kalman.*`` parameters.  Mode changes at run time are
bumpless: the new law starts from the last measurement with its integral state set so its
first output equals the last applied torque.

A replaced law (mode change, run-time parameter) is also bumpless in the command itself: in
its first period the old law runs once more and the difference between the two outputs is
added to the new law's torque, decaying with :attr:`PositionController.TRANSFER_TIME_S`, so the
command continues from where it was and the new law takes over smoothly.

Run-time parameters: :meth:`PositionController.reconfigure` rebuilds the law whenever a
parameter it was built from changes.  Which parameters those are is recorded while the law is
built (:attr:`PositionController.law_params`), so the rule cannot go stale when a law starts
reading another parameter.
"""
from __future__ import annotations

import copy
import dataclasses
import math
import threading

from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, Iterator, Mapping

import numpy as np

from ..common.contract import RESOLVER_COUNT_RAD
from ..common.hunting import HUNT_SETTLE_S
from ..common.paramspec import ParamSet

from . import design
from .compensation import Compensator, FriedlandPark, ReferenceFeedforward, StictionGain
from .friction_observer import FrictionObserver
from .integral_policy import IntegralPolicy
from .fine_positioning import FineConfig, FineLearner, FinePositioner
from .laws import ControlLaw, FinePositioningLaw, PIDLaw, StateFeedbackLaw
from .limits import CurrentLimiter
from .model import NominalModel
from .params import CONTROLLER_SPEC, MODES
from .seating import Seating
from .signals import Estimate, Measurement
from .trajectory import TrajectoryShaper


#: modes of issue 14 (controller v2) that follow a demand with acceleration feed-forward
V2_MODES = ("observer_ff", "observer_fp")


@dataclass(frozen=True)
class Designs:
    """Everything the design step computed (kept for diagnostics and tests)."""

    pid: design.PIDGains
    placement: design.StateFeedback
    placement_poles_s: np.ndarray
    lqr: design.StateFeedback
    observer_gain: np.ndarray
    kalman_gain: np.ndarray


def design_all(ps: Mapping[str, Any], model: NominalModel) -> Designs:
    """Every design of :class:`Designs` from the parameters ``ps`` and the nominal ``model``.

    Deterministic in the parameters it reads and the (frozen) model, so it is computed once
    per such set and cached (:data:`_DESIGN_CACHE_SIZE` sets, fresh copies each call): the
    pole placements, Riccati solutions and matrix exponentials took ~0.1 s per driver built,
    which every test, fuzz case and run-time law rebuild paid again for the same parameters."""
    with _DESIGN_LOCK:
        for names in _DESIGN_READS:
            key = _design_key(ps, model, names)
            if key in _DESIGNS:
                _DESIGNS.move_to_end(key)
                return copy.deepcopy(_DESIGNS[key])
    log = _ReadLog(ps)
    designs = _canonical(_design_all(log, model))
    names = tuple(sorted(log.read))
    key = _design_key(ps, model, names)
    if key is not None:
        with _DESIGN_LOCK:
            if names not in _DESIGN_READS:
                _DESIGN_READS.append(names)
            _DESIGNS[key] = designs
            while len(_DESIGNS) > _DESIGN_CACHE_SIZE:
                _DESIGNS.popitem(last=False)
    # a copy on the first call too: the caller gets the same (C-ordered) arrays from the
    # computation as from the cache
    return copy.deepcopy(designs)


def _canonical(value):
    """``value`` with every array in it (through dataclass fields) a fresh C-contiguous copy.

    Why: scipy's ``place_poles`` hands back ``np.real`` of a complex matrix, a strided view
    (strides 16/96 bytes for a 2 x 6 gain), and the designs transpose some gains; ``copy.deepcopy``
    of such an array keeps its element order but not its strides.  The laws' small matrix-vector
    products (``@``) take numpy's own loop for a strided operand and BLAS ``gemv`` for a
    contiguous one, which sum in different orders: the same gain gave results 1 ULP apart,
    depending on whether a driver's designs were computed (first build of a parameter set in
    the process) or copied from the cache (any later build), and the stick-slip plants grow
    that ULP into a different run.  One layout for every build makes a run's result
    independent of what ran before it in the process."""
    if isinstance(value, np.ndarray):
        return np.array(value, order="C", copy=True)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.replace(value, **{f.name: _canonical(getattr(value, f.name))
                                             for f in dataclasses.fields(value) if f.init})
    if isinstance(value, tuple) and not hasattr(value, "_fields"):
        return tuple(_canonical(v) for v in value)
    return value


#: parameter sets whose designs :func:`design_all` keeps
_DESIGN_CACHE_SIZE = 32
_DESIGNS: OrderedDict[tuple, Designs] = OrderedDict()
#: the names each uncached design read (one tuple: the design does not branch on values; a
#: branch would add a second, and an entry only matches when everything *it* read is equal)
_DESIGN_READS: list[tuple[str, ...]] = []
_DESIGN_LOCK = threading.Lock()


def _design_key(ps: Mapping[str, Any], model: NominalModel, names: tuple[str, ...]) -> tuple | None:
    """The cache key of the design from ``names`` of ``ps`` and ``model``; None if a value is
    missing or not hashable (then nothing is cached)."""
    try:
        key = (model, names, tuple(ps[n] for n in names))
        hash(key)
    except (KeyError, TypeError):
        return None
    return key


def _design_all(ps: Mapping[str, Any], model: NominalModel) -> Designs:
    """:func:`design_all`, uncached."""
    period = 1.0 / ps["loop_rate_hz"]
    pid = design.design_pid(model, period, ps["pi.crossover_hz"], ps["pi.phase_margin_deg"],
                            ps["pi.integral_corner_ratio"], ps["pi.derivative_filter_ratio"])
    # the coupling mode's damping as configured, lowered where a stiff coupling would make the
    # held (friction-locked) valve's drive lose its stiffness (design.hold_stiff_state_feedback)
    placement, poles = design.hold_stiff_state_feedback(
        model, period, ps["design.bandwidth_hz"], ps["design.damping"], ps["design.integrator_ratio"],
        ps["design.resonance_damping"], ps["design.resonance_frequency_ratio"])
    q, r = design.bryson_weights(model, ps["lqr.position_error_rad"], ps["lqr.velocity_rad_s"],
                                 ps["lqr.twist_rad"], ps["lqr.integral_rad_s"], ps["lqr.current_a"])
    lqr = design.lqr_state_feedback(model, period, q, r)
    ao, _, _, co = model.observer_model(period)
    obs_poles = design.observer_poles(model, ps["design.bandwidth_hz"], ps["observer.bandwidth_ratio"], period)
    observer_gain = design.current_estimator_gain(ao, co, design.to_discrete(obs_poles, period))
    # Kalman: the unknown load torques random-walk (friction jumps at breakaway and reversal);
    # the measurements carry resolver noise and quantisation
    g = np.vstack([np.zeros((4, 2)), np.eye(2)])
    qn = np.diag([(ps["kalman.motor_torque_noise_nm"] * model.gear_ratio) ** 2, ps["kalman.torque_noise_nm"] ** 2])
    rn = np.diag([(ps["kalman.measurement_counts"] * RESOLVER_COUNT_RAD / model.gear_ratio) ** 2,
                  (ps["kalman.measurement_counts"] * RESOLVER_COUNT_RAD) ** 2])
    kalman = design.kalman_gain(ao, g, co, qn, rn)
    return Designs(pid, placement, poles, lqr, observer_gain, kalman)


class _ReadLog(Mapping[str, Any]):
    """A read-only view of a parameter set that records which names were read."""

    def __init__(self, values: Mapping[str, Any]):
        self._values = values
        self.read: set[str] = set()

    def __getitem__(self, name: str) -> Any:
        self.read.add(name)
        return self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)


class PositionController:
    """Mode selection, torque-to-current conversion and current limiting."""

    #: time constant of the bumpless-transfer offset after a law is replaced, s: slower than
    #: the closed loop (12 Hz) so the new law's integrator takes the torque over smoothly
    TRANSFER_TIME_S = 0.1

    def __init__(self, params: ParamSet | None = None):
        self.ps = params if params is not None else CONTROLLER_SPEC.defaults()
        self.model = NominalModel.from_params(self.ps)
        self.period = 1.0 / self.ps["loop_rate_hz"]
        self.designs = design_all(self.ps, self.model)
        #: what the fine-positioning stage learns about this valve (kept across mode switches;
        #: :meth:`reset_learning` forgets it, ``learner.save/load`` persist it)
        self.learner = FineLearner(self.ps["fine.pressure_bands"], self.ps["fine.learn_limit_rad"])
        lim = self.ps
        self._limiter = CurrentLimiter(lim["limits.peak_current_a"], lim["limits.peak_time_s"],
                                       lim["limits.continuous_current_a"], self.period)
        self.law: ControlLaw
        self.law_params: frozenset[str]
        self.law, self.law_params = self._make_law(self.ps["mode"], self.ps)
        self._started = False
        self.last_current = 0.0
        self.last_torque = 0.0
        self._outgoing: ControlLaw | None = None   # the replaced law, run once more for the transfer
        self._transfer = 0.0                        # bumpless-transfer torque offset, N*m
        self._transfer_next = None                  # ... from the second period (a handover torque)
        self._transfer_decay = float(np.exp(-self.period / self.TRANSFER_TIME_S))

    # ------------------------------------------------------------------ construction
    def _make_law(self, mode: str, ps: Mapping[str, Any]) -> tuple[ControlLaw, frozenset[str]]:
        """The law for ``mode`` built from ``ps``, and the parameter names the build read."""
        if mode not in MODES:
            raise ValueError(f"unknown mode {mode!r}; allowed: {', '.join(MODES)}")
        log = _ReadLog(ps)
        law = self._build(mode, log)
        return law, frozenset(log.read)

    def _build(self, mode: str, ps: Mapping[str, Any]) -> ControlLaw:
        m, period, d = self.model, self.period, self.designs
        if mode in ("pi", "pi_dither"):
            amp = ps["pi.dither_pct"] / 100.0 * m.stroke_rad if mode == "pi_dither" else 0.0
            return PIDLaw(d.pid, m, period, amp, ps["pi.dither_hz"])
        # a followed demand (sines, ramps): the v2 modes feed velocity and acceleration forward
        # from the demand, extrapolated by the delays of the medians in front of them;
        # the dissertation's modes and fc_gain keep the velocity-only reference they were
        # designed and measured with (kalman_fc's sweep falls to 2.4 Hz with the quicker filter)
        legacy = mode not in V2_MODES
        # the slope median delays the followed velocity one sample, the demand conditioning's
        # median one more
        follow_lead = 0.0 if legacy else period * (2.0 if ps["demand.conditioning"] else 1.0)
        if legacy:      # the dissertation's modes and fc_gain keep the limits they were measured with
            v_max, a_max = ps["trajectory.max_velocity_rad_s"], ps["trajectory.max_acceleration_rad_s2"]
        else:           # designed from the drive's voltage and current ratings at the supply it runs from
            lim = design.design_trajectory(m, ps["drive.supply_voltage_v"], ps["limits.peak_current_a"],
                                           ps["trajectory.current_fraction"], ps["trajectory.voltage_fraction"])
            v_max, a_max = lim.max_velocity_rad_s, lim.max_acceleration_rad_s2
        shaper = TrajectoryShaper(period, v_max, a_max, ps["trajectory.step_threshold_rad"],
                                  ps["trajectory.velocity_filter_s" if legacy else "trajectory.follow_filter_s"],
                                  ps["trajectory.min_move_time_s"], ps["trajectory.feedforward_lead_s"],
                                  follow_acceleration=not legacy, follow_lead=follow_lead,
                                  # the v2 modes start a planned move when the valve breaks away (observer_fp's
                                  # main law makes the moves the fine stage then finishes)
                                  breakaway_wait=ps["trajectory.breakaway_wait_s"] if mode in V2_MODES else 0.0,
                                  breakaway_rad=ps["trajectory.breakaway_counts"] * RESOLVER_COUNT_RAD,
                                  breakaway_max_move=ps["trajectory.breakaway_max_move_pct"] / 100.0 * m.stroke_rad)
        integral = IntegralPolicy(ps["integral.deadband_jump_fraction"], ps["integral.deadband_min_rad"],
                                  ps["ff.stuck_speed_rad_s"], ps["integral.stuck_ramp_time_s"],
                                  ps["integral.relax_time_s"],
                                  relieve_unarrested_swing=ps["integral.relieve_unarrested_swing"],
                                  relieve_met_surplus=ps["integral.relieve_met_surplus"],
                                  relieve_every_breakaway=ps["integral.relieve_every_breakaway"],
                                  relieve_fit=ps["integral.relieve_fit"],
                                  read_stiffness=ps["integral.read_stiffness"],
                                  stiffness_tolerance=ps["integral.stiffness_tolerance"],
                                  probe_soft_floor=ps["integral.probe_soft_floor"],
                                  probe_shown_friction=ps["integral.probe_shown_friction"],
                                  unchain_rewound=ps["integral.unchain_rewound"],
                                  cross_ratio_from_met=ps["integral.cross_ratio_from_met"],
                                  cross_met_margin=ps["integral.cross_met_margin"],
                                  cross_until_move=ps["integral.cross_until_move"],
                                  cross_keep_after=ps["integral.cross_keep_after"],
                                  cross_keep_unmet=ps["integral.cross_keep_unmet"],
                                  # the learned steady load never exceeds what the drive can hold
                                  load_limit_nm=ps["limits.continuous_current_a"] * m.torque_constant_nm_per_a
                                  * m.gear_ratio)
        feedback, gain = d.placement, d.observer_gain
        if mode == "kalman_fc":
            feedback, gain = d.lqr, d.kalman_gain
        elif ps["design.method"] == "lqr":
            feedback = d.lqr
        seating = Seating(ps["seat.margin_pct"] / 100.0 * m.stroke_rad, ps["seat.overtravel_rad"],
                          ps["seat.torque_nm"], m.stroke_rad,
                          *Seating.swing_design(m, ps["seat.swing_damping"], period))
        main = StateFeedbackLaw(mode, m, period, feedback, gain, shaper, integral, self._compensator(mode, ps),
                                seating, speed_window=ps["ff.speed_window_periods"],
                                delay_periods=int(round(ps["resolver_delay_s"] / period)), v2=not legacy,
                                hold_on_friction_met=mode in V2_MODES,
                                snap_peak_nm=ps["fine.peak_current_a"] * m.torque_constant_nm_per_a)
        if mode != "observer_fp":
            return main
        fine = FinePositioner(m, period, self._fine_config(ps), self.learner)
        # fine.apex_policy: its move model made with the law, on the told model (cheap: no table is built) -- the
        # one the node's configure builds the tables of (prepare); made at the first doublet instead it would take
        # a friction scale learned by then and need tables no configure built (offline and node alike, task h34t)
        fine.prepare(build=False)
        return FinePositioningLaw(mode, main, fine, min_jump_rad=ps["fine.min_jump_rad"])

    @staticmethod
    def _servo_mode_ref(ps: Mapping[str, Any]) -> float:
        """(``fine.servo_coupling_cap``) The default valve's stuck-valve drivetrain mode sqrt(K / J1), rad/s, the
        reference the stage's servo stiffness is capped by on a stiffer coupling; 0: the option off."""
        if not ps["fine.servo_coupling_cap"]:
            return 0.0
        ref = NominalModel.from_params(CONTROLLER_SPEC.defaults())
        return math.sqrt(ref.coupling_stiffness_nm_per_rad / ref.j1)

    def _fine_config(self, ps: Mapping[str, Any]) -> FineConfig:
        per = self.period
        # the pulse's times were set on the default model's coupling: lengthened on a softer one, its
        # acceleration across the wider twist band is the default valve's (fine.swing_scaled_pulse)
        swing = FinePositioner.swing_scale(self.model, NominalModel.from_params(CONTROLLER_SPEC.defaults())) \
            if ps["fine.swing_scaled_pulse"] else 1.0
        return FineConfig(ps["fine.tolerance_counts"] * RESOLVER_COUNT_RAD,
                          max(int(round(ps["fine.engage_time_s"] / per)), 1),
                          max(int(round(ps["fine.observe_time_s"] / per)), 1),
                          max(int(round(ps["fine.park_time_s"] / per)), 1), ps["fine.park_speed_rad_s"],
                          ps["fine.overdrive_fraction"], ps["fine.preload_margin"],
                          max(int(round(ps["fine.rise_time_s"] * swing / per)), 1),
                          max(int(round(ps["fine.fall_time_s"] * swing / per)), 1),
                          ps["fine.learn_gain"], ps["fine.max_pulses"],
                          ps["fine.servo_hz"], ps["fine.max_move_rad"], ps["fine.peak_current_a"],
                          ps["fine.max_crossings"], ps["fine.probe_step"], ps["fine.min_move_fraction"],
                          ps["fine.doublet_max_error_rad"], ps["fine.kick_current_a"], ps["fine.kick_rise_rad"],
                          ps["fine.doublet_probe_step"], ps["fine.doublet_margin"],
                          park_approach_rad=ps["fine.park_approach_rad"],
                          park_approach_speed=ps["fine.park_approach_speed_rad_s"],
                          doublet_sigmas=ps["fine.doublet_sigmas"],
                          approach_short=ps["fine.approach_short"],
                          min_move_prior=ps["fine.min_move_prior"], scatter_gain=ps["fine.scatter_gain"],
                          misfit_weight=ps["fine.misfit_weight"],
                          misfit_limit=ps["fine.misfit_limit"], misfit_decay=ps["fine.misfit_decay"],
                          breakaway_fit=ps["fine.breakaway_fit"], fit_margin=ps["fine.fit_margin"],
                          reversal_window_periods=max(int(round((HUNT_SETTLE_S - ps["fine.reversal_lead_s"]) / per)), 0),
                          no_cross_short=ps["fine.no_cross_short"], move_per_overdrive=ps["fine.move_per_overdrive"],
                          move_per_level=ps["fine.move_per_level"],
                          retreat_full_periods=ps["fine.retreat_full_periods"],
                          cold_start=ps["fine.cold_start"], cold_band_gate=ps["fine.cold_band_gate"],
                          cold_climb=ps["fine.cold_climb"], cold_friction_min=ps["fine.cold_friction_min"],
                          cold_still=ps["fine.cold_still"], rest_noise_rate=ps["fine.rest_noise_rate"],
                          timeable_delay=ps["fine.timeable_delay"],
                          servo_margin_rad=math.radians(ps["fine.servo_margin_deg"]),
                          resolver_delay_s=ps["resolver_delay_s"],
                          learn_kick_rise=ps["fine.learn_kick_rise"],
                          drop_rest_at_engage=ps["fine.drop_rest_at_engage"],
                          restair_sigmas=ps["fine.restair_sigmas"],
                          preload_sigmas=ps["fine.preload_sigmas"],
                          first_kick_fraction=ps["fine.first_kick_fraction"],
                          probe_reached=ps["fine.probe_reached"], preload_cap=ps["fine.preload_cap"],
                          doublet_jump_fraction=ps["fine.doublet_jump_fraction"],
                          learned_scale_min=ps["fine.learned_scale_min"], learned_scale_max=ps["fine.learned_scale_max"],
                          continuous_current_a=ps["limits.continuous_current_a"],
                          learned_load_max=ps["fine.learned_load_max"],
                          learned_one_sample=ps["fine.learned_one_sample"],
                          learned_agree=ps["fine.learned_agree"],
                          stair_far_sigmas=ps["fine.stair_far_sigmas"],
                          repark_from_state=ps["fine.repark_from_state"],
                          start_quantile=ps["fine.start_quantile"], start_step_sigmas=ps["fine.start_step_sigmas"],
                          main_sample_weight=ps["fine.main_sample_weight"],
                          unbiased_samples=ps["fine.unbiased_samples"],
                          unbiased_preload_pull=ps["fine.unbiased_preload_pull"],
                          retreat_stop_unmoved=ps["fine.retreat_stop_unmoved"],
                          retreat_unmoved_fraction=ps["fine.retreat_unmoved_fraction"],
                          engage_inside_deadband=ps["fine.engage_inside_deadband"],
                          stair_growth_after=ps["fine.stair_growth_after"],
                          stair_growth_slope=ps["fine.stair_growth_slope"],
                          apex_policy=ps["fine.apex_policy"], apex_land_rad=ps["fine.apex_land_rad"],
                          apex_move_sd_rad=ps["fine.apex_move_sd_rad"], apex_min_chance=ps["fine.apex_min_chance"],
                          apex_kick_max_a=ps["fine.apex_kick_max_a"], apex_kick_ratio=ps["fine.apex_kick_ratio"], apex_retreat_periods=ps["fine.apex_retreat_periods"],
                          apex_excess_nominal=ps["fine.apex_excess_nominal"], apex_floor_plan=ps["fine.apex_floor_plan"],
                          apex_choice_after_command=ps["fine.apex_choice_after_command"],
                          retreat_plan_after_command=ps["fine.retreat_plan_after_command"],
                          apex_kick_continuous=ps["fine.apex_kick_continuous"], apex_worse_given_move=ps["fine.apex_worse_given_move"],
                          apex_keep_rad=ps["fine.apex_keep_rad"], servo_unmoved_doublet=ps["fine.servo_unmoved_doublet"], servo_unmoved_doublet_jumps=ps["fine.servo_unmoved_doublet_jumps"], apex_level_law=ps["fine.apex_level_law"],
                          engage_gear_rest=ps["fine.engage_gear_rest"], handover_settle_speed=ps["fine.handover_settle_speed_rad_s"],
                          handback_settle=ps["fine.handback_settle"], apex_stop_rad=ps["fine.apex_stop_rad"],
                          apex_mix_points=ps["fine.apex_mix_points"],
                          handover_unwind=ps["fine.handover_unwind"],
                          handover_unwind_max_jumps=ps["fine.handover_unwind_max_jumps"],
                          handover_unwind_near=ps["fine.handover_unwind_near"],
                          hold_relax=ps["fine.hold_relax"],
                          hold_relax_periods=max(int(round(ps["fine.hold_relax_time_s"] / per)), 1),
                          apex_floor_repeat=ps["fine.apex_floor_repeat"],
                          retreat_cap=ps["fine.retreat_cap"], retreat_cap_half=ps["fine.retreat_cap_half"], observe_hold_integral=ps["fine.observe_hold_integral"],
                          observe_hold_moved=ps["fine.observe_hold_moved"],
                          supply_voltage_v=ps["drive.supply_voltage_v"],
                          hold_reversed=ps["fine.hold_reversed"],
                          retreat_return_guard=ps["fine.retreat_return_guard"],
                          retreat_trough_bound=ps["fine.retreat_trough_bound"],
                          retreat_trough_misfit=ps["fine.retreat_trough_misfit"],
                          park_settle=ps["fine.park_settle"],
                          apex_unraised_plan=ps["fine.apex_unraised_plan"],
                          apex_probe_hold=ps["fine.apex_probe_hold"],
                          trough_delay_s=ps["resolver_delay_s"] if ps["fine.retreat_trough_delay"] else 0.0,
                          retreat_return_hold=ps["fine.retreat_return_hold"],
                          retreat_return_rest=ps["fine.retreat_return_rest"],
                          unmoved_settled=ps["fine.unmoved_settled"],
                          kick_lost_fraction=ps["fine.kick_lost_fraction"],
                          servo_mode_ref_rad_s=self._servo_mode_ref(ps))

    def _compensator(self, mode: str, ps: Mapping[str, Any]) -> Compensator:
        m, period = self.model, self.period
        if mode == "fc_gain":
            return StictionGain(ps["fc_gain.gain"], ps["fc_gain.error_scale_rad"])
        if mode not in ("observer_fc", "kalman_fc", "observer_ff", "observer_fp"):
            return Compensator()
        # boundary layer of the friction sign: the velocity one valve resolver count per loop
        # period stands for (observer_fc / kalman_fc; observer_ff signs by its reference)
        v_count = RESOLVER_COUNT_RAD / period
        fps = (FrictionObserver(ps["fp.motor.alpha"], ps["fp.motor.beta"], ps["fp.motor.gain_cap"],
                                ps["fp.motor.freeze_velocity_rad_s"], period,
                                max_level=3.0 * m.motor_static_nm / m.motor_inertia_kgm2,
                                boundary_velocity=v_count * m.gear_ratio),
               FrictionObserver(ps["fp.valve.alpha"], ps["fp.valve.beta"], ps["fp.valve.gain_cap"],
                                ps["fp.valve.freeze_velocity_rad_s"], period,
                                max_level=3.0 * (m.valve_static_nm + m.valve_static_per_dp_nm) / m.valve_inertia_kgm2,
                                boundary_velocity=v_count))
        if mode in ("observer_ff", "observer_fp"):
            return ReferenceFeedforward(*fps, ps["ff.velocity_smoothing_rad_s"], ps["ff.stuck_speed_rad_s"],
                                        ps["ff.static_start"], ps["fp.compensation_fraction"], period,
                                        ps["ff.breakaway_ramp_s"], ps["ff.breakaway_start_fraction"],
                                        # the breakaway retreat: one period of the valve on the coupling
                                        retreat_periods=int(round(2.0 * math.pi * math.sqrt(
                                            m.valve_inertia_kgm2 / m.coupling_stiffness_nm_per_rad) / period)),
                                        read_breakaway=ps["ff.read_breakaway"],
                                        read_wrong_dp=ps["ff.read_breakaway_wrong_dp"],
                                        snap_fit_cap=ps["ff.snap_fit_cap"],
                                        slide_lowers_wrong_dp_cap=ps["ff.slide_lowers_wrong_dp_cap"],
                                        band_start=ps["ff.band_starts_wrong_dp_move"],
                                        unconfirmed_start=ps["ff.unconfirmed_dp_start"],
                                        wrong_dp_cut_retreat=ps["ff.wrong_dp_cut_retreat"],
                                        snap_cap_nm=ps["fine.peak_current_a"] * m.torque_constant_nm_per_a,
                                        breakaway_rad=ps["trajectory.breakaway_counts"] * RESOLVER_COUNT_RAD)
        return FriedlandPark(*fps, ps["fp.compensation_fraction"], ps["ff.stuck_speed_rad_s"])

    # ------------------------------------------------------------------ run time
    @property
    def mode(self) -> str:
        return self.law.name

    def switch_law(self, mode: str, meas: Measurement | None, pressure_kpa: float) -> None:
        """(Re)build the law for ``mode`` from the present parameters.  With a measurement the
        new law continues bumplessly from the last applied torque; without one it starts at
        the next :meth:`update`."""
        law, names = self._make_law(mode, self.ps)
        self._install(law, names, meas, pressure_kpa)

    def _install(self, law: ControlLaw, names: frozenset[str], meas: Measurement | None,
                 pressure_kpa: float) -> None:
        outgoing, self.law, self.law_params = self.law, law, names
        if meas is not None and self._started:
            hand = outgoing.handover_torque(meas)
            self.law.reset(meas, self.last_torque if hand is None else hand, pressure_kpa)
            self._outgoing = outgoing
        else:
            self._started = False
            self._outgoing, self._transfer, self._transfer_next = None, 0.0, None

    def build_law(self, ps: Mapping[str, Any]) -> tuple[ControlLaw, frozenset[str]]:
        """A new law for ``ps["mode"]`` built from ``ps`` and the parameter names it read;
        changes nothing (any thread: it reads only the model, the designs and the learner).
        Raises if the law cannot be built."""
        return self._make_law(ps["mode"], ps)

    def prepare(self, law: ControlLaw | None = None, build: bool = True) -> tuple[int, float]:
        """Build ahead what ``law`` (None: the law in force; else one from :meth:`build_law`) would otherwise build
        lazily inside :meth:`update` -- today the fine stage's move tables (``fine.apex_policy``,
        :meth:`FinePositioner.prepare`).  Returns (tables that were still to build, CPU seconds spent); ``build``
        False: count only, build nothing.  A real-time caller calls it outside its
        control callback; the offline simulator does not (a lazy build there only costs run time, and the tables
        are shared in the process: a campaign's runs build them once)."""
        law = self.law if law is None else law
        fine = getattr(law, "fine", None)
        return fine.prepare(build) if isinstance(fine, FinePositioner) else (0, 0.0)

    def defer_tables(self, law: ControlLaw | None = None, gate: bool = True) -> tuple | None:
        """(task h36b) For a real-time caller that builds ``law``'s move tables off its control thread (None: the law
        in force): ``(fine stage, its move model, the keys to build)`` when any is missing -- the stage then runs
        main's staircase until the caller has adopted them into the model and called ``fine.release_tables()``
        (:meth:`FinePositioner.defer_tables`) -- else None (nothing to build, or no ``fine.apex_policy``).  ``gate``
        False: the same answer, the stage left to build what it asks for lazily (lockstep)."""
        law = self.law if law is None else law
        fine = getattr(law, "fine", None)
        if not isinstance(fine, FinePositioner):
            return None
        keys = fine.defer_tables(gate)
        return (fine, fine.moves, keys) if keys else None

    def reconfigure(self, ps: ParamSet, meas: Measurement | None, pressure_kpa: float,
                    prepared: tuple[ControlLaw, frozenset[str]] | None) -> bool:
        """Adopt run-time parameters ``ps``: current limits at once; the law ``prepared`` by
        :meth:`build_law` for ``ps`` (``None``: the present law stays) is installed, bumplessly
        from the last applied torque when ``meas`` is given.  Building first and swapping here
        keeps a change atomic.  Returns whether the law was replaced."""
        new_law = prepared
        self.ps = ps
        self.configure_limits(ps["limits.peak_current_a"], ps["limits.peak_time_s"],
                              ps["limits.continuous_current_a"])
        if new_law is not None:
            self._install(*new_law, meas, pressure_kpa)
        return new_law is not None

    def reset_learning(self) -> None:
        """Forget what the law learned (fine-positioning twists, the jump ratio sizing the
        integrator deadband): back to the nominal model."""
        self.law.after_period()             # a try's start left for after the command judges on what was learned
        self.learner.reset()
        self.law.forget()

    def reset(self, meas: Measurement, pressure_kpa: float, torque_nm: float = 0.0,
              keep_limits: bool = False) -> None:
        """(Re)arm from a measurement, starting from ``torque_nm`` (0 after a trip).
        ``keep_limits``: keep the I²t budget spent and the overload timer (a re-arm after a
        stalled loop must not refill them, or stalls would hide a jam)."""
        if not keep_limits:
            self._limiter.reset()
        self.law.reset(meas, torque_nm, pressure_kpa)
        self._outgoing, self._transfer, self._transfer_next = None, 0.0, None
        self.last_torque = torque_nm
        self.last_current = torque_nm / self.model.torque_constant_nm_per_a
        self._started = True

    def after_period(self) -> bool:
        """The law's work left for after the period's command (:meth:`ControlLaw.after_period`)."""
        return self.law.after_period()

    def update(self, t: float, demand_rad: float, meas: Measurement, pressure_kpa: float) -> float:
        """One loop period: returns the limited q-current command, A."""
        if not self._started:
            self.reset(meas, pressure_kpa)
        kt = self.model.torque_constant_nm_per_a
        torque = self.law.update(t, demand_rad, meas, pressure_kpa)
        if self._outgoing is not None:       # first period of a new law: continue the old command
            # the command continues in this period; the offset that then decays is the one to
            # the outgoing law's handover torque (a fine stage's hold, not its doublet)
            old = self._outgoing.update(t, demand_rad, meas, pressure_kpa)
            hand = self._outgoing.handover_torque(meas)
            self._transfer = old - torque
            self._transfer_next = None if hand is None else hand - torque
            self._outgoing = None
        else:
            if self._transfer_next is not None:
                self._transfer, self._transfer_next = self._transfer_next, None
            self._transfer *= self._transfer_decay
        torque += self._transfer
        request = torque / kt
        current = self._limiter.apply(request)
        self.last_current = current
        self.last_torque = current * kt
        self.law.applied(self.last_torque, self._limiter.saturated)
        return current

    def estimate(self) -> Estimate:
        return self.law.estimate()

    def reference_position(self) -> float:
        """The shaped reference the law tracks this period (rad; NaN when it has none)."""
        ref = self.law.reference_position()
        return ref if ref is not None else float("nan")

    # ------------------------------------------------------------------ current limits
    def configure_limits(self, peak_a: float, peak_time_s: float, continuous_a: float) -> None:
        """New current limits (A, s), effective from the next period; the I²t budget spent so
        far is kept."""
        self._limiter.configure(peak_a, peak_time_s, continuous_a)

    @property
    def current_limits(self) -> tuple[float, float]:
        """(peak current A, I2t budget above the continuous rating A^2*s) in force."""
        return self._limiter.peak, self._limiter.budget

    def reset_limits(self) -> None:
        """Refill the I²t budget and clear the overload timer (after a fault reset)."""
        self._limiter.reset()

    @property
    def overload_time(self) -> float:
        """How long (s) the loop has asked for more than the continuous current with the I²t
        budget exhausted: a jam or overload."""
        return self._limiter.overload_time

    @property
    def i2t_budget_fraction(self) -> float:
        """Fraction of the I²t budget spent (0 cold .. 1 exhausted)."""
        return self._limiter.budget_used / max(self._limiter.budget, 1e-12)

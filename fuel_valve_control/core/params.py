"""Controller parameters (SPEC §3, §4): every design choice is a named value with a unit.

The ``model.*`` section is the controller's *nominal* knowledge of the actuator (what the
vendor's data sheet and drawings say); gains are designed from it at start-up.  It is the
controller's own parameter set -- a controller deployed on real hardware runs without the
simulated plant installed -- and its defaults are the data-sheet values the simulated plant
is also built from (``test_architecture.py`` checks that they agree), so a perturbed plant
(robustness studies) is controlled with gains designed for the nominal one.
"""
from __future__ import annotations

from pathlib import Path

from ..common.config_dir import default_config_dir
from ..common.contract import DRIVE_COMMAND_TIMEOUT_S, PRESSURE_MAX_KPA, STROKE_RAD
from ..common.paramspec import RECORDED_TOPICS, ConfigError, Param, ParamSet, ParamSpec

MODES = ("pi", "pi_dither", "observer", "observer_fc", "kalman_fc", "fc_gain", "observer_ff", "observer_fp")
DEFAULT_MODE = "observer_fp"  # observer_ff + the fine stage (h18s, docs/control_results.md §17); SPEC named observer_fc


def _nominal(name: str, value: float, unit: str, description: str, low: float = 0.0, high: float = 1e6,
             low_open: bool = False) -> Param:
    """A ``model.*`` entry: nominal (data-sheet) value of a physical quantity, start-up only."""
    return Param(f"model.{name}", value, unit, description, low, high, low_open)


#: data-sheet motor constants the torque constant is derived from (SPEC §2)
_POLE_PAIRS, _FLUX_LINKAGE_WB = 2, 0.0115

#: largest Friedland-Park exponent beta accepted (see :func:`_friedland_park_params`)
FP_BETA_MAX = 4.0


def _friedland_park_params(shaft: str, freeze_default: float, freeze_high: float) -> list[Param]:
    """The Friedland-Park observer parameters of one shaft (same meaning on both)."""
    return [
        Param(f"fp.{shaft}.alpha", 2.0, "", f"{shaft}-shaft observer gain alpha", 0.0, 1e6, low_open=True,
              runtime=True),
        # beta <= 4 (Friedland & Park use 1..3): alpha*|v|^beta cannot overflow a double for any
        # velocity estimate below 1e75 rad/s even at alpha's maximum; beta 200 overflowed at 35 rad/s
        Param(f"fp.{shaft}.beta", 1.5, "", f"{shaft}-shaft observer exponent beta", 0.0, FP_BETA_MAX,
              low_open=True, runtime=True),
        Param(f"fp.{shaft}.gain_cap", 200.0, "1/s", f"cap on alpha*beta*|v|^(beta-1), {shaft} shaft", 0.0, 1e4,
              low_open=True, runtime=True),
        Param(f"fp.{shaft}.freeze_velocity_rad_s", freeze_default, "rad/s",
              f"{shaft} speed below which the estimate is frozen", 0.0, freeze_high, runtime=True),
    ]


CONTROLLER_SPEC = ParamSpec("controller", [
    # --- interface contract (SPEC §4) -----------------------------------------------------
    Param("mode", DEFAULT_MODE, "", "control law", choices=MODES, runtime=True),
    Param("loop_rate_hz", 1000.0, "Hz", "position-loop rate (gains are designed for it)", 100.0, 10000.0),
    Param("demand_source", "percent", "", "which demand topic drives the valve", choices=("percent", "ma"),
          runtime=True),
    Param("demand_timeout_s", 0.5, "s", "demand older than this is stale", 0.005, 60.0, runtime=True),
    Param("demand_timeout_action", "trip", "", "on a stale demand: hold the last demand or trip",
          choices=("hold", "trip"), runtime=True),
    Param("resolver_delay_s", 0.0, "s", "measured delay of the resolver samples (conversion, transport), "
          "compensated in the state observers: a sample corrects the estimate of when it was taken, which is "
          "predicted forward over the inputs applied since (rounded to loop periods; 0 = none)", 0.0, 0.02),
    # --- measured pressure differential (input topic pressure_differential) ----------------
    Param("pressure.fallback_kpa", 0.0, "kPa", "Δp the friction-dependent terms are scheduled for while "
          "the measured Δp is missing, stale or implausible (0: the lowest friction, which cannot "
          "over-compensate and hunt)", 0.0, PRESSURE_MAX_KPA, runtime=True),
    Param("pressure.timeout_s", 0.1, "s", "a measured Δp older than this is stale (also: none received "
          "this long after the loop started): the contract rate is >= 50 Hz (the plant: 100 Hz), so 5 periods "
          "at the slowest; a source slower than the contract needs >= 3 of its periods here", 0.005, 60.0,
          runtime=True),
    Param("pressure.recover_s", 0.0, "s", "0: a Δp warning is latched until ~/reset (SPEC section 4).  > 0: a "
          "warning for a gap (no reading, or a stale one) clears itself once readings have arrived without a gap "
          "for this long; a warning for an implausible reading stays latched until ~/reset regardless", 0.0, 600.0,
          runtime=True),
    Param("pressure.range_margin_kpa", 310.0, "kPa", "readings beyond 0..pressure max by more than this "
          "are implausible (within it they are clamped)", 0.0, PRESSURE_MAX_KPA, runtime=True),
    Param("pressure.max_rate_kpa_s", 5.0e5, "kPa/s", "a change between two readings faster than this is "
          "implausible (full scale in ~12 ms: faster than any fuel-system hydraulic transient)",
          1.0, 1e8, low_open=True, runtime=True),
    Param("pressure.friction_check", True, "", "cross-check of the Δp schedule against the static valve "
          "friction met at confirmed breakaways (core/friction_check.py): where no friction scale within "
          "friction_scale_min..max (widened by friction_check_margin) explains the friction met at the Δp read, "
          "the reading is implausible (warning) and the friction terms are scheduled for the Δp the friction "
          "met says (on by default: quick campaigns seeds 1000 and 3000 no more hunting or faults than off, "
          "the 4 warnings in their 60 runs all on wrong or missing readings)", runtime=True),
    Param("pressure.friction_scale_min", 0.5, "", "lowest valve friction the check allows for, as a multiple of "
          "the nominal schedule (wear, temperature; the laws adapt within this range themselves)",
          0.01, 1.0, runtime=True),
    Param("pressure.friction_scale_max", 3.0, "", "highest valve friction the check allows for, as a multiple of "
          "the nominal schedule (a valve this sticky at the Δp read is not rescheduled)", 1.0, 100.0, runtime=True),
    Param("pressure.friction_check_margin", 1.3, "", "scatter of the friction met allowed beyond "
          "friction_scale_min..max before a Δp reading is judged implausible (the nominal schedule's static "
          "levels at Δp 0 and max, x0.5..3, leave a factor 1.83 between them); the reading is used again inside "
          "the range widened by its square root", 1.0, 10.0, low_open=True, runtime=True),
    # --- demand conditioning (core/demand_filter.py; every mode but the pi baselines) ------
    Param("demand.conditioning", True, "", "condition the demand (glitch median, noise-sized hold band) "
          "before the loop; the pi/pi_dither baselines always take it raw", runtime=True),
    Param("demand.band_sigmas", 3.0, "", "hold band half-width in estimated demand-noise rms (3: a noise "
          "sample leaves it 0.27 % of the time, and it must do so confirm_samples times in a row)", 0.0, 20.0,
          runtime=True),
    Param("demand.min_band_counts", 1.0, "counts", "smallest hold band half-width, valve resolver counts "
          "(a clean demand passes any change larger than what the valve resolver resolves)", 0.0, 100.0,
          runtime=True),
    Param("demand.confirm_samples", 2, "", "consecutive samples beyond the band (same side) that start "
          "following the demand (a step arrives 1 + this many samples late)", 1, 50, runtime=True),
    Param("demand.quiet_time_s", 0.02, "s", "demand within one band of an anchor this long: hold again",
          0.001, 1.0, runtime=True),
    Param("demand.noise_time_s", 0.2, "s", "time constant of the demand-noise estimate", 0.001, 60.0,
          runtime=True),
    Param("demand.hold_window_s", 0.5, "s", "longest window averaged while holding (slow drifts inside the "
          "band are followed with this memory)", 0.001, 60.0, runtime=True),
    # --- actuator ratings -----------------------------------------------------------------
    Param("limits.peak_current_a", 37.0, "A", "peak current (data sheet: 37 A for <= 20 ms)", 0.0, 40.0,
          low_open=True, runtime=True),
    Param("limits.peak_time_s", 0.020, "s", "time the peak current may flow from a full I2t budget",
          0.0, 1.0, runtime=True),
    Param("limits.continuous_current_a", 15.0, "A", "continuous current rating", 0.0, 40.0, low_open=True,
          runtime=True),
    # --- baseline PI(D) (the existing analog driver) --------------------------------------
    Param("pi.crossover_hz", 10.0, "Hz", "open-loop crossover on the nominal linear plant", 0.5, 100.0),
    Param("pi.phase_margin_deg", 45.0, "deg", "phase margin at the crossover", 10.0, 80.0),
    Param("pi.integral_corner_ratio", 0.25, "", "integral corner as a fraction of the crossover",
          0.01, 1.0),
    Param("pi.derivative_filter_ratio", 4.0, "", "derivative filter pole as a multiple of the crossover",
          1.5, 50.0),
    Param("pi.dither_hz", 25.0, "Hz", "dither frequency of pi_dither", 1.0, 200.0, runtime=True),
    Param("pi.dither_pct", 1.0, "%", "dither amplitude of pi_dither, percent of stroke", 0.0, 10.0,
          runtime=True),
    # --- state feedback with integral action (observer, *_fc, fc_gain) --------------------
    Param("design.method", "pole_placement", "", "gain design for observer/observer_fc/fc_gain",
          choices=("pole_placement", "lqr")),
    Param("design.bandwidth_hz", 12.0, "Hz", "natural frequency of the dominant closed-loop pair",
          0.5, 100.0),
    Param("design.damping", 0.9, "", "damping ratio of the dominant closed-loop pair", 0.2, 2.0),
    Param("design.integrator_ratio", 0.35, "", "integrator pole as a fraction of the dominant frequency",
          0.01, 2.0),
    Param("design.resonance_damping", 0.2, "", "damping given to the coupling mode (its frequency is kept)",
          0.01, 1.0),
    Param("design.resonance_frequency_ratio", 1.0, "", "closed-loop / open-loop coupling-mode frequency",
          0.3, 3.0),
    Param("observer.bandwidth_ratio", 12.0, "", "Luenberger observer poles as a multiple of the "
          "controller poles (each pole's natural frequency)", 1.0, 20.0),
    Param("lqr.position_error_rad", 1e-2, "rad", "Bryson scale: acceptable valve position error (1e-2: a 15 Hz / zeta 0.78 dominant pair, below the coupling mode even at K x 0.1 (28 Hz); 2e-3 gave 35 Hz, which a K x 0.1 coupling turned into a 37 A oscillation)", 1e-6, 1.0),
    Param("lqr.velocity_rad_s", 2.0, "rad/s", "Bryson scale: acceptable shaft velocities", 1e-3, 1000.0),
    Param("lqr.twist_rad", 5e-3, "rad", "Bryson scale: acceptable coupling twist theta1 - thetaL (weighted as "
          "a twist: cross terms of the two angles)", 1e-6, 1.0),
    Param("lqr.integral_rad_s", 5e-4, "rad*s", "Bryson scale: acceptable integrated error (5e-4: integrator "
          "pole at 3.2 Hz)", 1e-9, 10.0),
    Param("lqr.current_a", 1.0, "A", "Bryson scale: acceptable current (1 A: a current weight 100x the "
          "former 10 A one; 10 A gave a ~7300 N*m/rad motor-angle gain and a 104 Hz pair at zeta 0.3 that "
          "sat at the 37 A limit)", 0.01, 40.0),
    Param("kalman.torque_noise_nm", 0.2, "N*m", "process noise: change of the unmodelled valve torque per loop "
          "period, rms (0.2: the valve-velocity estimate's noise 0.046 rad/s rms, inside the Friedland-Park sign's "
          "boundary layer of one count per period; 2 N*m made a 500 Hz filter with 0.18 rad/s that flipped the "
          "friction term every period)", 1e-6, 100.0),
    Param("kalman.motor_torque_noise_nm", 0.01, "N*m", "process noise: unmodelled motor torque", 1e-9, 10.0),
    Param("kalman.measurement_counts", 0.5, "counts", "resolver noise incl. quantisation, rms counts",
          0.01, 100.0),
    # --- integral action near the target (anti-hunting) ------------------------------------
    Param("integral.deadband_jump_fraction", 0.55, "", "integrator frozen while |error| < this fraction of "
          "the stick-slip jump (2(Ts-Tc)/K at the current pressure, times the measured/nominal ratio "
          "learned from the valve's own breakaways)", 0.0, 5.0, runtime=True),
    Param("integral.stuck_ramp_time_s", 0.1, "s", "a valve stuck outside the deadband has its torque "
          "ramped through the static friction level in this time (quasi-static breakaway)", 0.001, 100.0,
          runtime=True),
    Param("integral.relax_time_s", 0.3, "s", "time constant with which a settled, stuck valve's drive "
          "relaxes to the middle of the static-friction band (0 = off)", 0.0, 100.0, runtime=True),
    Param("integral.relieve_unarrested_swing", False, "", "observer_ff, observer_fp: on a valve whose stick-slip "
          "swing cannot stop itself while the drive stays at the breakaway torque (valve inertia / motor inertia "
          "at the gear output > 0.2172; nominal 0.11, never on), give the stuck ramp's static-Coulomb surplus back "
          "once the valve breaks away (docs/control_results.md section 38: JL x3 startup worst plateau 4.6e-3 -> "
          "4.8e-4 rad, but its observer_fp campaign p95 1.4e-3 -> 2.4e-3: off)"),
    Param("integral.relieve_every_breakaway", False, "", "observer_ff, observer_fp: give the stuck ramp's "
          "static-Coulomb surplus back at a plateau's hold on every valve whose breakaway drive differs from the told "
          "static friction by more than integral.relieve_fit, whatever its valve / motor inertia ratio (at most the "
          "scheduled Ts - Tc; not while the reference ramps or a planned move waits for its breakaway).  A run's first "
          "small step on friction x0.6, 3.7e-3 rad at max dp: 115 % -> 0 % overshoot; full box median 2.15e-3 -> "
          "1.84e-3 rad (seed 3000), 2.00e-3 -> 1.85e-3 (seed 5000); but overload faults on plants beyond rating 9 -> 14, "
          "a 2 % step grid cell's late one-way correction over the hunting allowance and three other valves' startup "
          "worse: off (docs/control_results.md section 115)"),
    Param("integral.relieve_fit", 0.15, "", "with integral.relieve_every_breakaway: no give-back where the drive the "
          "valve broke away at lies within this fraction of the told static friction (a valve of the told friction, "
          "whose slide the fine stage is planned on; the nominal box's scatter is 2-8 %)", 0.0, 10.0),
    Param("integral.relieve_met_surplus", True, "", "with integral.relieve_unarrested_swing (or "
          "integral.relieve_every_breakaway): size the give-back on the drive the valve broke away at (the static friction met) times the schedule's 1 - Tc/Ts, not on "
          "the scheduled Ts - Tc (docs/control_results.md section 47)"),
    Param("integral.read_stiffness", True, "", "observer_ff, observer_fp: read the coupling stiffness at every "
          "hold (twist from the two resolvers against the drive at rest) and, beyond the reading's scatter, size the "
          "hold's stick-slip jump and the planned moves' coupling-snap feed-forward on it (docs/control_results.md "
          "sections 41, 45; default since stop 19: grids at K x 0.5 / 0.3 / 0.1 hunting 1 / 4 / 3 -> 0 / 3 / 0 cells, "
          "the 3 at the stick-slip jump floor)"),
    Param("integral.stiffness_tolerance", 0.5, "", "observer_ff, observer_fp with integral.read_stiffness: the "
          "coupling read at the holds is acted on only when K_model / K lies beyond 1 + this + the reading's scatter "
          "bound (docs/control_results.md sections 41, 45)", 0.0, 10.0),
    Param("integral.probe_soft_floor", True, "", "observer_ff, observer_fp with integral.read_stiffness: where "
          "only the read coupling's jump floor holds the valve (its error beyond the deadband the jumps learned "
          "would give), the hold's stuck ramp still pushes toward the target, but only up to the static friction "
          "whose jump on the coupling read would leave the error at the deadband's edge: a valve with less friction "
          "than the schedule lets go within a jump that fits (docs/control_results.md section 52; default since "
          "h26k: adaptation grid K x 0.1 friction x 0.5 max Δp final error 2.09e-2 (never moved) -> 3.7-5.6e-3 rad, "
          "full box p95 unchanged, median 2.56 -> 2.50e-3 rad)"),
    Param("integral.probe_shown_friction", False, "", "observer_ff, observer_fp: where the deadband in force "
          "(the jumps learned, the crossing breaker) holds the valve further from its target than the deadband of "
          "the quasi-static jump at the static friction the hold has met would, the hold's stuck ramp still pushes "
          "toward the target, once per target, up to the drive whose quasi-static jump that deadband would just "
          "hold (docs/control_results.md section 68; off: measured)"),
    Param("integral.unchain_rewound", False, "", "observer_fp (the limit-cycle breaker's chain): a breakaway "
          "piece is joined to the one before only if the coupling's twist did not rise its way by half the "
          "nominal jump or more between them (the gear output wound it again: the piece was driven, not the "
          "first jump's unspent twist) (docs/control_results.md section 71; off: measured)"),
    Param("integral.deadband_min_rad", 2.9e-4, "rad", "smallest deadband (3 valve resolver counts)",
          0.0, 0.05, runtime=True),
    Param("integral.cross_ratio_from_met", False, "", "observer_fp (the limit-cycle breaker's chain): the jump a "
          "chained breakaway across the target sets both ways is at most integral.cross_met_margin x the "
          "quasi-static jump of the drive the hold had on the valve when it let go (drive / scheduled static "
          "friction x K_model / K read), never below the last piece's own jump (docs/control_results.md "
          "section 74; off: measured)"),
    Param("integral.cross_met_margin", 1.5, "", "with integral.cross_ratio_from_met: the bound's margin over the "
          "quasi-static jump (breakaways on the box's couplings run 1.1-1.45x quasi-static, docs section 42/52)",
          1.0, 10.0),
    Param("integral.cross_until_move", False, "", "observer_fp (the limit-cycle breaker): a crossing's widening of "
          "both directions' jump ratio holds until the next planned move; the hold at a new target sizes its "
          "deadband by the jumps' own ratios (docs/control_results.md section 74; off: measured)"),
    Param("integral.cross_keep_after", 0, "", "observer_fp (the limit-cycle breaker): > 0: a crossing's widening "
          "is returned at the next planned move (as integral.cross_until_move, which this implies) only while "
          "the hold has counted fewer than this many crossings; after that it is kept across moves (a valve "
          "that crossed repeatedly jumps that far; docs/control_results.md section 78; 0 = off: measured)",
          0, 100),
    Param("integral.cross_keep_unmet", False, "", "observer_fp (the limit-cycle breaker): where a planned move returns a "
          "crossing's widening (integral.cross_until_move / cross_keep_after), a direction no jump has been measured "
          "in keeps it (its own ratio is only the other way's mean) (docs/control_results.md section 78; off: measured)"),
    # --- the drive's supply (planned moves are designed for it, core/design.design_trajectory)
    Param("drive.supply_voltage_v", 28.0, "V", "DC bus voltage of the drive (data sheet 18-32 V; set it to the "
          "configured or measured supply): observer_ff/observer_fp plan moves no faster than the back-EMF it "
          "leaves room for, so at 18 V a move slows down instead of saturating the voltage", 18.0, 32.0,
          runtime=True),
    Param("drive.current_loop_bandwidth_hz", 1500.0, "Hz", "bandwidth of the drive's dq current regulators (its "
          "tuning: a PI cancelling the R-L pole); core/pulse_moves.py models the fine stage's doublet with it (the "
          "kick's 4 A settle within it, the retreat's 30 A reversal slews at the supply's voltage; docs/control_results.md "
          "section 80); read by nothing else", 100.0, 20000.0),
    # --- reference trajectory for large demand changes -------------------------------------
    Param("trajectory.max_velocity_rad_s", 11.0, "rad/s", "observer, observer_fc, kalman_fc, fc_gain: slew rate "
          "of planned moves (observer_ff, observer_fp: designed, trajectory.voltage_fraction)", 0.01, 100.0),
    Param("trajectory.max_acceleration_rad_s2", 600.0, "rad/s^2", "observer, observer_fc, kalman_fc, fc_gain: "
          "peak acceleration of planned moves (observer_ff, observer_fp: designed, "
          "trajectory.current_fraction)", 1.0, 1e5),
    Param("trajectory.voltage_fraction", 0.95, "", "observer_ff, observer_fp: fraction of the SVPWM voltage "
          "circle (supply / sqrt 3) a planned move may use at its top speed against the worst known load and "
          "friction (the rest: the feedback's corrections and the current loop)", 0.1, 1.0, low_open=True),
    Param("trajectory.current_fraction", 0.65, "", "observer_ff, observer_fp: fraction of "
          "limits.peak_current_a a planned move's peak acceleration may take against the worst known load "
          "and friction (the rest: the feedback's corrections; issue 14 target <= 30 A)", 0.05, 1.0,
          low_open=True),
    Param("trajectory.step_threshold_rad", 0.005, "rad", "demand changes larger than this in one period "
          "are planned as moves", 0.0, 2.0),
    Param("trajectory.min_move_time_s", 0.02, "s", "planned moves last at least this long (lower "
          "acceleration for short moves)", 0.0, 2.0),
    Param("trajectory.feedforward_lead_s", 0.002, "s", "how far ahead the acceleration feed-forward "
          "of a move is taken (hold and current-loop delay)", 0.0, 0.05),
    Param("trajectory.breakaway_wait_s", 0.0, "s", "observer_ff, observer_fp: a planned move waits at its start, at most "
          "this long, while the friction feed-forward ramps the drive to breakaway; its clock starts when the "
          "valve lets go (0 = start on the clock, as the other modes; 0.25 makes the 2 % step adapt to friction "
          "x0.5-3 and inertia +-20 % at K nominal, but on couplings softer than the model the robustness "
          "campaign got worse: off by default, docs/control_results.md section 9)", 0.0, 1.0, runtime=True),
    Param("trajectory.breakaway_max_move_pct", 5.0, "%", "observer_ff, observer_fp: only planned moves up to this (percent "
          "of stroke) wait for breakaway; longer ones start on the clock and have the time to catch a late "
          "breakaway up", 0.0, 100.0, runtime=True),
    Param("trajectory.breakaway_counts", 3.0, "counts", "observer_ff, observer_fp: valve travel (valve resolver counts, "
          "the move's way) that counts as breakaway and starts a waiting move", 0.5, 100.0, runtime=True),
    Param("trajectory.velocity_filter_s", 0.005, "s", "observer, observer_fc, kalman_fc, fc_gain: time constant of the "
          "demand-velocity estimate used as feed-forward when the demand is followed directly", 0.0, 1.0),
    Param("trajectory.follow_filter_s", 0.001, "s", "observer_ff, observer_fp: time constant of the "
          "velocity and acceleration estimates of a directly followed demand (one loop period: the "
          "demand conditioning keeps noise out, and 5 ms cost 30 deg at 20 Hz)", 0.0, 1.0),
    # --- seating on the stops ---------------------------------------------------------------------
    Param("seat.margin_pct", 0.5, "%", "demands within this of a stop seat the valve on it", 0.0, 10.0),
    Param("seat.overtravel_rad", 0.1, "rad", "how far beyond the stop a seating move is aimed", 0.0, 0.5),
    Param("seat.torque_nm", 3.0, "N*m", "seating torque beyond the known load (valve side)", 0.0, 50.0),
    Param("seat.swing_damping", 0.7, "", "damping ratio the seated torque gives the motor's swing against the "
          "blocked valve (sqrt(K / (Jm N^2))) for twice its settling time after the valve arrives on a stop: the "
          "coupling arrives wound past the seated twist and, undamped, swung the valve back off the stop (80:1 "
          "gear: 2.5e-2 rad bounces every ~55 ms; docs/control_results.md section 39; 0 = constant seated torque)",
          0.0, 2.0),
    # --- Friedland-Park friction observers --------------------------------------------------
    *_friedland_park_params("motor", freeze_default=2.0, freeze_high=1000.0),
    *_friedland_park_params("valve", freeze_default=0.05, freeze_high=100.0),
    Param("fp.compensation_fraction", 1.0, "", "fraction of the estimated friction fed to the command",
          0.0, 1.5, runtime=True),
    # --- observer_ff: friction feed-forward along the reference ------------------------------
    Param("ff.velocity_smoothing_rad_s", 0.01, "rad/s", "reference speed over which the feed-forward "
          "direction ramps from 0 to +-1", 0.0, 10.0, runtime=True),
    Param("ff.stuck_speed_rad_s", 0.03, "rad/s", "measured valve speed at or below which the valve "
          "counts as stuck (static level fed forward)", 0.0, 10.0, runtime=True),
    Param("ff.static_start", False, "", "feed the static (breakaway) level forward while a move starts "
          "pulling a valve at rest", runtime=True),
    Param("ff.breakaway_ramp_s", 0.05, "s", "observer_ff: while a move waits for breakaway the valve "
          "feed-forward rises by one learned static-friction level in this time", 0.001, 1.0, runtime=True),
    Param("ff.breakaway_start_fraction", 0.4, "", "observer_ff: the breakaway ramp starts at this fraction of "
          "the learned static-friction level (below the lowest friction expected, x 0.5 of nominal)",
          0.0, 1.0, runtime=True),
    Param("ff.read_breakaway", True, "", "observer_ff, observer_fp: a clocked planned move reads the static "
          "friction the valve lets go at from the coupling's twist (both resolvers); where it let go below the "
          "scheduled Coulomb level but not below the least friction the valve can have (0.5 x the schedule, "
          "net and gross of a held load known from one edge only), the valve's friction feed-forward for the "
          "rest of that move is capped at the friction met (docs/control_results.md sections 31, 34, 43)",
          runtime=True),
    Param("ff.read_breakaway_wrong_dp", True, "", "observer_ff, observer_fp, with ff.read_breakaway: until the "
          "moves' readings both ways confirm the Δp told, a move's breakaway reading is taken as friction (and "
          "caps the move) down to the least friction the valve can show at any Δp the transducer may have "
          "misread whose flow torque helps the move (0.5 x that Δp's schedule less the flow torque the known load "
          "carries beyond it), not only down to 0.5 x the schedule at the Δp told; a held load the hold learned from one slip edge "
          "is then re-learned on that Δp's static level (docs/control_results.md sections 53, 56)",
          runtime=True),
    Param("ff.slide_lowers_wrong_dp_cap", True, "", "observer_ff, observer_fp, with ff.read_breakaway_wrong_dp: "
          "a move whose breakaway reading was cut because only a misread Δp explains it takes the friction it meets "
          "while sliding (coupling torque less J_L x acceleration, beyond the known load) as its cap, lowering it "
          "too, down to the least friction the valve can have at any Δp (0.5 x the schedule at Δp 0 over the one "
          "told) instead of 0.1 x (docs/control_results.md section 60)", runtime=True),
    Param("ff.band_starts_wrong_dp_move", True, "", "observer_ff, observer_fp, with ff.read_breakaway: while a "
          "clocked planned move's valve still sticks (its breakaway not read yet), its friction feed-forward is at most "
          "the static friction the hold's relax slips showed from both edges of the band, where that is below half the "
          "least the valve can have at the Δp told (0.25 x the schedule: only a misread Δp explains it), not below 0.5 x "
          "the schedule at Δp 0 (docs/control_results.md section 65)", runtime=True),
    Param("ff.unconfirmed_dp_start", False, "", "observer_ff, observer_fp, with ff.read_breakaway_wrong_dp: "
          "while the Δp told is unconfirmed (the moves' readings both ways have not confirmed it) and a misread Δp "
          "would help a clocked move, its friction feed-forward starts, while the valve still sticks, at the least "
          "friction any Δp explains (0.5 x the schedule at Δp 0) and rises to the schedule over a quarter of the "
          "valve's period on the coupling (docs/control_results.md section 65)", runtime=True),
    Param("ff.wrong_dp_cut_retreat", True, "", "observer_ff, observer_fp, with ff.read_breakaway_wrong_dp: a "
          "clocked move whose breakaway reading is cut because only a misread Δp explains it takes back the coupling "
          "torque it carries at the cut beyond the cut's Coulomb level (what the told Δp's level wound in while the "
          "valve stuck) over one period of the valve on the coupling, as a waiting move's breakaway retreat does "
          "(docs/control_results.md section 83)", runtime=True),
    Param("ff.snap_fit_cap", False, "", "observer_ff, observer_fp, on a coupling read softer than the model: a "
          "planned move's coupling-snap feed-forward is taken from its plan and scaled by one factor for the whole "
          "move, decided at its start, so its planned peak plus the move's static friction feed-forward fits the "
          "current cap (fine.peak_current_a), instead of being clipped period by period (docs/control_results.md "
          "section 57)", runtime=True),
    Param("ff.speed_window_periods", 4, "", "periods over which the valve speed is measured from the "
          "valve resolver", 1, 100),
    # --- observer_fp: fine positioning of a stuck valve (issue 14) ---------------------------
    Param("fine.tolerance_counts", 3.0, "counts", "a plateau is done when the valve is within this many "
          "valve resolver counts of the demand", 0.5, 100.0, runtime=True),
    Param("fine.engage_time_s", 0.01, "s", "valve at rest this long (reference arrived) before fine "
          "positioning starts", 0.002, 1.0, runtime=True),
    Param("fine.park_time_s", 0.005, "s", "least time to move the twist to its preload", 0.001, 0.1, runtime=True),
    Param("fine.park_speed_rad_s", 0.5, "rad/s", "largest twist rate while preloading (quasi-static: the "
          "gear-output hold must not overshoot into breakaway)", 0.01, 10.0, runtime=True),
    Param("fine.park_approach_rad", 5e-4, "rad", "the last this much of the preload twist is approached at "
          "fine.park_approach_speed_rad_s (the servo overshoots the end of a fast approach: 2.7e-4 rad median "
          "at 0.5 rad/s)", 0.0, 0.01, runtime=True),
    Param("fine.park_approach_speed_rad_s", 0.1, "rad/s", "largest twist rate over the last "
          "fine.park_approach_rad of the preload", 0.01, 10.0, runtime=True),
    Param("fine.observe_time_s", 0.015, "s", "wait after a pulse for the valve to stop (>= half a period of "
          "the valve on the softest coupling, pi / sqrt(0.3 K / JL) = 11 ms)", 0.002, 0.5, runtime=True),
    Param("fine.overdrive_fraction", 0.15, "", "pulse peak beyond the learned breakaway twist, fraction of "
          "the static band (breakaway - swing centre)", 0.0, 2.0, runtime=True),
    Param("fine.preload_margin", 0.3, "", "preload twist below the learned breakaway, fraction of the static "
          "band (covers the per-breakaway scatter)", 0.0, 1.0, runtime=True),
    Param("fine.rise_time_s", 0.002, "s", "pulse: preload to peak (sin^2 blend)", 0.001, 0.05, runtime=True),
    Param("fine.fall_time_s", 0.003, "s", "pulse: peak to the final twist, well inside the valve's 6 ms "
          "half swing so the swing is the one planned", 0.001, 0.05, runtime=True),
    Param("fine.swing_scaled_pulse", True, "", "fine.rise_time_s and fine.fall_time_s are for the default model's "
          "coupling; on a softer told coupling (stiffness K) they grow by sqrt(K_default / K), so the gear output's "
          "acceleration across the wider twist band stays within what fine.peak_current_a allowed the default valve "
          "(soft coupling K 200: x1.55; with the seconds as given its capped pulses fell short, the learned breakaway "
          "climbed and a preload broke the valve loose a whole jump: 2 % step 27.6 -> 0.0 %, task h24s); never "
          "shorter; false: the seconds as given", runtime=False),
    Param("fine.learn_gain", 0.7, "", "fraction of each measured correction taken into the learned twists",
          0.0, 1.0, runtime=True),
    Param("fine.max_pulses", 25, "", "pulses per plateau before the stage holds where it is", 1, 1000,
          runtime=True),
    Param("fine.servo_hz", 60.0, "Hz", "bandwidth of the stiff gear-output hold on the motor resolver",
          1.0, 200.0),
    Param("fine.servo_margin_deg", 0.0, "deg", "the gear-output servo's least phase margin counting the measured "
          "resolver_delay_s beside the loop period: where fine.servo_hz's gives less, its bandwidth is lowered until "
          "the margin is this (0: the delay not counted; the 60 Hz servo has 33 deg at 1 kHz with no delay, 11 deg at "
          "0.6 ms and none at 0.9 ms, where it rattled at +-30 A: task s34, docs section 118)", 0.0, 80.0),
    Param("fine.max_move_rad", 0.02, "rad", "errors larger than this are left to the main law", 1e-4, 1.0,
          runtime=True),
    Param("fine.peak_current_a", 30.0, "A", "the fine stage's torque is capped at this current (its pulses "
          "are what draws the peak)", 1.0, 40.0, runtime=True),
    Param("fine.max_crossings", 3, "", "pulses that took the valve across the target, per plateau, "
          "before the stage holds where it is", 1, 1000, runtime=True),
    Param("fine.probe_step", 0.1, "", "a pulse that did not move the valve raises the learned breakaway this "
          "fraction of the static band beyond the twist it reached", 0.0, 1.0, runtime=True),
    Param("fine.probe_reached", False, "", "a pulse that did not move the valve raises the learned breakaway only to "
          "fine.probe_step beyond the twist it reached: one that fell short of the learned level leaves it, and the "
          "step goes to the planned peak of the next servo-blended pulses instead (a per direction / Δp band offset, "
          "x0.7 at each of their moves) (off: beyond the larger of the two, the probe ratchet; task h25p)", runtime=True),
    Param("fine.preload_cap", False, "", "a servo-blended pulse's preload goes no further than the furthest twist a pulse "
          "that did not move the valve reached at this stop (the ratchet may have raised the learned level, and the "
          "preload planned from it, past what they proved; task h25p)", runtime=True),
    Param("fine.retreat_stop_unmoved", False, "", "doublet: once the valve is seen not to have moved after the "
          "retreat, the observe servo holds the gear output at the preload less fine.park_approach_rad instead of the "
          "move's final twist (a shallower trough for the next stair's park; task h28r)", runtime=True),
    Param("fine.retreat_unmoved_fraction", 0.5, "", "doublet: the current of the retreat's last period (the "
          "half one) as a fraction of fine.peak_current_a backwards when the valve has not moved a half count by "
          "then (0.5: as when it has; less: a shallower trough for the next stair's park; task h28r)", -1.0, 1.0,
          runtime=True),
    Param("fine.repark_from_state", False, "", "doublet: the park after a stair that did not move the valve is "
          "planned from the twist and twist rate the retreat left (the servo's rebound from the trough): a cubic to "
          "fine.park_approach_rad short of the preload, passed at fine.park_approach_speed_rad_s, then one to the "
          "preload at rest, with the servo's integral back at the whole static correction that held the last preload "
          "-- instead of from rest at the trough's twist at fine.park_speed_rad_s (stair 24 -> 22 periods, nominal "
          "box plateaus > 8e-4 rad 67 -> 62 / 50 -> 41, but p95 1.32 -> 1.49e-3 rad on seed 1000: the valves that "
          "let go move further; task h29r, docs/control_results.md section 61)", runtime=True),
    Param("fine.stair_far_sigmas", 0.0, "", "doublet: while a staircase's apex lies more than this many learned rms "
          "scatters of the breakaway twist below the learned breakaway, a stair that did not move the valve is followed "
          "by one up to fine.kick_rise_rad higher (the largest that keeps the next preload below the apex reached), "
          "never past that bound; nearer, fine.doublet_probe_step x the band (0 = every stair that; task h27s)",
          0.0, 10.0, runtime=True),
    Param("fine.start_quantile", 0.0, "", "doublet: a new staircase starts where this fraction of first stairs let "
          "the valve go (in the kick or the preload), learned per direction and dp band from their outcomes by a "
          "quantile tracker in learned scatters below the learned breakaway, starting from fine.doublet_sigmas "
          "(0 = always fine.doublet_sigmas; task h29q)", 0.0, 0.5, runtime=True),
    Param("fine.start_step_sigmas", 0.5, "", "fine.start_quantile: the tracker's step, learned scatters (a let-go "
          "moves the start (1 - quantile) x this deeper, a miss quantile x this shallower)", 0.0, 5.0, runtime=True),
    Param("fine.main_sample_weight", 1.0, "", "the main law's breakaways from rest count this fraction of a doublet's "
          "breakaway in the learned breakaway twist and scatter (fine.scatter_gain x this; nominal box: unbiased but "
          "p10/p90 +-7e-4 rad off the plant's true level, a moved doublet's 1.6e-4 wide; task h29q)", 0.0, 1.0,
          runtime=True),
    Param("fine.unbiased_samples", False, "", "every input of the learned breakaway a sample of the level drawn at its "
          "stop: a doublet that moved the valve at its apex plus the let-go offset (half the kick's rise), not half a "
          "stair below; a servo-blended pulse a censored sample (the level below the twist it let go at, above the "
          "stop's furthest unmoved apex), taken as the learned normal's conditional mean and second moment, instead "
          "of the pull to the apex and the raise by fine.probe_step at each unmoved pulse (the next pulse's peak "
          "still climbs; task h30u)", runtime=True),
    Param("fine.min_move_fraction", 0.5, "", "no pulse for an error below this fraction of the learned smallest "
          "move a pulse makes (0.5: a move m improves an error e only if m < 2|e|; 0 = pulse regardless)",
          0.0, 2.0, runtime=True),
    Param("fine.doublet_max_error_rad", 1.0e-3, "rad", "errors up to this are closed by a torque doublet (one "
          "period of kick on the preload, then the whole current backwards) instead of the servo-blended pulse "
          "(0 = never)", 0.0, 0.02, runtime=True),
    Param("fine.kick_current_a", 4.0, "A", "doublet: current added to the hold for one period", 0.0, 30.0,
          runtime=True),
    Param("fine.kick_rise_rad", 1.5e-4, "rad", "doublet: preload this far below the learned breakaway twist "
          "(about the twist the kick adds)", 0.0, 0.01, runtime=True),
    Param("fine.doublet_probe_step", 0.03, "", "doublet: as fine.probe_step (small: each 1e-4 rad of "
          "overdrive adds about 4e-4 rad to the move)", 0.0, 1.0, runtime=True),
    Param("fine.doublet_margin", 0.3, "", "doublet: after each stop the first apex lies this fraction of the "
          "static band below the learned breakaway (its level is drawn anew at every stop); the staircase climbs "
          "from there, until the breakaway scatter is learned", 0.0, 2.0, runtime=True),
    Param("fine.min_move_prior", 0.19, "", "the smallest move a doublet makes before one is learned, fraction of "
          "the nominal stick-slip jump 2 (T_s - T_c(dp)) / K (benchmarks/fine_doublet.py: 0.86e-3 of 4.6e-3 rad at "
          "max dp)", 0.0, 1.0, runtime=True),
    Param("fine.approach_short", 0.2, "", "a servo-blended pulse (errors beyond fine.doublet_max_error_rad) "
          "aims this fraction of the static band (T_s - T_c(dp)) / K short of the target (0.2: 4.6e-4 rad at max dp), "
          "so that the doublet finishes the move from the same side", 0.0, 2.0, runtime=True),
    Param("fine.move_per_overdrive", 0.0, "rad/rad", "doublet: the valve's move per twist overdrive at breakaway "
          "(benchmarks/fine_doublet.py: ~4): after a doublet that did not move the valve the next stair climbs as far "
          "as the worst move it allows still leaves at most half the error (a move up to 1.5 x it; up to 1 x where it "
          "must not cross), between fine.doublet_probe_step x the band and fine.kick_rise_rad (0 = always "
          "fine.doublet_probe_step; 4 measured no better on the nominal box, task h21n)", 0.0, 100.0, runtime=True),
    Param("fine.move_per_level", 0.0, "rad/rad", "doublet: the valve's move per rad of twist its breakaway level "
          "lies above the learned breakaway (nominal box, the plant's true level per doublet: 0.64, task h22m): a "
          "staircase whose last unmoved apex lies so far above the learned breakaway that the move expected there "
          "(the learned smallest move plus this x the excess) exceeds the error / fine.min_move_fraction stops and "
          "holds (0 = never; 0.64 measured no better on the nominal box: 68 / 51 vs 67 / 50 plateaus > 8e-4 rad on "
          "seeds 1000 / 2000)", 0.0, 100.0, runtime=True),
    Param("fine.retreat_full_periods", 1, "", "doublet: loop periods of the whole current (fine.peak_current_a) "
          "backwards after the kick, then one of half of it (the valve lets go at the end of the first: a second "
          "whole period cuts the bare plant's smallest move 0.74 -> 0.68e-3 rad, but in closed loop the servo's rebound "
          "from the deeper swing broke valves loose for whole jumps: nominal box 139 vs 67 plateaus > 8e-4 rad, task "
          "h22m)", 1, 3, runtime=True),
    Param("fine.learn_kick_rise", False, "", "doublet: plan each preload below its stair's apex by the twist the "
          "kick was seen to add above the preload (the mean over the stage's own unmoved doublets) instead of "
          "fine.kick_rise_rad (nominal box: 0.28-0.30e-3 rad seen where 0.15e-3 is planned; on, measured no better: "
          "121 / 124 vs 144 / 116 plateaus > 5e-4, 63 / 51 vs 67 / 50 > 8e-4 rad on seeds 1000 / 2000, p95 1.85e-3 vs "
          "1.32e-3 on seed 1000; first stairs letting go during the kick's rise 9 vs 6 on 80 runs, task h22f)", runtime=True),
    Param("fine.first_kick_fraction", 1.0, "", "doublet: a staircase's first stair kicks with this fraction of "
          "fine.kick_current_a, its preload planned that fraction of fine.kick_rise_rad (or with fine.learn_kick_rise "
          "the rise its own first stairs were seen to reach) below its apex (1 = the same kick on every stair; 0.5 with "
          "fine.learn_kick_rise measured worse on the nominal box: 71 / 62 vs 67 / 50 plateaus > 8e-4 rad on seeds "
          "1000 / 2000, task h22f)",
          0.0, 1.0, runtime=True),
    Param("fine.doublet_jump_fraction", 0.0, "", "a torque doublet also for errors up to this fraction of the "
          "nominal stick-slip jump 2 (T_s - T_c(dp)) / K, besides fine.doublet_max_error_rad (0 = never; task h23s: "
          "on a soft coupling, K 200, the main law stops ~half a jump short and the servo-blended pulse's preload broke "
          "the valve loose a whole jump across, 2 % step overshoot 27.6 %; 0.5 gives 0.5 % there but the nominal box "
          "134 vs 67 plateaus > 8e-4 rad, p95 2.27e-3 vs 1.32e-3: docs §37)",
          0.0, 2.0, runtime=True),
    Param("fine.doublet_sigmas", 2.0, "", "doublet: after each stop the first apex lies this many learned rms "
          "scatters of the breakaway twist below the learned breakaway", 0.0, 10.0, runtime=True),
    Param("fine.scatter_gain", 0.2, "", "weight of each breakaway sample (the main law's from rest, a doublet's) "
          "in the learned breakaway twist and its rms scatter per direction and dp band", 0.0, 1.0, runtime=True),
    Param("fine.fit_margin", 0.3, "", "the stage engages only on a valve whose twist at rest lies inside the "
          "nominal static band (load +- T_s(dp)) / K widened by this fraction of T_s / K (breakaway scatter and "
          "ripple); beyond it the model does not describe the valve and the main law's integral hold keeps it",
          0.0, 10.0, runtime=True),
    Param("fine.misfit_weight", 0.5, "", "weight of each engagement's outcome (failed: handed back, or the valve "
          "left further off than found) in the learned misfit record per direction and dp band (0 = never learn)",
          0.0, 1.0, runtime=True),
    Param("fine.misfit_limit", 0.5, "", "above this misfit record the stage stays out of that direction and dp "
          "band (0.5 with weight 0.5: after two failures in a row)", 0.0, 1.0, runtime=True),
    Param("fine.misfit_decay", 0.9, "", "the misfit record decays by this factor per plateau the stage stays "
          "out of (0.9: it tries again after ~4 plateaus)", 0.0, 1.0, runtime=True),
    Param("fine.breakaway_fit", 0.3, "", "the stage engages only when the twist at which the main law last broke "
          "the valve loose lies within this fraction of T_s(dp)/K of the nominal breakaway twist (load +- T_s) / K "
          "(measured: within 0.15 on the nominal plant with friction scatter, 0.5-2.7 off on valves the model does "
          "not describe)", 0.0, 10.0, runtime=True),
    Param("fine.learned_scale_min", 1.0, "", "the stage plans from the friction scale s and steady load its "
          "valve's main-law breakaways show (two each way: s = (r+ - r-) / 2 of the ratios (twist K - load) / T_s) "
          "when the told model does not fit them and s lies in [fine.learned_scale_min, fine.learned_scale_max]; "
          "1 and 1: the told model only (task h26f, docs §50); 1 (default, with fine.learned_scale_max 2: task h29f, "
          "docs §64): below the told friction the full box's seven runs that read s 0.5-1 (1010: LuGre x0.58, read "
          "0.57 -- right; 1112, 1183, 1137 ...) ended their plateaus +25.7e-3 rad worse in sum, the four above 1 -36e-3", 0.2, 1.0, runtime=True),
    Param("fine.learned_scale_max", 2.0, "", "upper end of the friction scale the stage plans from "
          "(fine.learned_scale_min; 1: the told model only; 2 by default, task h29f, docs §64)", 1.0, 5.0, runtime=True),
    Param("fine.learned_load_max", 1.0, "", "... and only while the steady load read beyond the told one is at most "
          "this x T_s(dp) (the breakaways' (r+ + r-) / 2; task h26f, docs §50: with any load, reads of 1.4-5.7 T_s on "
          "loaded full-box valves made their plateaus worse and one run hunt; 1: full box median -1 %, p95 and hunters "
          "unchanged)", 0.0, 1.0e3, runtime=True),
    Param("fine.learned_one_sample", True, "", "with fine.learned_scale_min/max: a direction's friction ratio is read "
          "from its first breakaway when that is plausible (beyond every ratio seen the other way, and within "
          "[learned_scale_min - learned_load_max - breakaway_fit, learned_scale_max + learned_load_max + breakaway_fit]); "
          "later breakaways take the median as before (task h28f, docs §59)", runtime=True),
    Param("fine.preload_sigmas", 0.0, "", "a servo-blended pulse's preload lies at least this many learned rms "
          "scatters of the breakaway twist below the learned breakaway, besides fine.preload_margin x the static band "
          "(0 = the band's fraction only; task h29a, docs §63)", 0.0, 10.0, runtime=True),
    Param("fine.drop_rest_at_engage", True, "", "the rest the stage reads the main law's next breakaway from "
          "(the twist holding the valve after the engage time at rest, while the stage is idle) is dropped when the "
          "stage engages: kept, the valve's displacement by the stage's own pulses read as a main-law breakaway from "
          "the rest before them, at that rest's twist, after a hand-back or a new demand mid-staircase (task h29a, "
          "docs §63)", runtime=True),
    Param("fine.learned_agree", False, "", "with fine.learned_scale_min/max: a direction's kept friction ratios "
          "(its last three main-law breakaways) are read only while they spread no more than fine.breakaway_fit "
          "(friction scatter: < 0.15 on the nominal plant); wider, they read nothing, as two that disagree "
          "(task h29f, docs §64)", runtime=True),
    Param("fine.restair_sigmas", 0.0, "", "after two preload breakaways on one plateau the stage goes on with "
          "a doublet staircase whose first apex lies this many learned rms scatters of the breakaway twist below the "
          "preload twist the last one broke at, instead of handing the plateau back to the main law; a third hands it "
          "back (0 = hand back at the second; task h30b, docs §66)", 0.0, 10.0, runtime=True),
    Param("fine.cold_start", True, "", "the stage engages before any breakaway has been seen (a run's first "
          "steps too small for the main law's hold to move the valve): after FRESH_WAIT engage times at rest with "
          "the twist at rest inside the nominal static band, it judges the valve by its own first doublets and "
          "hands back when the first breakaway they find lies beyond fine.breakaway_fit x T_s/K of nominal.  On "
          "since stop 34 with fine.cold_climb and fine.cold_still (docs section 117: nominal plateaus > 8e-4 rad "
          "56 -> 36 of 1440); alone (without the climb) it throws a valve with friction x0.5-0.8 of the told a whole "
          "jump across its first small step (1.5e-3 rad step: 2.2-4.3e-3 off; docs section 114.9)",
          runtime=True),
    Param("fine.cold_band_gate", False, "", "with fine.cold_start: a cold engagement also needs the main law's hold "
          "to have met both slip edges of the static band, half their difference within fine.breakaway_fit x T_s of "
          "the told static friction (a valve of about the told friction: the cold staircase neither breaks a "
          "low-friction valve loose in its first preload nor climbs toward a far higher level); no band measured, no "
          "cold engagement (task h30c, docs §67)", runtime=True),
    Param("fine.cold_climb", True, "", "with fine.cold_start and fine.apex_policy: a cold try parks at the furthest "
          "twist the valve is proven to hold (the last unmoved apex, else its rest twist) and kicks with the largest "
          "kick, until the next apex would enter the told level's region (fine.doublet_sigmas prior scatters below "
          "it), where the policy takes over: a valve of less friction than told is crossed in a kick, not in a park; "
          "its trough and final twist sized for the level proven; cold only once the demand has changed since the "
          "start, on any error inside the main law's deadband (task s33, docs section 116; on since stop 34, section "
          "117)", runtime=True),
    Param("fine.cold_friction_min", 0.0, "", "fine.cold_climb: the least valve friction (x the told static level) "
          "assumed before any breakaway: the climb's first preload lies fine.doublet_sigmas prior scatters below that "
          "level and its retreat's trough above the other way's (0: none -- the climb starts from the twist the valve "
          "rests at; at 0.5, the issue's lowest friction, a valve told the rated dp at 0 dp (x0.09) broke loose in "
          "the first park: docs section 116)", 0.0, 1.0, runtime=True),
    Param("fine.cold_still", True, "", "with fine.cold_start: a cold engagement needs the valve still where it was "
          "when this plateau's demand arrived (within fine.tolerance_counts): the cold class is a first step the main "
          "law left unmoved; a valve the hold moved toward the target (creep, LuGre friction) rests at the edge of its "
          "band, and the climb from that rest threw full box 3025 (friction x2.9, untold load) 1.5e-2 rad across "
          "(task s34, docs section 117)", runtime=True),
    Param("fine.rest_noise_rate", 0.015, "", "where more than this fraction of a still valve's sample-to-sample "
          "reading steps fail the rest test (a step under half fine.tolerance_counts; read while the main law holds) "
          "-- a noisy valve resolver -- the engage test's rest compares the means of the last two fine.engage_time_s "
          "of readings instead, and a main-law breakaway's twist is read at the slide's onset: at 0.5-1 count rms the "
          "steps reset the rest count and left the breakaway's twist stale, and the stage seldom engaged (nominal "
          "0.25-count resolver: 0.14 % median, 0.78 % at most; 0.5 count: 1.7 % at least; 0: never; task s35, docs "
          "section 119: on by default since stop 35)",
          0.0, 1.0, runtime=True),
    Param("fine.timeable_delay", True, "", "the stage stays out where its gear-output servo has no phase margin "
          "with the loop period and the measured resolver_delay_s (without: the period's lag alone -- the 60 Hz servo "
          "of the 1 kHz loop has none left from ~0.9 ms of delay, and limit-cycled at +-30 A there; task s35, docs "
          "section 119: on by default since stop 35)",
          runtime=True),
    Param("fine.min_jump_rad", 1.0e-3, "rad", "the stage engages only where the nominal stick-slip jump "
          "2 (T_s - T_c(dp)) / K at the dp scheduled is at least this: below it (dp < ~15 % of max) the doublet's "
          "smallest move exceeds the valve's whole jump (bare plant: 0.77e-3 / 2.2e-3 / 1.4e-3 rad at 0 / 5 / 10 % "
          "of max dp for jumps of 0.42-0.83e-3; 2.6e-4 at 50 %) and the main law's hold, its deadband about half "
          "a jump, ends closer (at dp 0 the stage's doublets overshot the 2 % step 24-38 %)", 0.0, 1.0,
          runtime=True),
    Param("fine.reversal_lead_s", 0.02, "s", "the stage counts the valve's reversals on a plateau from this long "
          "before the hunting metric's window (common.hunting.HUNT_SETTLE_S after the step) and never makes the "
          "one that would be the metric's second: the conditioned demand reaches it a few periods after the step, "
          "and counted from earlier it counts no fewer", 0.0, 0.3, runtime=True),
    Param("fine.hold_reversed", False, "", "the stage does not hand a plateau back to the main law (a preload that "
          "broke the valve loose twice, a move away from the target, a learned state or twist that does not fit) once "
          "the valve has reversed on the plateau's late window or the main law's move back would reverse it: that move "
          "starts from the edge of the static band the valve has just slid to, and where it crossed the target it was "
          "the hunting metric's second reversal (nominal box seed 2035 plateau 10 with fine.apex_policy: 1.0e-2 rad, "
          "2 reversals; task h34h, docs section 86) -- the stage holds the gear output where it is instead, and makes "
          "no more pulses on the plateau; in force also whenever fine.apex_policy is", runtime=True),
    Param("fine.no_cross_short", 0.4, "", "a move that must not cross the target (the valve has reversed once on "
          "the plateau's late window, or this move would) aims this fraction of the nominal stick-slip jump "
          "2 (T_s - T_c(dp)) / K short, and is made only for an error of at least twice that (0 = never made)",
          0.0, 2.0, runtime=True),
    Param("fine.late_loop_s", 2.5e-3, "s", "real time: a resolver sample that arrives, or is stamped, more than "
          "this beyond one period after the previous one marks the loop late (as does a drive watchdog trip); the "
          "stage's pulses are timed open-loop torques that a late loop stretches -- a 29 A kick held ~7 ms instead "
          "of ~4 ms by a starved loop moved a held valve 6.5e-2 rad -- so it stands aside (the main law holds) "
          "for fine.late_loop_holdoff_s after (measured beside two CPU hogs: gaps of 1-2 ms beyond the period a "
          "few times a second, one of 6 ms in 15 s)", 5e-4, 1.0, runtime=True),
    Param("fine.late_loop_holdoff_s", 2.0, "s", "the stage stands aside this long after the loop was late "
          "(fine.late_loop_s; 0 = never) where it keeps being late (fine.late_loop_repeats; else "
          "fine.late_loop_holdoff_first_s): where it was late every 0.25 s, a 0.2 s hold-off let valves be thrown up "
          "to 1.4e-2 rad, 2 s 2.7e-3 (docs section 113)", 0.0, 600.0, runtime=True),
    Param("fine.late_loop_holdoff_first_s", 0.2, "s", "the hold-off after a late loop that is not repeated "
          "(fewer than fine.late_loop_repeats late episodes in the fine.late_loop_holdoff_s before it; at most "
          "that): an isolated late loop costs the stage a try, and kept aside 2 s the plateau is left to the main "
          "law, whose steps overshoot (start-up profile with late answers emulated, benchmarks/loop_stalls.py: 23 "
          "of 192 steps over 10 % with 2 s alone, 6 with this; docs section 113)", 0.0, 600.0, runtime=True),
    Param("fine.late_loop_repeats", 2, "", "earlier late episodes (late loops more than "
          "fine.late_loop_holdoff_first_s apart) within fine.late_loop_holdoff_s that make a late loop's hold-off "
          "the long one: a loop late every 0.25 s (benchmarks/vcpu_freezes.py) keeps the stage aside as with 2 s "
          "alone (valves thrown at most 2.9e-3 rad; 1: the same, 3: 8.4e-3)", 1, 15, runtime=True),
    Param("fine.pulse_fallback", True, "", "real time: while the stage commands, the drive is told on the latched "
          "current_fallback topic what to apply in periods whose command is late: after a doublet's kick (a "
          "one-period timed torque) its planned retreat for one period, then the current holding the valve against "
          "the known load (the middle of the static band); in the stage's other periods that current alone -- held "
          "instead, a kick is a longer kick and throws the valve.  Empty (hold the last command) while the main law "
          "commands (docs section 113).  Off: always empty", runtime=True),
    Param("fine.kick_lost_fraction", 0.15, "", "real time: a doublet's kick whose gear-output acceleration, read "
          "from the motor resolver in the next sample, is below this fraction of the one its torque makes did not "
          "reach the drive (a late command; a kick that reached it reads 0.64 nominal, 0.41 at 18 V with the "
          "inertia +20 %, a lost one about 0): the stage kicks again instead of retreating (a retreat with no kick "
          "before it throws the valve backwards), and hands the plateau back if that kick is lost too; counted in "
          "fine_kicks_lost on /diagnostics.  0: not checked (docs section 114)", 0.0, 0.9, runtime=True),
    Param("fine.pressure_bands", 4, "", "learned values are kept per direction and per this many Δp bands",
          1, 64),
    Param("fine.learn_limit_rad", 0.15, "rad", "bound of every learned twist offset (covers friction x3 on a "
          "coupling x0.3: (3 Ts + load) / (0.3 K) ~ 0.14 rad)", 1e-4, 1.0),
    Param("fine.engage_inside_deadband", False, "", "the stage does not wait FRESH_WAIT engage times for the main "
          "law to break the valve loose on a plateau whose error at rest lies inside the main law's integrator "
          "deadband by at least fine.tolerance_counts (and the hold probes nothing: coupling read as told): its hold "
          "does not move the valve there, and the wait (0.09 s of a 0.3-0.8 s plateau) was out of the doublet "
          "staircase's time (task h32d, docs §76)", runtime=True),
    Param("fine.stair_growth_after", 0, "", "doublet: after this many stairs of one staircase that did not move the "
          "valve, each further stair climbs fine.doublet_probe_step x the band x (stairs done / this) -- a staircase "
          "that far up is in the tail of the stairs-needed distribution (nominal box: median 6, p90 19) -- at most "
          "fine.kick_rise_rad (the next preload below the apex reached) and as far as the worst move it allows "
          "(smallest move + fine.move_per_overdrive, else fine.stair_growth_slope, x the stair) leaves at most half "
          "the error (0 = never; 12 measured no better on the nominal box: the tail's moves are already large, docs §77; "
          "task h32e)", 0, 1000, runtime=True),
    Param("fine.stair_growth_slope", 4.0, "rad/rad", "fine.stair_growth_after: the valve's move per twist overdrive "
          "at breakaway the grown stair is bounded with where fine.move_per_overdrive is 0 (benchmarks/fine_doublet.py: "
          "~4)", 0.1, 100.0, runtime=True),
    Param("fine.apex_policy", True, "", "doublet: each apex placed where the learned breakaway level's law (normal, "
          "the learned level and scatter, truncated from below by the highest apex an unmoved doublet reached at this "
          "stop) and the doublet's move model give the largest P(land within fine.apex_land_rad) + P(no move) x the "
          "next try's best such chance, instead of a staircase from fine.doublet_sigmas scatters below the level; no "
          "try more likely to worsen the error than to improve it (it replaces the smallest-move stopping rules; task "
          "h33p, docs/control_results.md section 81).  Not at run time: with it on, the ROS controller node builds the "
          "doublet's move tables at configure (~14 s of CPU; task h34t)"),
    Param("fine.apex_land_rad", 4e-4, "rad", "fine.apex_policy: the landing tolerance its tries aim into (issue 14's "
          "5e-4 rad p95 target less a resolver count of noise; benchmarks/plateau_floor.py's stop tolerance)",
          1e-4, 2e-3, runtime=True),
    Param("fine.apex_move_sd_rad", 2e-4, "rad", "fine.apex_policy: rms error of the doublet's move model about its "
          "prediction (docs section 33: the moved doublets' residual about the fit to the true static excess, "
          "0.19e-3 rad)", 1e-5, 2e-3, runtime=True),
    Param("fine.apex_min_chance", 0.0, "", "fine.apex_policy: no try whose chance of ending within "
          "fine.apex_land_rad (this try or, after no move, the next) is not above this (0: every try not more "
          "likely to worsen the error; 0.1 stopped staircases main's finished, task h33p)", 0.0, 1.0,
          runtime=True),
    Param("fine.apex_kick_ratio", 2.0, "", "fine.apex_policy: successive kicks of its set are this many times the "
          "last (2: 4 / 8 / 16 A; smaller: a finer choice of the apex a kick's rise reaches from the last unmoved apex)",
          1.05, 4.0, runtime=True),
    Param("fine.apex_retreat_periods", 2, "", "fine.apex_policy: its doublets retreat this many loop periods at the "
          "whole current (fine.peak_current_a) before the half one (0 = fine.retreat_full_periods; h33a: the deeper "
          "retreat carries plateau_floor's gain)", 0, 3, runtime=True),
    Param("fine.apex_kick_max_a", 16.0, "A", "fine.apex_policy: the kick is chosen per try among "
          "fine.kick_current_a x 1, 2, 4 ... up to this (docs section 75.4: the kick's size sets how much the "
          "level's draw matters; 0 = fine.kick_current_a only)", 0.0, 30.0, runtime=True),
    Param("fine.retreat_cap", True, "", "doublet: the retreat is the whole current command itself, -fine.peak_current_a "
          "toward the move's start, for its whole periods (fine.apex_retreat_periods, else fine.retreat_full_periods), "
          "and no half period -- benchmarks/plateau_floor.py's deep shape (docs section 82) -- instead of the hold "
          "less the whole current (-19.4 A for an opening pulse at 0.5 rad, max dp) and a period of half; false: "
          "main's doublet (task h34s, docs section 84)", runtime=True),
    Param("fine.retreat_cap_half", False, "", "with fine.retreat_cap: keep main's period of half the current (the "
          "hold less half of fine.peak_current_a) after the retreat's whole periods, before the observe servo (traced: "
          "without it the servo's first period pushes toward the move while the valve still slides; task h34s, docs "
          "section 84)", runtime=True),
    Param("fine.observe_hold_integral", False, "", "doublet: the gear-output servo's integral is not integrated while "
          "it pulls the retreat's swing back after a doublet (the observe phase): held at the value the park left. "
          "Saturated at the current cap for 3-4 periods, the deeper retreat's pull-back wound it to ~3.4e-3 rad of "
          "equivalent position error (main's doublet: 0.6e-3), the gear output overshot the final twist by 2-3e-3 rad "
          "and the rebound broke the valve loose a second time (task h34s, docs section 84)", runtime=True),
    Param("fine.retreat_return_guard", False, "", "doublet: a doublet whose valve went a tolerance toward the try and "
          "came back to within half a tolerance of its start is a move there and back, not an unmoved stair: counted "
          "as a pulse, the plateau held where it is, and every later doublet on this plant retreats one whole period "
          "(its trough passed the other way's breakaway: the slippery valve, friction x0.4, with fine.retreat_cap and "
          "fine.apex_retreat_periods 2 repeated such doublets 20 times -- hunting; task h35v, docs section 89)",
          runtime=True),
    Param("fine.retreat_trough_bound", True, "", "doublet: a retreat whose trough -- the twist the move model "
          "(fine.apex_policy's PulseMoves) predicts after the kick on a valve that stays stuck -- would pass the other "
          "way's learned breakaway twist less fine.doublet_sigmas of its learned scatter is made shallower: fewer whole "
          "periods, then one period's command scaled toward the hold.  The deep retreat (fine.retreat_cap, two periods) "
          "swings the twist 7-17e-3 rad below the preload: inside the nominal valve's static band at max Δp, past the "
          "other breakaway at low Δp (full box run 1069) or on a narrow band (friction x0.4, stiff coupling) -- the "
          "valve broke loose backwards (task h36g, docs section 90)", runtime=True),
    Param("fine.retreat_trough_misfit", False, "", "with fine.retreat_trough_bound: the trough's margin above the other "
          "way's learned breakaway also fine.breakaway_fit x T_s(dp)/K -- the level misfit the stage engages with (full "
          "box run 1069, coupling x0.91 untold: the true closing level lay 1.5e-3 rad above the learned one; task h36g, "
          "docs section 90)", runtime=True),
    Param("fine.park_settle", False, "", "doublet: the park ends (the kick starts) only once the gear output has "
          "settled on the preload -- its speed within the drivetrain's stuck-valve mode sqrt(K/J1) x "
          "fine.tolerance_counts (a ringing of at most the tolerance) -- or after as many periods again as the park "
          "planned.  A park still ringing adds its swing to the kick and to the retreat's trough, which the move "
          "model's trough (fine.retreat_trough_bound) then misreads by 3-4e-3 rad (full box run 1069: the gear output "
          "ran +1 rad/s into the kick and the trough passed the closing breakaway; task h37t, docs section 96)",
          runtime=True),
    Param("fine.retreat_trough_delay", False, "", "with fine.retreat_trough_bound: the move model's trough has the "
          "observe servo read the gear output and valve resolver_delay_s late (at most one period), as the stage's own "
          "servo does -- the model's tables assume 50 us; at 0.62 ms (full box run 1069) its trough of a one-period "
          "retreat lay 1.2-1.5e-3 rad shallower than with the delay (task h37t, docs section 96)", runtime=True),
    Param("fine.apex_unraised_plan", False, "", "fine.apex_policy: after an unmoved try whose measured apex raised the "
          "floor (the highest unmoved apex of the stop) by less than a resolver count, the level's law is truncated at "
          "that try's planned apex instead: truncated at the reading it gave the same try again and again (full box run "
          "1027, coupling x0.81 untold: the apex read 0.45e-3 rad below its plan, 15, 15 and 141 identical unmoved "
          "tries on three plateaus; task h37t, docs section 96).  A narrower fine.apex_floor_plan", runtime=True),
    Param("fine.apex_probe_hold", False, "", "fine.apex_policy with fine.retreat_trough_bound: where the bound has cut "
          "the planned retreat, a try the policy expects not to move the valve -- P(no move) within main's park-break "
          "chance Phi(-fine.doublet_sigmas) of 1 -- retreats one period at the hold instead of the bound's shallower "
          "retreat: there is no move to stop, and the move model's one-period troughs read 3.3-4.2e-3 rad shallow on "
          "full box run 1069 (#7: P(no move) 1.000); task h37t, docs section 96", runtime=True),
    Param("fine.retreat_return_rest", False, "", "with fine.retreat_return_guard: when the return is seen the observe "
          "servo's reference is frozen at the gear output's present angle and the doublet is judged once the valve rests "
          "(back at its start: counted and the plateau held; else as any move) instead of leaving the plateau (task "
          "h35v, docs section 89)", runtime=True),
    Param("fine.retreat_return_hold", False, "", "with fine.retreat_return_guard: when the return is seen the stage holds "
          "the gear output where it is (no more pulses on the plateau) instead of handing the plateau back (task h35v, "
          "docs section 89)", runtime=True),
    Param("fine.servo_coupling_cap", True, "", "the stage's gear-output servo stiffness capped on a coupling stiffer "
          "(relative to J1) than the default valve's: with the valve stuck the coupling's K adds to the servo's kp, and "
          "kp + K is held at most the default valve's J1 (w^2 + K_ref/J1_ref) (w = 2 pi fine.servo_hz; never below "
          "J1 w^2 / 4), so the closed loop keeps the designed poles and damping; K 1500 N*m/rad: zeta 0.62 -> 0.73, "
          "the pull back from a retreat's trough no longer overshoots past that valve's narrow static band (stiff "
          "coupling step_small with C3 + fine.retreat_trough_bound 14.4 -> 0 %; task h40s, docs section 105).  Valves "
          "no stiffer: unchanged",
          runtime=False),
    Param("fine.unmoved_settled", False, "", "doublet: an unmoved doublet is judged (and the next park planned "
          "from rest) only once the gear output's speed is below fine.park_approach_speed_rad_s, or at the end of "
          "fine.observe_time_s (after a 16 A kick the retreat's rebound still ran ~0.65 rad/s toward the level and "
          "the next park carried it 0.36e-3 rad past its preload, breaking the valve loose in 12 of 120 parks; "
          "task h35v, docs section 89)", runtime=True),
    Param("fine.observe_hold_moved", True, "", "doublet: as fine.observe_hold_integral, but only in the observe of a "
          "doublet that has moved the valve (half a tolerance from its start): an unmoved stair's observe integrates as "
          "main's, whose next park is tuned with it (held there too, the parks ended 0.57e-3 rad short of their planned "
          "preload, median: 12 vs 29 moves in 10 nominal runs, 549 vs 479 doublets; task h34s, docs section 84)", runtime=True),
    Param("fine.apex_excess_nominal", True, "", "fine.apex_policy: the move model's excess (the level above the "
          "Coulomb-equilibrium twist) taken from the stage model's own Coulomb equilibrium (load + T_c)/K -- the "
          "coordinate the model is built in -- not from the learned swing centre (fine.learn's equilibrium offset: "
          "0.14-0.21e-3 rad toward the try on the nominal box, which read the moves 1.3-1.4 x short; task h34m, "
          "docs section 85)", runtime=True),
    Param("fine.apex_choice_after_command", True, "", "fine.apex_policy: the choice of a try an observe's verdict "
          "starts (~0.5-1 ms of CPU, docs section 94) runs after that period's command has gone out -- the ROS node "
          "calls it once the command is published, offline the next period runs it first -- instead of between the "
          "resolver sample and the command: the same choices and commands to the last bit (that period's command "
          "reads nothing the choice sets; not with fine.retreat_stop_unmoved or fine.repark_from_state, where the "
          "choice stays inline).  A plateau's first try (the engagement's) stays inline (task h39n, docs section 103)",
          runtime=True),
    Param("fine.retreat_plan_after_command", True, "", "fine.retreat_trough_bound: the doublet's retreat (how many "
          "periods at the cap, how deep -- the move model's trough on a stuck valve, 0.3-1.2 ms of CPU, docs section "
          "108.5) is planned after the kick period's command has gone out -- the ROS node runs it once the command is "
          "published, offline the next period runs it first -- instead of between the resolver sample and the kick's "
          "command: the same plans and commands to the last bit (the kick reads nothing the plan sets; docs section "
          "111)", runtime=True),
    Param("fine.apex_floor_plan", True, "", "fine.apex_policy: after an unmoved try the level's law is truncated "
          "at the higher of the apex the resolvers read and the apex the try planned (the once-a-period sample "
          "misses the kick's peak; plateau_floor's --floor plan, docs section 82.3; task h34m)", runtime=True),
    Param("fine.apex_kick_continuous", False, "", "fine.apex_policy: after an unmoved try the preload stays at the "
          "last unmoved apex (a twist that held the valve) and the kick current is the continuous variable, sized "
          "by the move model's rise to reach each candidate apex (moves interpolated between the kick set's "
          "tables), within fine.kick_current_a .. fine.apex_kick_max_a and the current cap (task h34m, docs "
          "section 85)", runtime=True),
    Param("fine.apex_worse_given_move", False, "", "fine.apex_policy: no try more likely to worsen the error than "
          "to improve it *given that it moves* (the policy's rule counts P(no move) as not worse: at a stop whose "
          "level lies high every move overshoots the error and the law's climb went on until one did; task h34m, "
          "docs section 85)", runtime=True),
    Param("fine.apex_keep_rad", 8e-4, "rad", "fine.apex_policy: from a rest within this |error| a try is judged as "
          "with fine.apex_worse_given_move (no try more likely to worsen the error than to improve it given that it "
          "moves); beyond it by the policy's unconditional rule.  With it on, a hold the policy decides while the gear "
          "output still turns faster than fine.park_approach_speed_rad_s is reached by a park from the present twist "
          "(not a servo reference stepped to the hold's twist).  0: off (task h41n, docs section 110; on since stop 29, "
          "section 111: nominal pool 63 -> 56 plateaus > 8e-4, p95 0.756 -> 0.706e-3 rad)",
          0.0, 0.05, runtime=True),
    Param("fine.servo_unmoved_doublet", 0, "", "after this many servo-blended pulses toward one way that did not move "
          "the valve at a stop, the next pulses there are doublets (with fine.apex_policy the policy's tries) while "
          "|error| is within one nominal stick-slip jump: a servo-blended pulse's apex stops short of its plan at a "
          "level drawn high, each unmoved pulse raises the learned level one probe step, and the one that lets go "
          "throws the valve a whole jump.  0: off (task h42s, docs section 112)", 0, 1000, runtime=True),
    Param("fine.servo_unmoved_doublet_jumps", 1.0, "", "fine.servo_unmoved_doublet: only while |error| is within "
          "this many nominal stick-slip jumps at the stop's pressure (task h42s, docs section 112)", 0.0, 10.0,
          runtime=True),
    Param("fine.apex_level_law", "mixture", "", "fine.apex_policy: the law of the static level the apex is placed on: "
          "normal = the learned level and scatter (a normal clipped at 3 scatters); mixture = a mixture of normals "
          "about the learned level with scatters log-uniform from the learned one to the widest the stage is designed "
          "for (fine.breakaway_fit / 3 x T_s(dp)/K: a level within the engage gate's bound at 3 scatters) -- the "
          "campaign draws each valve's scatter from a range and the learned one is a few stops' estimate, so the law "
          "is heavier tailed than one normal; student = a Student-t with the learned scatter and (2 - "
          "fine.scatter_gain) / fine.scatter_gain - 1 degrees of freedom (the learned scatter's sample count; task "
          "h36l, docs section 92)", choices=("normal", "mixture", "student"), runtime=True),
    Param("fine.apex_mix_points", 81, "", "fine.apex_level_law mixture / student: the levels the law is weighed on "
          "(equally spaced over +-3 of its widest scatter; 81 as built, docs section 92).  The choice's cost grows about "
          "as their square (the candidates are the levels and 8 more): fewer is a cheaper, coarser choice -- not the "
          "same tries (task h40m, docs section 106)", 21, 161, runtime=True),
    Param("fine.apex_floor_repeat", False, "", "fine.apex_policy: once the policy plans an apex no further (within half "
          "of fine.tolerance_rad) than one it already tried at this stop without moving the valve, the law is "
          "truncated at the planned apex, not the measured one, for the rest of the stop (the reading is shown short "
          "of the plan; fine.apex_floor_plan does it from the first try; task h37m, docs section 95)", runtime=True),
    Param("fine.engage_gear_rest", 0.1, "", "the fine stage engages only once the gear output no longer winds the "
          "twist away from the target by more than this fraction of fine.tolerance_rad a period (the valve at rest "
          "with the main law's last move still unwinding sits in a stick mid-swing and slides on; 0 = off; task "
          "h37m, docs section 95)", 0.0, 10.0, runtime=True),
    Param("fine.handover_unwind", False, "", "a new demand arriving while the fine stage holds the valve with the twist "
          "on the new move's side of the static band's middle (between the learned breakaways): the stage moves the "
          "gear output to the band's middle over fine.observe_time_s before handing over (held next to that way's "
          "breakaway, the main law's small step broke the valve loose at once and its stick-slip jump ran past: "
          "startup seed 0 with C2, 14.6 %; task h38s, docs section 98)", runtime=True),
    Param("fine.handover_unwind_max_jumps", 0.0, "", "with fine.handover_unwind: only a new demand within this many "
          "nominal stick-slip jumps (at the present delta-p) of the valve is unwound for; a larger step hands over at "
          "once (unwound to the middle, the main law's larger moves stopped short more often and its hold then crept a "
          "whole jump past); 0 = any step (task h39h, docs section 101)", 0.0, 100.0, runtime=True),
    Param("fine.handover_unwind_near", 0.0, "", "with fine.handover_unwind: only a hold whose twist lies within this "
          "many (T_s - T_c)/K of the new move's learned breakaway is unwound for (farther, the main law's move creeps "
          "rather than lets go at once); 0 = anywhere on that side (task h39h, docs section 101)", 0.0, 100.0,
          runtime=True),
    Param("fine.hold_relax", 0.0, "", "while the fine stage holds the valve (plateau done), the gear output moves the "
          "held twist this fraction of the way to the static band's middle (between the two learned breakaway twists, "
          "the load included), slowly (fine.hold_relax_time_s), stopping if the valve moves: held next to the breakaway "
          "its last doublet pushed toward, the next small step that way broke the valve loose at once and its "
          "stick-slip jump ran past (startup seed 0 with C2, 14.6 %); 0 = off (task h39h, docs section 101)",
          0.0, 1.0, runtime=True),
    Param("fine.hold_relax_time_s", 0.06, "s", "the length of fine.hold_relax's move (a sin^2 blend; task h39h, docs "
          "section 101)", 0.001, 1.0, runtime=True),
    Param("fine.handover_settle_speed_rad_s", 0.1, "rad/s", "a new demand arriving while the fine stage is mid-park, "
          "-pulse or -observe: the stage holds the gear output where it is until it turns slower than this with the "
          "valve at rest (at most 2 x fine.observe_time_s), then hands over; the main law restarts with its observer's "
          "speeds at 0 and, handed a doublet's swing, broke the valve loose toward the new target at once (nominal "
          "seed 4034 #11, 44.7 % overshoot); 0 = at once (off; task h38s, docs section 98)", 0.0, 10.0, runtime=True),
    Param("fine.handback_settle", True, "", "with fine.handover_settle_speed_rad_s > 0: the fine stage's own "
          "hand-back decided mid-park, -pulse or -observe holds the gear output where it is until it turns slower "
          "than that speed with the valve at rest (at most 2 x fine.observe_time_s) before the main law takes over -- "
          "as a new demand's hand-over does; the main law restarts with its observer's speeds at 0, and handed the "
          "observe's pull-back from a retreat's trough it ran through the breakaway (nominal box seed 4013 #9, C3: "
          "1.06e-2 rad past a 9.4e-3 step, 112 %); off: at once (stop 28, docs section 108)", runtime=True),
    Param("fine.apex_stop_rad", 4.8e-4, "rad", "fine.apex_policy: the stage is done (it neither engages nor tries again) "
          "once the valve rests within this of the demand, when larger than fine.tolerance_rad -- the policy aims its "
          "tries into fine.apex_land_rad, but its done-test was the tolerance (3 counts, 2.9e-4 rad): from rests at "
          "2.9-4e-4 rad 59 % of its moves ended > 5e-4 (C2 + F, nominal box); 4.8e-4 measured on the nominal box "
          "(1440 plateaus > 5e-4 188 -> 161, > 8e-4 72 -> 62); 0 = off: the tolerance (task h39t, docs section 102)",
          0.0, 2e-3, runtime=True),
    Param("fine.unbiased_preload_pull", False, "", "with fine.unbiased_samples: a servo-blended pulse whose preload "
          "broke the valve loose pulls the learned breakaway to below that preload with fine.learn_gain (main's "
          "treatment), instead of the censored sample's fine.scatter_gain step toward the conditional mean (that "
          "step left the level above the twist the valve had just broken at, and the next preload broke it loose "
          "for a whole jump: full box seed 1137); not when an unmoved pulse at that stop already held an apex beyond "
          "the preload (the move is its late let-go: full box seed 1039; task h32a, docs §73)", runtime=True),
    # --- fc_gain (appendix A) ------------------------------------------------------------------
    Param("fc_gain.gain", 0.8, "", "stiction-breaking torque as a fraction of the nominal valve "
          "static friction at the current pressure", 0.0, 3.0, runtime=True),
    Param("fc_gain.error_scale_rad", 1e-3, "rad", "error over which the term ramps to full size",
          1e-6, 1.0, runtime=True),
    # --- fault logic (SPEC §4) -----------------------------------------------------------------
    Param("faults.tracking_error_rad", 0.1, "rad", "tracking error limit", 1e-3, 1.1, runtime=True),
    Param("faults.tracking_error_time_s", 1.0, "s", "time beyond the limit before the fault latches (a leaky "
          "count: time beyond the limit adds, time within it subtracts, so dips do not restart it)",
          0.01, 60.0, runtime=True),
    Param("faults.resolver_timeout_s", 0.02, "s", "resolver silence that latches a fault", 0.002, 5.0,
          runtime=True),
    Param("faults.arm_steady_s", 0.25, "s", "real time: the drive's first arm after start-up or activation "
          "waits until the resolver stream has run on time this long (no gap between samples, stamps or arrivals, "
          "beyond faults.resolver_timeout_s); until then the drive stays off (the spring holds the valve) and a "
          "resolver silence restarts the wait instead of latching a fault (a node process's start-up stalls are "
          "not a failed resolver: docs section 107).  0: arm on the first sample.  Offline and in lockstep the "
          "samples are on time by construction: arms on the first, whatever this is", 0.0, 10.0, runtime=True),
    Param("faults.resolver_max_step_rad", 0.05, "rad", "valve reading change per period that is "
          "physically impossible (implausible)", 1e-3, 1.0, runtime=True),
    # motor/valve resolver disagreement = coupling twist; both limits derive from the model
    # (driver.ValveDriver.twist_limits): the twist the applied torque can cause on a coupling
    # between this fraction of the nominal stiffness and the nominal one, plus the margin
    Param("faults.coupling_stiffness_min_fraction", 0.1, "", "softest coupling the resolver disagreement "
          "check allows for, fraction of model.coupling_stiffness_nm_per_rad (SPEC robustness box: 0.1)",
          0.05, 1.0, runtime=True),
    Param("faults.resolver_disagreement_margin_rad", 0.05, "rad", "twist beyond what the applied torque "
          "explains that is still plausible (backlash up to 0.05 rad, resolver noise, inertial torques)",
          1e-3, 0.2, runtime=True),
    Param("faults.resolver_disagreement_time_s", 0.1, "s", "leaky time the twist may disagree with the "
          "applied torque before the motor/valve resolver pair is implausible (coupling transients)",
          0.01, 1.0, runtime=True),
    Param("faults.stamp_future_tolerance_s", 0.05, "s", "a resolver sample stamped further than this ahead "
          "of the loop's clock is implausible (dropped; it never becomes the reference of the jump check)",
          0.001, 1.0, runtime=True),
    Param("faults.drive_command_timeout_s", DRIVE_COMMAND_TIMEOUT_S, "s", "command watchdog of a drive that "
          "does not report its state (no drive_status): a loop gap longer than this switched the drive off, so "
          "the loop re-arms from the measurement with the torque holding the valve there and re-enables it; 0: the drive has no "
          "command watchdog.  A drive that reports its state is followed instead (driver.py)", 0.0, 1.0),
    Param("faults.stale_sample_periods", 0.0, "", "real time: a resolver sample that reaches the loop more than "
          "this many periods later than the loop's usual latency (its age, arrival minus stamp, beyond the least age "
          "seen lately) is stale: its period commands the torque that holds the valve where it was measured instead "
          "of a law period computed for a valve that has moved on (the law skips it).  Offline starved step "
          "52.4 -> 47.3 % at 1.5; on the nodes beside two CPU hogs no better (16 + 16 interleaved stall-test runs: 2 "
          "failed with it, 3 without): most of the lateness there is on the command's way to the drive, which "
          "the loop cannot see (docs/control_results.md section 54); 0 = off (default)", 0.0, 1000.0, runtime=True),
    Param("faults.i2t_fault_time_s", 2.0, "s", "time the loop may ask for more than the I2t limit allows "
          "(jam / overload) before the fault latches", 0.05, 60.0, runtime=True),
    # --- valve health: NAMUR NE107 status and duty counters (core/health.py, issue 12) ---------
    Param("health.tracking_error_rad", 0.05, "rad", "tracking error beyond which the valve is out of "
          "specification (NE107 S), below the fault limit faults.tracking_error_rad", 1e-4, 1.1, runtime=True),
    Param("health.tracking_error_time_s", 0.5, "s", "leaky time beyond health.tracking_error_rad before "
          "out of specification", 0.01, 60.0, runtime=True),
    Param("health.hunting_reversals", 6, "", "reversals within health.hunting_window_s at a steady demand "
          "that are hunting (NE107 S)", 2, 10000, runtime=True),
    Param("health.hunting_window_s", 2.0, "s", "window of the hunting count", 0.1, 60.0, runtime=True),
    Param("health.reversal_hysteresis_rad", 1e-3, "rad", "a move back by more than this from the latest "
          "extreme is a reversal (counts travel and reversals without counting resolver noise)",
          1e-5, 0.1, runtime=True),
    Param("health.high_dp_kpa", 5000.0, "kPa", "Δp at or above which time at high Δp is counted",
          0.0, PRESSURE_MAX_KPA, runtime=True),
    Param("health.friction_band", 0.3, "", "friction trend beyond this fraction off the valve's learned "
          "baseline: maintenance required (NE107 M)", 0.01, 10.0, runtime=True),
    Param("health.trend_time_constant_s", 10.0, "s", "smoothing of the friction trend compared with the "
          "baseline", 0.01, 3600.0, runtime=True),
    Param("health.baseline_after_s", 30.0, "s", "driven time after which the smoothed friction trend becomes "
          "the valve's baseline (when none was loaded)", 0.0, 86400.0, runtime=True),
    Param("health.breakaway_rise_nm", 1.0, "N*m", "breakaway torque (valve side) above its baseline that "
          "needs maintenance (NE107 M)", 0.0, 100.0, runtime=True),
    Param("health.travel_limit_rad", 1e6, "rad", "total valve travel that needs maintenance (NE107 M)",
          0.0, 1e12, runtime=True),
    Param("health.reversal_limit", 10000000, "", "reversals that need maintenance (NE107 M)", 0, 2**62,
          runtime=True),
    # --- valve tests (core/valve_tests.py: signature and partial-stroke tests) -----------------
    Param("tests.enable", False, "", "test mode: the operator's consent to a valve signature test (it takes "
          "the valve off the demand for tens of seconds); partial-stroke tests do not need it", runtime=True),
    Param("tests.hunting_limit_rad", 2e-3, "rad", "a test is refused while the valve's position spread over "
          "the last 2 s (half peak-to-peak) exceeds this: hunting or still moving", 1e-4, 0.1, runtime=True),
    Param("tests.abort_band_pct", 1.0, "%", "a running test is aborted (the demand handed back) when the "
          "operator demand moves further than this from its value at the start", 0.05, 50.0, runtime=True),
    Param("tests.degradation_ratio", 1.5, "", "a figure (friction, breakaway, travel time) beyond this ratio "
          "of the baseline's, or below its inverse, raises 'maintenance required'", 1.05, 10.0, runtime=True),
    Param("tests.baseline_path", "", "", "controller node, read at start-up: JSON file of stored completed "
          "results (a valve_test message, fuel_valve_sim/fuel_valve_report --json output); empty: the first "
          "completed run of each test is its baseline"),
    Param("tests.signature.start_pct", 20.0, "%", "lower end of the signature ramp, percent of stroke",
          2.0, 98.0, runtime=True),
    Param("tests.signature.end_pct", 60.0, "%", "upper end of the signature ramp, percent of stroke",
          2.0, 98.0, runtime=True),
    Param("tests.signature.ramp_rate_pct_s", 5.0, "%/s", "ramp rate of the signature (slow: inertial and "
          "viscous torques small against friction)", 0.1, 50.0, runtime=True),
    Param("tests.signature.dwell_s", 1.0, "s", "rest at each end of a ramp and before the steps", 0.1, 30.0,
          runtime=True),
    Param("tests.signature.steps_pct", [0.1, 0.25, 0.5, 1.0, 2.0], "%", "step sizes of the step-response part "
          "(each stepped up from the ramp's start and back), percent of stroke", 0.01, 20.0, runtime=True),
    Param("tests.signature.step_time_s", 1.0, "s", "time each step is held (settling time is measured "
          "within it)", 0.1, 30.0, runtime=True),
    Param("tests.signature.bins", 10, "", "position bins of the friction/load curve over the ramp range", 3,
          200, runtime=True),
    Param("tests.partial.fraction_pct", 10.0, "%", "partial-stroke travel, percent of stroke (toward closed "
          "when there is room, else toward open)", 0.5, 50.0, runtime=True),
    Param("tests.partial.max_travel_pct", 15.0, "%", "largest excursion the turbine tolerates: a larger "
          "fraction is refused, a larger excursion aborts the test", 0.5, 50.0, runtime=True),
    Param("tests.partial.max_time_s", 10.0, "s", "longest the turbine tolerates the valve off its demand: "
          "the test aborts beyond it", 0.5, 120.0, runtime=True),
    Param("tests.partial.rate_pct_s", 10.0, "%/s", "rate of the partial-stroke moves", 0.5, 200.0, runtime=True),
    Param("tests.partial.dwell_s", 0.5, "s", "rest at the far end and after the return", 0.05, 10.0,
          runtime=True),
    Param("tests.partial.demand_window_s", 2.0, "s", "a partial-stroke test is refused while the demand moved "
          "over this window ...", 0.1, 60.0, runtime=True),
    Param("tests.partial.demand_band_pct", 0.5, "%", "... by more than this (peak to peak, percent of stroke)",
          0.01, 20.0, runtime=True),
    # --- nominal model (defaults = plant nominal values) --------------------------------------
    _nominal("motor_inertia_kgm2", 6.93e-6, "kg*m^2", "rotor inertia Jm", 0.0, 1.0, low_open=True),
    _nominal("motor_viscous_nms", 2.6e-5, "N*m*s/rad", "rotor viscous friction Bm", 0.0, 1.0),
    Param("model.torque_constant_nm_per_a", 1.5 * _POLE_PAIRS * _FLUX_LINKAGE_WB,
          "N*m/A", "motor torque per q-axis ampere, 1.5 p psi_f", 0.0, 10.0, low_open=True),
    # the drive's voltage budget (planned moves' speed, core/design.design_trajectory)
    _nominal("motor_pole_pairs", float(_POLE_PAIRS), "", "pole pairs p", 1.0, 32.0),
    _nominal("motor_resistance_ohm", 0.15, "ohm", "stator phase resistance R", 0.0, 10.0),
    _nominal("motor_lq_h", 0.28e-3, "H", "q-axis inductance Lq", 0.0, 1.0, low_open=True),
    _nominal("gear_ratio", 48.019, "", "gear ratio N", 1.0, 1000.0),
    _nominal("coupling_stiffness_nm_per_rad", 480.0, "N*m/rad", "coupling stiffness K", 0.0, 1e6, low_open=True),
    _nominal("coupling_damping_nms", 0.05, "N*m*s/rad", "coupling damping c", 0.0, 100.0),
    _nominal("valve_inertia_kgm2", 1.76e-3, "kg*m^2", "valve inertia JL", 0.0, 10.0, low_open=True),
    _nominal("valve_viscous_nms", 0.05, "N*m*s/rad", "valve viscous friction BL", 0.0, 100.0),
    _nominal("spring_preload_nm", 8.0, "N*m", "return-spring preload", 0.0, 200.0),
    _nominal("spring_rate_nm_per_rad", 4.0, "N*m/rad", "return-spring rate", 0.0, 1000.0),
    _nominal("flow_torque_max_nm", 2.0, "N*m", "peak flow torque at full pressure", 0.0, 50.0),
    _nominal("stroke_rad", STROKE_RAD, "rad", "stroke (open stop)", 0.1, 3.2),
    _nominal("pressure_max_kpa", PRESSURE_MAX_KPA, "kPa", "pressure of the full per_dp friction terms",
             0.0, 1e5, low_open=True),
    _nominal("motor_coulomb_nm", 0.0073, "N*m", "nominal motor Coulomb friction", 0.0, 10.0),
    _nominal("motor_static_nm", 0.010, "N*m", "nominal motor static friction", 0.0, 10.0),
    _nominal("valve_coulomb_nm", 0.4, "N*m", "nominal valve Coulomb friction at zero pressure", 0.0, 100.0),
    _nominal("valve_coulomb_per_dp_nm", 4.0, "N*m", "nominal valve Coulomb friction added at full pressure",
             0.0, 100.0),
    _nominal("valve_static_nm", 0.5, "N*m", "nominal valve static friction at zero pressure", 0.0, 100.0),
    _nominal("valve_static_per_dp_nm", 5.0, "N*m", "nominal valve static friction added at full pressure",
             0.0, 100.0),
])

#: parameters of the controller *node* only (ROS timing, telemetry, start-up); the node's schema
#: is :data:`CONTROLLER_NODE_SPEC` = these + :data:`CONTROLLER_SPEC` (the core's), and
#: ``config/controller.yaml`` is written from it
CONTROLLER_NODE_PARAMS = (
    Param("lockstep", False, "", "wait for a fresh demand each period (deterministic lockstep runs)"),
    Param("diagnostics_rate_hz", 2.0, "Hz", "rate of /diagnostics", 0.1, 100.0),
    Param("telemetry_decimation", 10, "", "publish position and estimate every N-th period (1 = every period)",
          1, 10000),
    Param("initial_current_a", 0.0, "A", "q-current the loop starts from when it first arms: bumpless "
          "take-over of a valve already held by a drive (the plant's start_held)", -40.0, 40.0),
    Param("monitor_drive_telemetry", False, "", "subscribe to the plant's drive telemetry for the "
          "measured-current check (one more 1 kHz subscription)"),
    Param("autostart", True, "", "configure and activate the managed (lifecycle) node at start; false: a "
          "supervisor drives the transitions through ~/change_state"),
    Param("learned_state_file", "", "", "file of the learned state (duty counters, friction baselines, learned "
          "twists), loaded at configure and saved at deactivate/cleanup/shutdown/exit and every "
          "learned_state_save_s ('': not persisted)"),
    Param("learned_state_save_s", 60.0, "s", "interval of the periodic save of learned_state_file", 1.0, 86400.0),
    RECORDED_TOPICS,
)
CONTROLLER_NODE_SPEC = CONTROLLER_SPEC.extended(CONTROLLER_NODE_PARAMS)


def load_controller_params(path: str | Path | None = "default", overrides=None) -> ParamSet:
    """Controller parameters from ``config/controller.yaml`` (``"default"``), a file, or none."""
    if path == "default":
        path = default_config_dir() / "controller.yaml"
    ps = CONTROLLER_SPEC.load_from_node_file(CONTROLLER_NODE_SPEC, path, overrides)
    check_consistency(ps)
    return ps


#: rating and supervision limits that may only be *tightened* at run time (issue 13): the value
#: in force at start-up is the widest a running node accepts; widening needs a restart with a
#: parameter file (a reviewed change, not a ``ros2 param set`` from anyone on the domain).
#: -1: a smaller value is tighter; +1: a larger one; a tuple: choices from loosest to tightest
TIGHTEN_ONLY = {
    "limits.peak_current_a": -1, "limits.peak_time_s": -1, "limits.continuous_current_a": -1,
    "faults.tracking_error_rad": -1, "faults.tracking_error_time_s": -1, "faults.resolver_timeout_s": -1,
    "faults.resolver_max_step_rad": -1, "faults.coupling_stiffness_min_fraction": +1,
    "faults.resolver_disagreement_margin_rad": -1, "faults.resolver_disagreement_time_s": -1,
    "faults.i2t_fault_time_s": -1, "faults.stamp_future_tolerance_s": -1, "demand_timeout_s": -1, "demand_timeout_action": ("hold", "trip"),
}


def check_tighten_only(start: ParamSet, changes: dict) -> None:
    """Raise :class:`ConfigError` if ``changes`` widens a :data:`TIGHTEN_ONLY` limit beyond
    its start-up value ``start``."""
    wider = []
    for name, value in changes.items():
        rule = TIGHTEN_ONLY.get(name)
        if rule is None:
            continue
        was = start[name]
        if isinstance(rule, tuple):
            widened = rule.index(value) < rule.index(was)
        else:
            widened = (value - was) * rule < 0
        if widened:
            wider.append(f"{name} {was!r} -> {value!r}")
    if wider:
        raise ConfigError(f"controller: rating/supervision limits can only be tightened at run time "
                          f"({'; '.join(wider)}); restart with a parameter file to widen")


def check_consistency(ps: ParamSet) -> None:
    """Cross-parameter rules a single range cannot express (raises :class:`ConfigError`)."""
    if ps["limits.continuous_current_a"] > ps["limits.peak_current_a"]:
        raise ConfigError("controller: limits.continuous_current_a must not exceed limits.peak_current_a")
    if ps["tests.signature.start_pct"] >= ps["tests.signature.end_pct"]:
        raise ConfigError("controller: tests.signature.start_pct must be below tests.signature.end_pct")

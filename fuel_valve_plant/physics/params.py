"""Plant parameters (SPEC §2) with units, ranges and data-sheet defaults.

Sign conventions used throughout the plant:

* angles in rad, positive = opening; valve 0 = closed, ``valve.stroke_rad`` = fully open;
  the motor shaft turns ``gearbox.ratio`` times the valve angle (gear output = θm / N);
* torques positive in the opening direction, except the *load* torques (return spring, flow
  torque, ``load_torque_nm``), which are given as magnitudes acting toward closed;
* friction levels are magnitudes; valve friction grows linearly with the pressure
  differential: ``T = (base + per_dp * Δp / Δp_max) * friction_scale``.
"""
from __future__ import annotations

from pathlib import Path

from fuel_valve_control.common.config_dir import default_config_dir
from fuel_valve_control.common.contract import DRIVE_COMMAND_TIMEOUT_S, PRESSURE_MAX_KPA, STROKE_RAD
from fuel_valve_control.common.paramspec import RECORDED_TOPICS, ConfigError, Param, ParamSet, ParamSpec

FRICTION_MODELS = ("stick_slip", "lugre")
RESOLVER_FAULTS = ("none", "resolver_stuck", "resolver_dropout", "resolver_noise_burst")

PLANT_SPEC = ParamSpec("plant", [
    # --- operating point (changeable at run time) ---------------------------------------
    Param("pressure_differential_kpa", PRESSURE_MAX_KPA, "kPa", "gas pressure differential across the valve",
          0.0, PRESSURE_MAX_KPA, runtime=True),
    Param("friction_scale", 1.0, "", "multiplies every friction level (robustness studies, wear)",
          0.0, 10.0, low_open=True, runtime=True),
    Param("load_torque_nm", 0.0, "N*m", "extra load torque on the valve shaft, positive toward closed",
          -30.0, 30.0, runtime=True),
    Param("supply_voltage_v", 28.0, "V", "DC bus voltage of the drive (data sheet 18-32 V)", 18.0, 32.0, runtime=True),
    Param("fault_injection", "none", "", "resolver fault injected into the valve-shaft resolver",
          choices=RESOLVER_FAULTS, runtime=True),
    Param("fault_noise_burst_rad", 0.05, "rad", "noise standard deviation while resolver_noise_burst is injected",
          0.0, 1.0, runtime=True),
    Param("initial_position_rad", 0.0, "rad", "valve angle at start (the plant starts at rest there)",
          0.0, STROKE_RAD),
    Param("seed", 0, "", "seed of the resolver noise and friction scatter generators (independent streams)",
          0, 2**31 - 1),
    # --- timing ----------------------------------------------------------------------------
    Param("physics_rate_hz", 20000.0, "Hz", "fixed integration rate of the physics (and the current loop)",
          1000.0, 200000.0),
    # --- PMS motor and drive ---------------------------------------------------------------
    Param("motor.pole_pairs", 2, "", "pole pairs p", 1, 32),
    Param("motor.resistance_ohm", 0.15, "ohm", "stator phase resistance R", 0.0, 10.0),
    Param("motor.ld_h", 0.20e-3, "H", "d-axis inductance Ld", 0.0, 1.0, low_open=True),
    Param("motor.lq_h", 0.28e-3, "H", "q-axis inductance Lq", 0.0, 1.0, low_open=True),
    Param("motor.flux_linkage_wb", 0.0115, "Wb", "permanent-magnet flux linkage psi_f", 0.0, 1.0, low_open=True),
    Param("motor.inertia_kgm2", 6.93e-6, "kg*m^2", "rotor (+ high-speed gear) inertia Jm", 0.0, 1.0, low_open=True),
    Param("motor.viscous_nms", 2.6e-5, "N*m*s/rad", "rotor viscous friction Bm", 0.0, 1.0),
    Param("drive.current_loop_bandwidth_hz", 1500.0, "Hz", "bandwidth of the dq PI current regulators",
          50.0, 10000.0),
    Param("drive.decoupling", True, "", "feed forward the dq cross-coupling and back-EMF voltages"),
    # --- drivetrain ------------------------------------------------------------------------
    Param("gearbox.ratio", 48.019, "", "gear ratio N (motor turns per valve turn)", 1.0, 1000.0),
    Param("gearbox.backlash_rad", 0.0, "rad", "total backlash at the gear output (0 = none)", 0.0, 0.05),
    Param("coupling.stiffness_nm_per_rad", 480.0, "N*m/rad", "torsional stiffness K of the coupling",
          0.0, 1e6, low_open=True),
    Param("coupling.damping_nms", 0.05, "N*m*s/rad", "torsional damping c of the coupling", 0.0, 100.0),
    Param("valve.inertia_kgm2", 1.76e-3, "kg*m^2", "valve shaft inertia JL", 0.0, 10.0, low_open=True),
    Param("valve.viscous_nms", 0.05, "N*m*s/rad", "valve shaft viscous friction BL", 0.0, 100.0),
    Param("valve.stroke_rad", STROKE_RAD, "rad", "angle of the open stop (60 deg)", 0.1, 3.2),
    # --- friction ----------------------------------------------------------------------------
    Param("friction.model", "stick_slip", "", "stick_slip: exact static/Coulomb/viscous switching; "
          "lugre: LuGre bristle model", choices=FRICTION_MODELS),
    Param("friction.pressure_max_kpa", PRESSURE_MAX_KPA, "kPa", "pressure at which per_dp terms apply in full",
          0.0, 1e5, low_open=True),
    Param("friction.motor.coulomb_nm", 0.0073, "N*m", "motor-shaft Coulomb friction Tc1", 0.0, 10.0),
    Param("friction.motor.static_nm", 0.010, "N*m", "motor-shaft static friction Ts1 (>= Coulomb)", 0.0, 10.0),
    Param("friction.motor.stribeck_velocity_rad_s", 0.0, "rad/s",
          "Stribeck velocity of the motor shaft (0 = no Stribeck curve)", 0.0, 1000.0),
    Param("friction.valve.coulomb_nm", 0.4, "N*m", "valve Coulomb friction at zero pressure", 0.0, 100.0),
    Param("friction.valve.coulomb_per_dp_nm", 4.0, "N*m", "valve Coulomb friction added at full pressure",
          0.0, 100.0),
    Param("friction.valve.static_nm", 0.5, "N*m", "valve static friction at zero pressure", 0.0, 100.0),
    Param("friction.valve.static_per_dp_nm", 5.0, "N*m", "valve static friction added at full pressure",
          0.0, 100.0),
    Param("friction.valve.stribeck_velocity_rad_s", 0.0, "rad/s",
          "Stribeck velocity of the valve shaft (0 = no Stribeck curve)", 0.0, 100.0),
    # friction that does not repeat exactly (off by default: nominal results stay reproducible)
    Param("friction.valve.static_scatter", 0.0, "", "relative rms scatter of the valve static level, drawn "
          "anew at every breakaway (normal, clipped to +-3 sigma, never below Coulomb; 0 = off)", 0.0, 0.3),
    Param("friction.valve.ripple", 0.0, "", "relative amplitude of a position ripple of both valve levels, "
          "1 + a sin(2 pi theta / period + phase) (0 = off)", 0.0, 0.3),
    Param("friction.valve.ripple_period_rad", 0.02, "rad", "valve angle per ripple period", 1e-4, 2.0),
    Param("friction.valve.ripple_phase_rad", 0.0, "rad", "phase of the ripple at the closed position",
          -10.0, 10.0),
    Param("friction.lugre.motor_stiffness_nm_per_rad", 200.0, "N*m/rad", "LuGre bristle stiffness sigma0, motor",
          0.0, 1e6, low_open=True),
    Param("friction.lugre.valve_stiffness_nm_per_rad", 5.0e4, "N*m/rad", "LuGre bristle stiffness sigma0, valve",
          0.0, 1e8, low_open=True),
    Param("friction.lugre.damping_ratio", 0.5, "", "LuGre bristle damping sigma1 as a fraction of critical",
          0.0, 2.0),
    Param("friction.lugre.motor_stribeck_velocity_rad_s", 2.0, "rad/s", "LuGre Stribeck velocity, motor",
          0.0, 1000.0, low_open=True),
    Param("friction.lugre.valve_stribeck_velocity_rad_s", 0.04, "rad/s", "LuGre Stribeck velocity, valve",
          0.0, 100.0, low_open=True),
    # --- loads -------------------------------------------------------------------------------
    Param("spring.preload_nm", 8.0, "N*m", "return-spring torque at the closed stop (toward closed)", 0.0, 200.0),
    Param("spring.rate_nm_per_rad", 4.0, "N*m/rad", "return-spring rate", 0.0, 1000.0),
    Param("flow.torque_max_nm", 2.0, "N*m", "peak flow torque at full pressure (toward closed, "
          "~ sin(pi * opening), zero at both stops)", 0.0, 50.0),
    # --- resolvers ------------------------------------------------------------------------
    Param("resolver.bits", 16, "", "resolution of both resolvers (counts per turn = 2**bits)", 8, 24),
    Param("resolver.valve_noise_counts", 0.25, "counts", "rms noise of the valve resolver, before quantisation",
          0.0, 1000.0, runtime=True),
    Param("resolver.motor_noise_counts", 0.25, "counts", "rms noise of the motor resolver, before quantisation",
          0.0, 1000.0, runtime=True),
    Param("resolver.delay_s", 50e-6, "s", "conversion delay of both resolvers (rounded to physics steps)",
          0.0, 0.02),
    # --- pressure-differential transducer (the controller's Δp input, SPEC §4) ---------------
    Param("pressure_sensor.rate_hz", 100.0, "Hz", "sample rate of the measured pressure differential",
          50.0, 10000.0),
    Param("pressure_sensor.noise_kpa", 0.0, "kPa", "rms noise of the measured pressure differential "
          "(0 = exact, so the documented control figures hold; ~6 = 0.1 % of full scale, an industrial "
          "transducer)", 0.0, 500.0, runtime=True),
    # a transducer that reads wrong (robustness studies, the controller's Δp cross-check):
    # reading = Δp (1 + gain_error) + bias_kpa + noise; both 0 = an exact transducer
    Param("pressure_sensor.bias_kpa", 0.0, "kPa", "offset of the measured pressure differential (0 = none)",
          -PRESSURE_MAX_KPA, PRESSURE_MAX_KPA, runtime=True),
    Param("pressure_sensor.gain_error", 0.0, "", "relative gain error of the measured pressure differential "
          "(0 = none, -1 = reads 0 whatever the pressure)", -1.0, 10.0, runtime=True),
    Param("pressure_sensor.silent", False, "", "the transducer sends nothing (a lost Δp input)", runtime=True),
])

#: parameters of the plant *node* only (timing and start-up of the ROS process); the node's
#: schema is :data:`PLANT_NODE_SPEC` = these + :data:`PLANT_SPEC`, and ``config/plant.yaml`` is
#: written from it (``python -m fuel_valve_control write-config``)
PLANT_NODE_PARAMS = (
    Param("publish_rate_hz", 1000.0, "Hz", "real time: resolver / telemetry publish rate (one control period)",
          10.0, 10000.0),
    Param("lockstep", False, "", "advance one control period per current_command and publish /clock"),
    Param("lockstep_participants", 2, "", "lockstep: number of nodes subscribed to /clock (use_sim_time nodes: "
          "controller, demand, recorder...) to wait for before the first step", 0, 100),
    Param("stop_after_s", 0.0, "s", "lockstep: stop advancing once the plant time reaches this (0: never), so "
          "a recorded run has exactly this length", 0.0, 1e6),
    Param("command_timeout_s", DRIVE_COMMAND_TIMEOUT_S, "s", "real time: drive watchdog; a published resolver "
          "sample not answered by a current_command for this long disables the drive (the spring closes the "
          "valve) and reports it on drive_status; it stays off until the controller re-enables it (a "
          "drive_enable true received after the trip), as a real drive does on a lost command stream "
          "(lockstep: not used, time stands still without commands)", 0.002, 0.1),
    Param("start_held", False, "", "start at rest at initial_position_rad held there by the drive (coupling "
          "twisted, holding current flowing), as the offline simulator's initial_percent does; false: at rest "
          "with the drive off"),
    RECORDED_TOPICS,
)
PLANT_NODE_SPEC = PLANT_SPEC.extended(PLANT_NODE_PARAMS)



def load_plant_params(path: str | Path | None = "default", overrides=None) -> ParamSet:
    """Plant parameters from ``config/plant.yaml`` (``"default"``), another file, or none."""
    if path == "default":
        path = default_config_dir() / "plant.yaml"
    ps = PLANT_SPEC.load_from_node_file(PLANT_NODE_SPEC, path, overrides)
    check_consistency(ps)
    return ps


def check_consistency(ps: ParamSet) -> None:
    """Cross-parameter rules a single range cannot express."""
    if ps["friction.motor.static_nm"] < ps["friction.motor.coulomb_nm"]:
        raise ConfigError("plant: friction.motor.static_nm must be >= friction.motor.coulomb_nm")
    if ps["friction.valve.static_nm"] < ps["friction.valve.coulomb_nm"]:
        raise ConfigError("plant: friction.valve.static_nm must be >= friction.valve.coulomb_nm")
    if (ps["friction.valve.static_nm"] + ps["friction.valve.static_per_dp_nm"]
            < ps["friction.valve.coulomb_nm"] + ps["friction.valve.coulomb_per_dp_nm"]):
        raise ConfigError("plant: valve static friction at full pressure must be >= its Coulomb friction")
    if ps["initial_position_rad"] > ps["valve.stroke_rad"]:
        raise ConfigError("plant: initial_position_rad must lie within the stroke (<= valve.stroke_rad)")
    # in-range values can still combine into a mode the explicit fixed-step physics cannot
    # integrate (issue 13: pole pairs 32, flux linkage 1 Wb, coupling damping 100 N*m*s/rad)
    from .stability import check_step_stability      # it needs the kernel packing (plant.py)
    check_step_stability(ps)

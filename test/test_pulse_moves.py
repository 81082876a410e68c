"""The plant-free doublet move model (``core/pulse_moves.py``, issue 14 Deliver 1, docs §80).

One module-scoped model (its two max-Δp tables, ~0.1 s each) serves every test; the plant validation
replays the same doublet on the bare nominal :class:`Plant` (no scatter / ripple, the static level set to
``T_c + K x``), started at rest with the twist at the preload (the drive holding it plus the motor's Coulomb friction, as
after the park's climb), with the FinePositioner's doublet currents and
its observe servo on the plant's true states -- the model's own idealisations, so what is compared is the
dynamics (two masses, stick-slip, the current loop), not the park or the resolvers.
"""
from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from fuel_valve_control.core.fine_positioning import FinePositioner
from fuel_valve_control.core.model import NominalModel
from fuel_valve_control.core.params import CONTROLLER_SPEC
from fuel_valve_control.core.position_controller import PositionController
from fuel_valve_control.core.pulse_moves import PulseMoves

ROOT = Path(__file__).resolve().parents[1]
CS = CONTROLLER_SPEC.defaults()
MODEL = NominalModel.from_params(CS)
PERIOD = 1.0 / CS["loop_rate_hz"]
P_MAX = MODEL.pressure_max_kpa
K = MODEL.coupling_stiffness_nm_per_rad
FL = MODEL.friction(P_MAX)
X_NOM = (FL.valve_static_nm - FL.valve_coulomb_nm) / K      # the nominal level's excess, rad (2.29e-3)


@pytest.fixture(autouse=True)
def _counted(own_table_builds):
    """This module counts the tables its PulseMoves build (``builds`` / ``runs``): none read from the session's
    shared directory (conftest)."""


@pytest.fixture(scope="module")
def fine() -> FinePositioner:
    pc = PositionController(CS)
    return pc.law.fine


#: the module's keyed grid: the Δp points the tests ask at and around (a short grid keeps prepare() cheap: ~6 tables)
TEST_DP_GRID = (0.5, 0.9, 1.0)


@pytest.fixture(scope="module")
def pm(fine) -> PulseMoves:
    return PulseMoves.for_positioner(fine, CS, dp_grid=TEST_DP_GRID, angle_grid=(0.5,))


def plant_doublet(d: int, excess: float, overdrive: float, aim: float, rise: float, p: float = P_MAX) -> float:
    """The valve's move (rad toward ``d``) on the bare nominal plant at Δp ``p`` for the doublet the default stage
    commands (preload ``rise`` below the apex, ``overdrive`` past a level ``excess`` above the Coulomb twist, aim
    ``aim``): ``benchmarks/pulse_moves_check.py``'s replay, the one reference the model is validated against."""
    from conftest import load_benchmark
    return load_benchmark("pulse_moves_check").plant_doublet(d, excess, overdrive, aim, rise, p)


def test_no_move_below_the_level(pm):
    """(1) An apex at or below the static level moves nothing: 0 by the API, and the simulation agrees (an
    apex 1e-5 rad short of the level leaves the valve where it was, 1e-5 beyond it breaks it loose) -- for
    aims short of where the observe servo's rebound from the retreat's trough reaches the level by itself
    (there the model answers NaN, as an unpredicted move)."""
    th0 = 0.5 * MODEL.stroke_rad
    for d in (1, -1):
        x = np.linspace(0.6, 1.5, 5) * X_NOM
        aim = 5e-4
        assert np.all(pm.move(d, P_MAX, x, 0.0, aim_rad=aim) == 0.0)
        assert np.all(pm.move(d, P_MAX, x, -1e-4, aim_rad=aim) == 0.0)
        rise = pm.rise(d, P_MAX)
        level = (MODEL.load_torque(th0, P_MAX) + d * (FL.valve_coulomb_nm + K * x)) / K
        for od, moved in ((-1e-5, False), (1e-5, True)):
            end = pm._simulate(d, P_MAX, pm.kick, th0, preload=level + d * (od - rise), excess=x,
                               aim=np.full(x.shape, aim))
            assert np.all((np.abs(end - th0) > 1e-6) == moved), (d, od, end - th0)
        # a level near the Coulomb equilibrium: the servo's rebound breaks the valve loose whatever the apex
        assert np.isnan(pm.move(d, P_MAX, 0.1 * X_NOM, -1e-5, aim_rad=aim))
        end = pm._simulate(d, P_MAX, pm.kick, th0, preload=level[:1] * 0 + (MODEL.load_torque(th0, P_MAX) + d * (
            FL.valve_coulomb_nm + 0.1 * K * X_NOM)) / K + d * (-1e-5 - rise), excess=np.array([0.1 * X_NOM]),
                           aim=np.array([aim]))
        assert abs(end[0] - th0) > 1e-5


def test_smallest_move_grows_with_the_excess(pm):
    """(2) §75.2's physics: a valve broken loose at ~0 overdrive jumps about twice its excess, so the smallest
    move a doublet can make grows with how far the stop's level lies above the Coulomb equilibrium -- from
    half the nominal excess up (below it the observe servo's overshoot keeps the valve going), and at the
    nominal level 0.8-0.95e-3 rad (0.5 x the jump 2 x 2.29e-3)."""
    for d in (1, -1):
        tab = pm.table(d, P_MAX)
        smallest = tab["moves"][:, :, 0].min(axis=1)
        sel = tab["excess"] >= 0.5 * X_NOM
        assert np.all(np.diff(smallest[sel]) > 0.0), smallest
        at_nom = np.interp(X_NOM, tab["excess"], smallest)
        assert 0.6e-3 < at_nom < 1.2e-3, at_nom
        assert smallest[-1] > 3.0 * at_nom


#: (excess / nominal excess, overdrive rad, aim rad) validated against the plant, away from the servo's
#: second-breakaway aims (docs §80: there the model answers NaN)
POINTS = ((0.5, 2e-5, 0.0), (0.5, 3e-4, 6e-4), (1.0, 1e-4, 0.0), (1.0, 8e-4, 1e-3), (1.7, 2e-5, 6e-4),
          (1.7, 3e-4, 0.0))


@pytest.mark.parametrize("d, dp_fraction", [(1, 1.0), (-1, 1.0), (1, 0.5)])
def test_agrees_with_the_bare_plant(pm, fine, d, dp_fraction):
    """(3) The moves within 10 % or 1e-4 rad of the bare nominal plant's for the same doublet, at max Δp both ways
    and at half Δp (measured: 300 random points at max Δp 100 % within, p95 7e-5, max 3.4e-4 rad, docs §80)."""
    p = dp_fraction * P_MAX
    fl = MODEL.friction(p)
    x_nom = (fl.valve_static_nm - fl.valve_coulomb_nm) / K
    rise = pm.rise(d, p)
    assert 0.2e-3 < rise < 0.4e-3
    for xf, od, aim in POINTS:
        x = xf * x_nom
        aim = aim * dp_fraction                                   # the same share of the (smaller) jump
        model = float(pm.move(d, p, x, od, aim_rad=aim))
        plant = plant_doublet(d, x, od, aim, rise, p)
        assert math.isfinite(model)
        assert abs(model - plant) <= max(0.1 * plant, 1e-4), (d, dp_fraction, xf, od, aim, model, plant)


def test_rise_agrees_with_the_bare_plant(pm, fine):
    """(3) The rise: the doublet on a valve held stuck (a level of 0.15 rad excess) peaks ``rise`` above the
    preload, within 2 %."""
    from fuel_valve_plant.physics import kernel as KN
    from fuel_valve_plant.physics.params import PLANT_SPEC
    from fuel_valve_plant.physics.plant import Plant

    ps = PLANT_SPEC.defaults()
    n, kt, cfg = MODEL.gear_ratio, MODEL.torque_constant_nm_per_a, fine.cfg
    theta = 0.5 * MODEL.stroke_rad
    load = MODEL.load_torque(theta, P_MAX)
    for d in (1, -1):
        pl = Plant(ps.replace({"friction.valve.static_per_dp_nm": 80.0}))
        pl.hold_at(theta)
        phi = (load + d * FL.valve_static_nm) / K
        hold = (K * phi / n + d * FL.motor_coulomb_nm) / kt
        pl.S[KN.S_THM] = (theta + phi) * n
        pl.S[KN.S_IQ] = hold
        pl.S[KN.S_XQ] = ps["motor.resistance_ohm"] * hold
        apex = 0.0
        for iq in [hold + d * cfg.kick_current_a] + [hold - d * cfg.peak_current_a] * cfg.retreat_full_periods \
                + [hold - d * 0.5 * cfg.peak_current_a]:
            pl.set_command(min(max(iq, -cfg.peak_current_a), cfg.peak_current_a), True)
            for _ in range(pl.steps_for(PERIOD)):
                pl.step(1)
                t = pl.truth()
                # the coupling torque over K (twist + damping share), as the model's rise
                tk = K * (t.motor_angle / n - t.valve_angle) + MODEL.coupling_damping_nms * (
                    t.motor_velocity / n - t.valve_velocity)
                apex = max(apex, d * (tk / K - phi))
        assert abs(pm.rise(d, P_MAX) - apex) <= 0.02 * apex, (d, pm.rise(d, P_MAX), apex)


def test_shapes_cache_and_outside(pm, fine):
    """Broadcasting, NaN outside the table, one table per (direction, Δp, kick), the drive's bandwidth as the
    plant's (the model's current loop is the drive's tuning)."""
    from fuel_valve_plant.physics.params import PLANT_SPEC

    assert CS["drive.current_loop_bandwidth_hz"] == PLANT_SPEC.defaults()["drive.current_loop_bandwidth_hz"]
    out = pm.move(1, P_MAX, np.linspace(1e-3, 3e-3, 4)[:, None], np.array([1e-5, 1e-4, 1e-3]))
    assert out.shape == (4, 3) and np.all(np.isfinite(out)) and np.all(out > 0.0)
    assert np.isnan(pm.move(1, P_MAX, 1.0, 1e-4))                 # excess beyond the table
    assert np.isnan(pm.move(1, P_MAX, X_NOM, 1.0))                # overdrive beyond one jump
    assert np.isnan(pm.move(1, P_MAX, X_NOM, 1e-4, aim_rad=-1e-3))
    # the cache's count on a private instance: the module's ``pm`` shares its tables with every PulseMoves of its
    # signature in the process (h33r), and another module's stage (test_apex_policy's 8 A kicks) may have built one
    own = PulseMoves.for_positioner(fine, CS, dp_grid=TEST_DP_GRID, angle_grid=(0.5,), share=False)
    own.move(1, P_MAX, X_NOM, 1e-4)
    own.move(-1, P_MAX, X_NOM, 1e-4)
    builds = own.builds
    own.move(1, P_MAX, X_NOM, 1e-4)
    own.move(-1, P_MAX, X_NOM, 1e-4)
    assert own.builds == builds                                  # cached
    own.move(1, P_MAX, X_NOM, 1e-4, kick_current_a=8.0)
    assert own.builds == builds + 1 and own.rise(1, P_MAX, 8.0) > own.rise(1, P_MAX)


def _imports(path: str) -> set:
    names = set()
    for node in ast.walk(ast.parse((ROOT / path).read_text())):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            names.add(("." * node.level) + (node.module or ""))
    return names


def test_module_is_plant_free_and_ros_free():
    """(4) core/pulse_moves.py imports neither the plant nor ROS nor the tools (test_architecture checks the
    whole core; this pins the new module) -- nor does its doublet kernel core/drivetrain_step.py (task h41k)."""
    names = _imports("fuel_valve_control/core/pulse_moves.py")
    # (task h36b: the disk cache and the background build add the standard library's file, hash and process modules)
    stdlib = {"hashlib", "os", "tempfile", "threading", "pathlib", "pickle", "subprocess", "sys", "signal", "fcntl",
              "shutil"}
    assert names <= {"__future__", "math", "collections", "time", "numpy", ".model", ".params",
                     ".drivetrain_step"} | stdlib, names
    # the kernel: numpy and the standard library's source tools (its float backend is its own source compiled again)
    assert _imports("fuel_valve_control/core/drivetrain_step.py") <= {
        "__future__", "ast", "copy", "inspect", "math", "types", "typing", "numpy"}


def test_prepare_leaves_nothing_to_build(pm, fine):
    """(§80.9) After ``prepare()`` every table the keyed grid can need is built: ``prepared``, nothing ``pending``,
    and no move / rise at any Δp, angle or shape simulates anything (the ROS node's 1 kHz callback never builds)."""
    spent = pm.prepare()
    assert spent >= 0.0 and pm.prepared and pm.pending() == []
    assert pm.pending(kicks=[8.5]) != []                          # an unprepared kick would build
    builds, runs = pm.builds, pm.runs
    rng = np.random.default_rng(2)
    for _ in range(20):
        d = int(rng.choice([1, -1]))
        p = float(rng.uniform(-0.1, 1.2)) * P_MAX                 # clamped to the grid's range
        th = float(rng.uniform(0.0, 1.0)) * MODEL.stroke_rad
        pm.rise(d, p, valve_angle_rad=th)
        pm.move(d, p, rng.uniform(0, 3e-3, (7, 5)), rng.uniform(-1e-4, 2e-3, (7, 5)), aim_rad=3e-4, valve_angle_rad=th)
    assert (pm.builds, pm.runs) == (builds, runs)
    # a second model of the same positioner (a campaign's next run, h33p's policy per engagement) shares the tables
    twin = PulseMoves.for_positioner(fine, CS, dp_grid=TEST_DP_GRID, angle_grid=(0.5,))
    assert twin.prepared
    twin.move(1, 0.93 * P_MAX, 2e-3, 1e-4, aim_rad=2e-4)
    assert twin.runs == 0
    alone = PulseMoves.for_positioner(fine, CS, share=False, dp_grid=TEST_DP_GRID, angle_grid=(0.5,))
    assert len(alone.pending()) == 6                                # 2 directions x 3 Δp (one kick, one angle)
    alone.prepare(max_s=0.0)                        # a budget: one table (+ its rise) at a time, max Δp first
    assert alone.builds == 1 and len(alone.pending()) == 5 and (1, P_MAX) == next(iter(alone._tables))[:2]
    # a fresh model with the same grid: prepare() builds exactly direction x Δp x angle x kick tables
    fresh = PulseMoves(MODEL, PERIOD, kick_current_a=pm.kick, peak_current_a=pm.cap, retreat_full_periods=1,
                       servo_kp=pm.kp, servo_kd=pm.kd, servo_ki=pm.ki, dp_grid=(1.0,), angle_grid=(0.2, 0.8))
    assert len(fresh.pending()) == 4 and not fresh.prepared
    with pytest.raises(ValueError):
        PulseMoves(MODEL, PERIOD, kick_current_a=4.0, peak_current_a=30.0, retreat_full_periods=1, servo_kp=1.0,
                   servo_kd=0.0, servo_ki=0.0, exact=True).prepare()


def test_keyed_grid_within_its_measured_bound(pm, fine):
    """(§80.9) The keyed model (Δp between grid points 0.9 and 1.0 x max, interpolated on the friction-normalised
    grids) against the exact table at that Δp: 500 random points of the policy's domain (excess 0.3-1.6 x nominal,
    overdrive log 1e-3-1 jump, aim 0-1 jump) within max(10 %, 1e-4 rad) for >= 97 % of those both answer, and the
    NaN answers differ on <= 8 % (measured on the default grid above 0.4 x max Δp: 99.5 %, p95 3.9e-5 rad, 5 % of
    the exact answers lost to NaN)."""
    exact = PulseMoves.for_positioner(fine, CS, exact=True, coarse_aims=False)     # h33m's table, every aim simulated
    rng = np.random.default_rng(4)
    p = 0.95 * P_MAX
    fl = MODEL.friction(p)
    xn = (fl.valve_static_nm - fl.valve_coulomb_nm) / K
    j = 2.0 * xn
    x = rng.uniform(0.3, 1.6, 500) * xn
    od = np.exp(rng.uniform(math.log(1e-3 * j), math.log(j), 500))
    aim = rng.uniform(0.0, 1.0, 500) * j
    a = pm.move(1, p, x, od, aim_rad=aim)
    b = exact.move(1, p, x, od, aim_rad=aim)
    both = np.isfinite(a) & np.isfinite(b)
    assert np.mean(np.isfinite(a) != np.isfinite(b)) <= 0.08
    e = np.abs(a - b)[both]
    assert np.mean(e <= np.maximum(0.1 * np.abs(b[both]), 1e-4)) >= 0.97, np.percentile(e, [50, 95, 100])
    assert abs(pm.rise(1, p) - exact.rise(1, p)) < 1e-6

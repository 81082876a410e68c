"""Plant configuration loading and validation: clear errors naming the key and its range."""
import pytest

from fuel_valve_control.common.paramspec import ConfigError, parse_overrides, read_ros_param_file
from fuel_valve_plant.physics.plant import Plant
from fuel_valve_plant.physics.params import PLANT_SPEC, PLANT_NODE_SPEC, default_config_dir, load_plant_params


def test_shipped_plant_yaml_holds_the_spec_defaults():
    ps = load_plant_params()
    defaults = PLANT_SPEC.defaults()
    assert ps.as_dict() == defaults.as_dict()
    # the file is the node's: the physics keys plus the node-only ones
    assert set(read_ros_param_file(default_config_dir() / "plant.yaml")) == set(PLANT_NODE_SPEC.params)
    assert ps["gearbox.ratio"] == 48.019 and ps["coupling.stiffness_nm_per_rad"] == 480.0


def _write(tmp_path, body):
    path = tmp_path / "plant.yaml"
    path.write_text("/**:\n  ros__parameters:\n" + body)
    return path


@pytest.mark.parametrize("body, fragments", [
    ("    motor:\n      resistance_ohm: -1.0\n", ["motor.resistance_ohm", "-1.0", "out of range", "ohm"]),
    ("    pressure_differential_kpa: 7000\n", ["pressure_differential_kpa", "6206"]),
    ("    friction_scale: 0\n", ["friction_scale", "0 < value"]),
    ("    coupling:\n      stifness_nm_per_rad: 48\n", ["unknown parameter", "coupling.stifness_nm_per_rad"]),
    ("    friction:\n      model: coulomb\n", ["friction.model", "stick_slip", "lugre"]),
    ("    motor:\n      pole_pairs: 2.5\n", ["motor.pole_pairs", "not an integer"]),
    ("    lockstep: maybe\n", ["lockstep", "boolean"]),
    ("    supply_voltage_v: .nan\n", ["supply_voltage_v", "not finite"]),
    ("    gearbox:\n      ratio: fast\n", ["gearbox.ratio", "not a number"]),
])
def test_bad_values_name_key_and_range(tmp_path, body, fragments):
    with pytest.raises(ConfigError) as err:
        load_plant_params(_write(tmp_path, body))
    for fragment in fragments:
        assert fragment in str(err.value)


def test_static_below_coulomb_is_rejected(tmp_path):
    path = _write(tmp_path, "    friction:\n      valve:\n        static_nm: 0.1\n")
    with pytest.raises(ConfigError, match="static_nm must be >="):
        load_plant_params(path)


def test_malformed_files(tmp_path):
    missing = tmp_path / "nope.yaml"
    with pytest.raises(ConfigError, match="cannot read"):
        load_plant_params(missing)
    bad = tmp_path / "bad.yaml"
    bad.write_text("plant: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_plant_params(bad)
    flat = tmp_path / "flat.yaml"
    flat.write_text("friction_scale: 2\n")
    with pytest.raises(ConfigError, match="ros__parameters"):
        load_plant_params(flat)


def test_partial_file_keeps_other_defaults(tmp_path):
    ps = load_plant_params(_write(tmp_path, "    coupling:\n      stiffness_nm_per_rad: 48.0\n"))
    assert ps["coupling.stiffness_nm_per_rad"] == 48.0
    assert ps["valve.inertia_kgm2"] == 1.76e-3


def test_runtime_changes_are_validated_and_atomic():
    plant = Plant(load_plant_params())
    plant.set_params({"pressure_differential_kpa": 1000.0})
    assert plant.params["pressure_differential_kpa"] == 1000.0
    with pytest.raises(ConfigError):
        plant.set_params({"pressure_differential_kpa": 500.0, "friction_scale": -1})
    assert plant.params["pressure_differential_kpa"] == 1000.0     # nothing applied
    with pytest.raises(ValueError, match="cannot change at run time"):
        plant.set_params({"physics_rate_hz": 10000.0})


def test_override_parsing():
    out = parse_overrides(["plant.friction_scale=2", "controller.mode=pi", "plant.friction.model=lugre"],
                          ["plant", "controller"])
    assert out == {"plant": {"friction_scale": 2, "friction.model": "lugre"}, "controller": {"mode": "pi"}}
    with pytest.raises(ConfigError, match="section must be one of"):
        parse_overrides(["valve.x=1"], ["plant", "controller"])
    with pytest.raises(ConfigError, match="section.key=value"):
        parse_overrides(["plant.friction_scale"], ["plant", "controller"])

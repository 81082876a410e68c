"""The layer rules of the package, checked (issue 9):

* the controller core (``fuel_valve_control.core``) and the shared pieces
  (``fuel_valve_control.common``) import neither ROS nor the simulated plant: the controller
  must install and run on real hardware without ``fuel_valve_plant``;
* the controller node imports no part of the plant either;
* the plant imports only ``fuel_valve_control.common`` (the interface contract, parameter
  machinery, friction law), never controller internals;
* the controller's own nominal model agrees with the data-sheet values the plant is built from.
"""
from __future__ import annotations

import ast
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CONTROL = ROOT / "fuel_valve_control"
PLANT = ROOT / "fuel_valve_plant"


def _imports(path: Path) -> set[str]:
    """Absolute module names a source file imports (anywhere in it, lazy imports included)."""
    tree = ast.parse(path.read_text())
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            out.add(name)
            out.update(f"{name}.{alias.name}" for alias in node.names)
    return out


def _sources(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*.py") if "__pycache__" not in p.parts)


@pytest.mark.parametrize("layer", ["core", "common"])
def test_controller_core_imports_no_plant_and_no_ros(layer):
    offenders = {}
    for path in _sources(CONTROL / layer):
        bad = {m for m in _imports(path)
               if m.split(".")[0] in ("fuel_valve_plant", "rclpy")
               or m.startswith(("fuel_valve_control.ros", "fuel_valve_control.tools"))}
        if bad:
            offenders[str(path.relative_to(ROOT))] = sorted(bad)
    assert not offenders, f"the {layer} layer must stay ROS-free and plant-free: {offenders}"


def test_plant_imports_only_the_shared_interface_of_the_controller_package():
    """Physics: only ``fuel_valve_control.common``.  The plant node may also use the ROS-layer
    helpers (QoS, messages, loop I/O), but never the controller core, its nodes or the tools."""
    offenders = {}
    for path in _sources(PLANT):
        mods = {m for m in _imports(path) if m.startswith("fuel_valve_control")}
        if "physics" in path.parts:
            bad = {m for m in mods if not m.startswith("fuel_valve_control.common")}
            bad |= {m for m in _imports(path) if m.split(".")[0] == "rclpy"}
        else:
            bad = {m for m in mods if m.startswith(("fuel_valve_control.core", "fuel_valve_control.tools"))
                   or (m.count(".") >= 2 and m.split(".")[2].endswith("_node"))}     # another node module
        if bad:
            offenders[str(path.relative_to(ROOT))] = sorted(bad)
    assert not offenders, f"the plant may import only the shared interface: {offenders}"


BLOCKER = textwrap.dedent("""
    import importlib, pkgutil, sys
    BLOCKED = {blocked!r}
    class Block:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"{{name}} is not installed on this machine (blocked by the test)")
    sys.meta_path.insert(0, Block())
""")


def _run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)


def test_controller_core_runs_with_the_plant_and_ros_uninstalled():
    """Import every core module and run a driver for 50 periods with ``fuel_valve_plant`` and
    ``rclpy`` unimportable: the situation of a controller deployed on the real actuator."""
    code = BLOCKER.format(blocked=("fuel_valve_plant", "rclpy")) + textwrap.dedent("""
        import fuel_valve_control.core as core, fuel_valve_control.common as common
        for pkg in (core, common):
            for info in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
                importlib.import_module(info.name)
        from fuel_valve_control.core.driver import ValveDriver
        from fuel_valve_control.core.params import load_controller_params
        d = ValveDriver(load_controller_params())
        for k in range(50):
            t = k * d.period
            d.demand_percent(t, 20.0)
            d.resolver(t, 0.0, 0.0)
            out = d.step(t)
        assert out.enable and out.state == "running", out
        assert not any(m.split(".")[0] in BLOCKED for m in sys.modules), "a blocked module was imported"
        print("ok")
    """)
    proc = _run(code)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr


def test_controller_node_module_imports_without_the_plant():
    code = BLOCKER.format(blocked=("fuel_valve_plant",)) + textwrap.dedent("""
        import fuel_valve_control.ros.controller_node as n
        assert callable(n.main)
        print("ok")
    """)
    proc = _run(code)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr


def test_contract_imports_without_rclpy():
    code = BLOCKER.format(blocked=("rclpy",)) + textwrap.dedent("""
        from fuel_valve_control.common import contract
        assert contract.TOPIC_TYPES[contract.RESOLVER] == "sensor_msgs/msg/JointState"
        print("ok")
    """)
    proc = _run(code)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr


def test_nominal_model_agrees_with_the_plant_data_sheet_values():
    """The controller's own ``model.*`` defaults are the data-sheet values the simulated plant
    is built from (two parameter sets, one truth: a drift would silently mis-design gains)."""
    from fuel_valve_control.core.params import CONTROLLER_SPEC
    from fuel_valve_plant.physics.params import PLANT_SPEC
    c, p = CONTROLLER_SPEC.defaults(), PLANT_SPEC.defaults()
    pairs = {
        "motor_inertia_kgm2": "motor.inertia_kgm2", "motor_viscous_nms": "motor.viscous_nms",
        "gear_ratio": "gearbox.ratio", "coupling_stiffness_nm_per_rad": "coupling.stiffness_nm_per_rad",
        "coupling_damping_nms": "coupling.damping_nms", "valve_inertia_kgm2": "valve.inertia_kgm2",
        "valve_viscous_nms": "valve.viscous_nms", "spring_preload_nm": "spring.preload_nm",
        "spring_rate_nm_per_rad": "spring.rate_nm_per_rad", "flow_torque_max_nm": "flow.torque_max_nm",
        "stroke_rad": "valve.stroke_rad", "pressure_max_kpa": "friction.pressure_max_kpa",
        "motor_coulomb_nm": "friction.motor.coulomb_nm", "motor_static_nm": "friction.motor.static_nm",
        "valve_coulomb_nm": "friction.valve.coulomb_nm",
        "valve_coulomb_per_dp_nm": "friction.valve.coulomb_per_dp_nm",
        "valve_static_nm": "friction.valve.static_nm", "valve_static_per_dp_nm": "friction.valve.static_per_dp_nm",
        "motor_pole_pairs": "motor.pole_pairs", "motor_resistance_ohm": "motor.resistance_ohm",
        "motor_lq_h": "motor.lq_h",
    }
    model_keys = {k.split(".", 1)[1] for k in c if k.startswith("model.")}
    assert model_keys == set(pairs) | {"torque_constant_nm_per_a"}, "a model.* entry has no data-sheet pair here"
    for mine, theirs in pairs.items():
        assert c[f"model.{mine}"] == pytest.approx(p[theirs], rel=1e-12), mine
    kt = 1.5 * p["motor.pole_pairs"] * p["motor.flux_linkage_wb"]
    assert c["model.torque_constant_nm_per_a"] == pytest.approx(kt, rel=1e-12)

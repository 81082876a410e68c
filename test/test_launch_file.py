"""Structure of ``launch/fuel_valve.launch.py`` (SPEC §4) without ROS 2 ``launch``.

``launch``, ``launch_ros`` and ``ament_index_python``'s package lookup are not installable from
PyPI here, so this test imports the launch file with small *fake* modules put into
``sys.modules``.  The fakes accept only the keyword arguments that the real Jazzy classes accept
(``launch.LaunchDescription``, ``launch.actions.DeclareLaunchArgument`` / ``OpaqueFunction``,
``launch.substitutions.LaunchConfiguration``, ``launch_ros.actions.Node``) and record what is
constructed; ``LaunchConfiguration.perform`` reads a context's launch configurations the way
the real one does.  The test then calls ``generate_launch_description()``, evaluates the
``OpaqueFunction`` with a fake context for several argument sets, and checks the declared
arguments, executables, namespace, parameter files (they must exist in the source tree's
``config/``) and parameter overrides (each name must be a parameter the node declares: its
parameter schema, imported from the code that declares it, is the list).

What this verifies is the *structure* the launch file hands to launch / launch_ros; it does not
verify launch semantics (substitution, process start-up, parameter-file loading by rcl): that
needs a real ROS 2 install (``ros2 launch fuel_valve fuel_valve.launch.py``).
"""
from __future__ import annotations

import ast
import importlib.util
import py_compile
import sys
import types
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAUNCH_FILE = ROOT / "launch" / "fuel_valve.launch.py"
CONFIG_FILES = {"plant": "plant.yaml", "controller": "controller.yaml", "demand": "demand.yaml"}
ARGUMENTS = {"namespace": "fuel_valve", "valves": "", "mode": "", "lockstep": "false", "record": "false",
             "autostart": "true", "bag": "fuel_valve_bag", "demand_profile": "", "learned_state_file": ""}
# rclpy declares use_sim_time on every node
ROS_PARAMS = {"use_sim_time"}
# keyword arguments of the real launch_ros Node / launch ExecuteProcess that the file may use
NODE_KWARGS = {"executable", "package", "name", "namespace", "exec_name", "parameters", "remappings",
               "ros_arguments", "arguments", "output", "emulate_tty", "respawn", "respawn_delay",
               "condition", "additional_env", "cwd", "sigterm_timeout", "sigkill_timeout"}


def _fake_modules(share_dir: Path) -> dict[str, types.ModuleType]:
    """Minimal stand-ins that record construction (structure only, no launch semantics)."""
    launch = types.ModuleType("launch")
    actions = types.ModuleType("launch.actions")
    substitutions = types.ModuleType("launch.substitutions")
    launch_ros = types.ModuleType("launch_ros")
    ros_actions = types.ModuleType("launch_ros.actions")
    ament = types.ModuleType("ament_index_python")
    ament_packages = types.ModuleType("ament_index_python.packages")

    class LaunchDescription:
        def __init__(self, initial_entities=None, *, deprecated_reason=None):
            self.entities = list(initial_entities or [])

    class DeclareLaunchArgument:
        def __init__(self, name, *, default_value=None, description=None, choices=None):
            assert isinstance(name, str)
            self.name, self.default_value, self.description, self.choices = name, default_value, description, choices

    class OpaqueFunction:
        def __init__(self, *, function, args=None, kwargs=None):
            assert callable(function)
            self.function, self.args, self.kwargs = function, list(args or []), dict(kwargs or {})

        def execute(self, context):
            return self.function(context, *self.args, **self.kwargs)

    class LaunchConfiguration:
        def __init__(self, variable_name, *, default=None):
            self.variable_name, self.default = variable_name, default

        def perform(self, context):
            if self.variable_name in context.launch_configurations:
                return context.launch_configurations[self.variable_name]
            if self.default is not None:
                return self.default
            raise LookupError(f"launch configuration '{self.variable_name}' does not exist")

    class Node:
        def __init__(self, *, executable, **kwargs):
            unknown = set(kwargs) - NODE_KWARGS
            assert not unknown, f"Node() got unexpected keyword arguments {unknown}"
            params = kwargs.get("parameters") or []
            assert isinstance(params, (list, tuple)), "parameters must be a list"
            for entry in params:
                if isinstance(entry, dict):
                    for key, value in entry.items():   # types normalize_parameter_dict accepts
                        assert isinstance(key, str) and isinstance(value, (str, bool, int, float)), (key, value)
                else:
                    assert isinstance(entry, (str, Path)), entry
            self.executable, self.kwargs = executable, kwargs

    def get_package_share_directory(package_name):
        assert package_name == "fuel_valve"
        return str(share_dir)

    launch.LaunchDescription = LaunchDescription
    launch.actions, launch.substitutions = actions, substitutions
    actions.DeclareLaunchArgument, actions.OpaqueFunction = DeclareLaunchArgument, OpaqueFunction
    substitutions.LaunchConfiguration = LaunchConfiguration
    launch_ros.actions = ros_actions
    ros_actions.Node = Node
    ament.packages = ament_packages
    ament_packages.get_package_share_directory = get_package_share_directory
    return {"launch": launch, "launch.actions": actions, "launch.substitutions": substitutions,
            "launch_ros": launch_ros, "launch_ros.actions": ros_actions,
            "ament_index_python": ament, "ament_index_python.packages": ament_packages}


@pytest.fixture
def description(monkeypatch):
    for name, module in _fake_modules(ROOT).items():
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location("fuel_valve_launch_under_test", LAUNCH_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.generate_launch_description()


def _all_nodes(description, **overrides) -> list:
    """Run the OpaqueFunction(s) with the declared defaults + overrides; every node."""
    declared = {e.name: e.default_value for e in description.entities if type(e).__name__ == "DeclareLaunchArgument"}
    context = types.SimpleNamespace(launch_configurations={**declared, **overrides})
    nodes = [e for e in description.entities if type(e).__name__ == "Node"]
    for entity in description.entities:
        if type(entity).__name__ == "OpaqueFunction":
            nodes += entity.execute(context) or []
    return nodes


def _evaluate(description, **overrides) -> dict:
    """:func:`_all_nodes` of a one-valve launch; {executable: node}."""
    nodes = _all_nodes(description, **overrides)
    by_exe = {n.executable: n for n in nodes}
    assert len(by_exe) == len(nodes), "an executable is started twice"
    return by_exe


def _overrides(node) -> dict:
    merged = {}
    for entry in node.kwargs.get("parameters") or []:
        if isinstance(entry, dict):
            merged.update(entry)
    return merged


def _files(node) -> list[Path]:
    return [Path(e) for e in node.kwargs.get("parameters") or [] if not isinstance(e, dict)]


def _declared_params(executable: str) -> set[str]:
    """What the node declares: the names of its parameter schema (the node declares exactly
    that schema, see ``ros.interface.declare_spec``)."""
    from fuel_valve_control.core.params import CONTROLLER_NODE_SPEC
    from fuel_valve_control.tools.profiles import DEMAND_NODE_SPEC
    from fuel_valve_control.tools.recorder import RECORDER_SPEC
    from fuel_valve_plant.physics.params import PLANT_NODE_SPEC
    schemas = {"plant": PLANT_NODE_SPEC, "controller": CONTROLLER_NODE_SPEC, "demand": DEMAND_NODE_SPEC,
               "recorder": RECORDER_SPEC}
    return set(schemas[executable].params) | ROS_PARAMS


def test_launch_file_compiles_and_imports_only_launch_api(tmp_path):
    py_compile.compile(str(LAUNCH_FILE), cfile=str(tmp_path / "launch.pyc"), doraise=True)
    tree = ast.parse(LAUNCH_FILE.read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            imported.add(node.module.split(".")[0])
    assert imported <= {"os", "launch", "launch_ros", "ament_index_python"}, imported
    assert any(isinstance(n, ast.FunctionDef) and n.name == "generate_launch_description" for n in tree.body)


def test_declared_arguments_and_defaults(description):
    declared = {e.name: e for e in description.entities if type(e).__name__ == "DeclareLaunchArgument"}
    assert {k: v.default_value for k, v in declared.items()} == ARGUMENTS
    assert all(v.description for v in declared.values())


def test_default_launch_starts_three_nodes_in_namespace_with_config_files(description):
    nodes = _evaluate(description)
    assert set(nodes) == {"plant", "controller", "demand"}
    for exe, node in nodes.items():
        assert node.kwargs["package"] == "fuel_valve"
        assert node.kwargs["namespace"] == "fuel_valve"
        assert node.kwargs.get("name", exe) == exe      # keeps the node name the code uses (~/trip ...)
        files = _files(node)
        assert files == [ROOT / "config" / CONFIG_FILES[exe]], files
        assert files[0].is_file()
        over = _overrides(node)
        assert over.get("lockstep") is False
        assert "use_sim_time" not in over                 # real time: ROS default (false)
    assert "mode" not in _overrides(nodes["controller"])  # config/controller.yaml decides
    assert "profile" not in _overrides(nodes["demand"])


@pytest.mark.parametrize("record", ["false", "true"])
def test_lockstep_settings(description, record):
    # the launch file only imports launch API, so it writes the clock wiring itself: it must be
    # the wiring fuel_valve_demo and the tests get from the launcher
    from fuel_valve_control.tools.launcher import clock_participants, lockstep_parameters, recording_parameters
    nodes = _evaluate(description, lockstep="true", record=record)
    plant = _overrides(nodes["plant"])
    assert plant["lockstep"] is True and plant["use_sim_time"] is False  # the plant publishes /clock
    assert plant["lockstep_participants"] == clock_participants(record == "true") == (3 if record == "true" else 2)
    participants = clock_participants(record == "true")
    for exe, node in nodes.items():
        over = _overrides(node)
        assert {k: over[k] for k in lockstep_parameters(exe, True, participants)} == \
            lockstep_parameters(exe, True, participants), exe
        # and the recording wiring: the publishers hold until the recorder matched
        assert over.get("recorded_topics") == recording_parameters(exe, record == "true").get("recorded_topics"), exe
    for exe in ("controller", "demand"):
        assert _overrides(nodes[exe])["lockstep"] is True
        assert _overrides(nodes[exe])["use_sim_time"] is True
    if record == "true":
        assert _overrides(nodes["recorder"])["use_sim_time"] is True
    else:
        assert "recorder" not in nodes


@pytest.mark.parametrize("namespace", ["fuel_valve", "/valve2", "plant_a/valve_1"])
def test_each_valve_has_its_own_clock(description, namespace):
    # the remapping the launcher gives every node of a lockstep run (the same ROS argument)
    from fuel_valve_control.tools.launcher import clock_remap
    for exe, node in _evaluate(description, lockstep="true", record="true", namespace=namespace).items():
        remaps = [f"{a}:={b}" for a, b in node.kwargs.get("remappings") or []]
        assert ["-r", *remaps] == clock_remap(namespace, True), exe
    assert clock_remap("/valve2", True)[1] == "/clock:=/valve2/clock"
    for node in _evaluate(description, namespace=namespace).values():     # real time: no clock at all
        assert not node.kwargs.get("remappings") and clock_remap(namespace, False) == []


def test_record_starts_recorder_with_bag_output(description):
    nodes = _evaluate(description, record="True", bag="/tmp/run7")
    assert set(nodes) == {"plant", "controller", "demand", "recorder"}
    rec = nodes["recorder"]
    assert rec.kwargs["namespace"] == "fuel_valve"
    assert _overrides(rec)["output"] == "/tmp/run7"
    assert _overrides(rec).get("use_sim_time", False) is False
    assert _evaluate(description, record="1")["recorder"].kwargs["package"] == "fuel_valve"


def test_mode_profile_and_namespace_overrides(description):
    nodes = _evaluate(description, mode="pi", demand_profile="step", namespace="valve2")
    assert _overrides(nodes["controller"])["mode"] == "pi"
    assert _overrides(nodes["demand"])["profile"] == "step"
    assert {n.kwargs["namespace"] for n in nodes.values()} == {"valve2"}
    # overrides come after the YAML file so they win
    params = nodes["controller"].kwargs["parameters"]
    assert isinstance(params[-1], dict) and not isinstance(params[0], dict)


def test_every_override_is_a_parameter_the_node_declares(description):
    for args in ({}, {"lockstep": "true", "record": "true", "mode": "pi", "demand_profile": "sine",
                      "autostart": "false"}):
        for exe, node in _evaluate(description, **args).items():
            unknown = set(_overrides(node)) - _declared_params(exe)
            assert not unknown, f"{exe}: launch sets undeclared parameters {unknown}"


def test_bad_boolean_is_rejected(description):
    with pytest.raises(ValueError, match="lockstep"):
        _evaluate(description, lockstep="maybe")


@pytest.mark.parametrize("text, value", [("true", True), ("false", False), ("0", False)])
def test_autostart_argument_reaches_the_controller_only(description, text, value):
    nodes = _evaluate(description, autostart=text)
    assert _overrides(nodes["controller"])["autostart"] is value
    assert all("autostart" not in _overrides(nodes[exe]) for exe in ("plant", "demand"))
    with pytest.raises(ValueError, match="autostart"):
        _evaluate(description, autostart="later")


@pytest.mark.parametrize("lockstep", ["false", "true"])
def test_valves_start_one_complete_stack_per_namespace_each_on_its_own_clock(description, lockstep):
    from fuel_valve_control.tools.launcher import clock_participants, clock_remap
    nodes = _all_nodes(description, valves="valve1, /valve2", lockstep=lockstep, record="true", bag="/tmp/b",
                       mode="pi")
    by_ns: dict[str, dict] = {}
    for node in nodes:
        stack = by_ns.setdefault(node.kwargs["namespace"], {})
        assert node.executable not in stack, (node.kwargs["namespace"], node.executable)
        stack[node.executable] = node
    assert set(by_ns) == {"valve1", "/valve2"}
    for ns, stack in by_ns.items():
        assert set(stack) == {"plant", "controller", "demand", "recorder"}
        assert _overrides(stack["recorder"])["output"] == f"/tmp/b_{ns.strip('/')}"   # a bag per valve
        assert _overrides(stack["controller"])["mode"] == "pi"                        # every valve configured alike
        for exe, node in stack.items():
            remaps = [f"{a}:={b}" for a, b in node.kwargs.get("remappings") or []]
            assert (["-r", *remaps] if remaps else []) == clock_remap(ns, lockstep == "true"), (ns, exe)
        if lockstep == "true":
            assert _overrides(stack["plant"])["lockstep_participants"] == clock_participants(True)
    # one valve when valves is empty; a namespace listed twice would start two plants on one clock
    assert {n.kwargs["namespace"] for n in _all_nodes(description, valves=" ")} == {"fuel_valve"}
    with pytest.raises(ValueError, match="twice"):
        _all_nodes(description, valves="v1,/v1")


def test_learned_state_file_is_per_valve(description, monkeypatch):
    """Two valves must not share a learned-state file (each controller refuses the other's, h24u):
    ``{namespace}`` / ``per_valve`` give one per valve; a shared path is refused at launch;
    empty keeps config/controller.yaml's (not persisted)."""
    nodes = _all_nodes(description, valves="valve1,/plant/valve2", learned_state_file="~/fv/{namespace}.json")
    files = {n.kwargs["namespace"]: _overrides(n)["learned_state_file"] for n in nodes if n.executable == "controller"}
    assert files == {"valve1": "~/fv/valve1.json", "/plant/valve2": "~/fv/plant_valve2.json"}
    monkeypatch.setenv("ROS_HOME", "/var/ros")
    nodes = _all_nodes(description, valves="a,b", learned_state_file="per_valve")
    assert sorted(_overrides(n)["learned_state_file"] for n in nodes if n.executable == "controller") == [
        "/var/ros/fuel_valve/a.json", "/var/ros/fuel_valve/b.json"]
    with pytest.raises(ValueError, match="one file for the valves"):
        _all_nodes(description, valves="a,b", learned_state_file="/tmp/shared.json")
    single = _all_nodes(description, learned_state_file="/tmp/one.json")      # one valve: any path
    assert [_overrides(n)["learned_state_file"] for n in single if n.executable == "controller"] == ["/tmp/one.json"]
    default = _all_nodes(description)
    assert all("learned_state_file" not in _overrides(n) for n in default)

"""``python -m fuel_valve_control write-config``: regenerate ``config/plant.yaml``,
``config/controller.yaml`` and ``config/demand.yaml`` from the node parameter schemas (values,
units, ranges and descriptions in one place); ``check-config`` exits 1 if a file differs from
what would be written (``test_parameters.py`` runs the same check)."""
import sys

from .common.paramspec import to_ros_yaml
from .common.config_dir import default_config_dir

PREAMBLE = """ROS 2 parameter-file format.
Generated from {source}
(`python -m fuel_valve_control write-config`; do not edit by hand): each line says unit, range,
meaning and whether the value may change at run time (`ros2 param set`).
Used by `ros2 run fuel_valve {node} --ros-args --params-file config/{node}.yaml` and the launch file."""

HEADERS = {
    "plant": "Plant (actuator simulation) parameters, " + PREAMBLE + "\n"
             "fuel_valve_sim reads the physics part (PLANT_SPEC); defaults are SPEC §2.",
    "controller": "Controller (valve driver) parameters, " + PREAMBLE + "\n"
                  "fuel_valve_sim reads the core part (CONTROLLER_SPEC).  Gains are not here: they are\n"
                  "designed at start-up from model.* and design.*.",
    "demand": "Demand (supervisory stack emulation) parameters, " + PREAMBLE,
}


def node_schemas() -> dict:
    """``{node: (ParamSpec, source module)}`` of the nodes that have a config file."""
    from fuel_valve_plant.physics.params import PLANT_NODE_SPEC   # a tool may import the plant
    from .core.params import CONTROLLER_NODE_SPEC
    from .tools.profiles import DEMAND_NODE_SPEC
    return {"plant": (PLANT_NODE_SPEC, "fuel_valve_plant/physics/params.py"),
            "controller": (CONTROLLER_NODE_SPEC, "fuel_valve_control/core/params.py"),
            "demand": (DEMAND_NODE_SPEC, "fuel_valve_control/tools/profiles.py")}


def config_text(node: str) -> str:
    """The generated ``config/<node>.yaml``: the node schema's defaults."""
    spec, source = node_schemas()[node]
    return to_ros_yaml(spec, header=HEADERS[node].format(source=source, node=node))


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv not in (["write-config"], ["check-config"]):
        print("usage: python -m fuel_valve_control write-config | check-config", file=sys.stderr)
        return 2
    stale = []
    for node in node_schemas():
        path = default_config_dir() / f"{node}.yaml"
        text = config_text(node)
        if argv == ["write-config"]:
            path.write_text(text)
            print(f"wrote {path}")
        elif not path.is_file() or path.read_text() != text:
            stale.append(str(path))
    if stale:
        print("out of date (run python -m fuel_valve_control write-config): " + ", ".join(stale), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

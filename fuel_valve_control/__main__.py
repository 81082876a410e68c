"""``python -m fuel_valve_control write-config``: regenerate config/controller.yaml from the
parameter specification (values, units, ranges and descriptions in one place)."""
import sys

from .common.paramspec import to_ros_yaml
from .common.config_dir import default_config_dir

from .core.params import CONTROLLER_SPEC

HEADER = """Controller (valve driver) parameters, ROS 2 parameter-file format.
Used by `ros2 run fuel_valve controller --ros-args --params-file config/controller.yaml`, by the
launch file and by fuel_valve_sim.  Generated from fuel_valve_control/core/params.py
(`python -m fuel_valve_control write-config`); each line says unit, range and meaning.
Gains are not here: they are designed at start-up from model.* and design.*."""


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv != ["write-config"]:
        print("usage: python -m fuel_valve_control write-config", file=sys.stderr)
        return 2
    path = default_config_dir() / "controller.yaml"
    path.write_text(to_ros_yaml(CONTROLLER_SPEC, header=HEADER))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

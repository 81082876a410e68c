"""ament_python package ``fuel_valve`` (also pip-installable for machines without ROS)."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "fuel_valve"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=["fuel_valve_plant", "fuel_valve_plant.*", "fuel_valve_control", "fuel_valve_control.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/config/scenarios", glob("config/scenarios/*.yaml")),
        (f"share/{PACKAGE}/config/valve_tests", glob("config/valve_tests/*.yaml")),
        (f"share/{PACKAGE}/config/sros2", glob("config/sros2/*.xml")),
    ],
    install_requires=["setuptools", "numpy", "scipy", "PyYAML"],
    zip_safe=True,
    maintainer="fuel_valve developers",
    maintainer_email="maintainers@users.noreply.h-seed-fca7060e.example",
    description="Fuel-metering valve actuator: plant simulation, friction-compensating controller, tools",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "plant = fuel_valve_plant.ros.plant_node:main",
            "controller = fuel_valve_control.ros.controller_node:main",
            "demand = fuel_valve_control.ros.demand_node:main",
            "recorder = fuel_valve_control.tools.recorder:main",
            "fuel_valve_sim = fuel_valve_control.tools.sim:main",
            "fuel_valve_report = fuel_valve_control.tools.report:main",
            "fuel_valve_demo = fuel_valve_control.tools.demo:main",
            "fuel_valve_datasheet = fuel_valve_plant.tools.datasheet:main",
            "fuel_valve_sros2_policy = fuel_valve_control.tools.sros2_policy:main",
        ],
    },
)

"""ament_python package ``fuel_valve`` (also pip-installable for machines without ROS)."""
from glob import glob

from setuptools import setup

PACKAGE = "fuel_valve"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=["fuel_valve_plant", "fuel_valve_control"],
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/config/scenarios", glob("config/scenarios/*.yaml")),
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
            "plant = fuel_valve_plant.plant_node:main",
            "controller = fuel_valve_control.controller_node:main",
            "demand = fuel_valve_control.demand_node:main",
            "recorder = fuel_valve_control.recorder:main",
            "fuel_valve_sim = fuel_valve_control.sim:main",
            "fuel_valve_report = fuel_valve_control.report:main",
            "fuel_valve_demo = fuel_valve_control.suite:main",
            "fuel_valve_datasheet = fuel_valve_plant.datasheet:main",
        ],
    },
)

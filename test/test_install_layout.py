"""Build the package the way a ROS 2 user does (``colcon build``) and check the install tree.

colcon, colcon-ros, colcon-python-setup-py and ament_package come from PyPI
(``requirements-build.txt``, installed into ``.venv`` by ``scripts/setup.sh``); no ROS install
and no sourced ROS environment is needed: colcon-ros identifies the package from
``package.xml`` (``ros.ament_python``) and runs ``setup.py`` with the venv's Python.  The test
copies the source tree into a temporary workspace ``src/fuel_valve`` and builds it twice (once
per session each, about 2 s): a plain (copy) install and ``--symlink-install``, both
``--merge-install``.  It checks what ``ros2 run`` / ``ros2 launch`` rely on:

* ``lib/fuel_valve/<executable>`` for every executable of SPEC §4 (``setup.cfg`` puts the
  console scripts there), executable, with an existing interpreter;
* ``share/fuel_valve/{package.xml, launch/fuel_valve.launch.py, config/*.yaml,
  config/scenarios/*.yaml}`` and the ament index marker
  ``share/ament_index/resource_index/packages/fuel_valve``;
* after sourcing the install's ``setup.sh`` (as a user does), ament_index_python finds the
  package and the installed ``fuel_valve_sim`` runs from the install: an unknown scenario exits 2
  with a message that lists the built-in scenarios (read from the installed share directory).

``package.xml`` is also parsed and validated with catkin_pkg (format 3, ament_python, the
exec_depends the nodes import).  Not covered: ``ros2 run`` / ``ros2 launch`` themselves (ros2cli
and launch are not on PyPI).
"""
from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
EXECUTABLES = ("plant", "controller", "demand", "recorder", "fuel_valve_sim", "fuel_valve_report")
CONFIGS = ("plant.yaml", "controller.yaml", "demand.yaml")
# not part of the package source a user would have checked out
IGNORE = shutil.ignore_patterns(".git", ".venv", "build", "install", "log", "__pycache__", "*.egg-info",
                                ".pytest_cache", "*.pyc", "out")
EXEC_DEPENDS = {"rclpy", "std_msgs", "sensor_msgs", "std_srvs", "diagnostic_msgs", "rosgraph_msgs",
                "rcl_interfaces", "builtin_interfaces", "ament_index_python", "launch", "launch_ros",
                "python3-numpy", "python3-scipy", "python3-yaml"}


def _colcon() -> str:
    here = Path(sys.executable).parent / "colcon"
    found = str(here) if here.exists() else shutil.which("colcon")
    if not found:
        pytest.fail("colcon is not installed: run `bash scripts/setup.sh` (requirements-build.txt)")
    return found


def _run(cmd, cwd=None, env=None, timeout=120) -> subprocess.CompletedProcess:
    return subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout, stdin=subprocess.DEVNULL)


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> Path:
    ws = tmp_path_factory.mktemp("colcon_ws")
    shutil.copytree(ROOT, ws / "src" / "fuel_valve", ignore=IGNORE, symlinks=True)
    return ws


def _env(ws: Path) -> dict:
    env = dict(os.environ)
    env["COLCON_HOME"] = str(ws / "colcon_home")   # no user defaults (e.g. a global --symlink-install)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return env


@pytest.fixture(scope="module", params=["copy", "symlink"])
def install(request, workspace) -> Path:
    ws, kind = workspace, request.param
    extra = ["--symlink-install"] if kind == "symlink" else []
    result = _run([_colcon(), "--log-base", ws / f"log_{kind}", "build", "--base-paths", "src",
                   "--build-base", ws / f"build_{kind}", "--install-base", ws / f"install_{kind}",
                   "--merge-install",
                   "--event-handlers", "console_direct-", *extra], cwd=ws, env=_env(ws))
    assert result.returncode == 0, f"colcon build ({kind}) failed:\n{result.stdout}\n{result.stderr}"
    assert "Finished <<< fuel_valve" in result.stdout, result.stdout
    return ws / f"install_{kind}"


def _sourced(install: Path, *cmd, timeout=60) -> subprocess.CompletedProcess:
    """Run cmd after `. install/setup.sh`, as a user's shell would."""
    return _run(["bash", "-c", '. "$0/setup.sh" && exec "$@"', install, *cmd], cwd=install.parent,
                env=_env(install.parent), timeout=timeout)


def test_colcon_identifies_an_ament_python_package(workspace):
    result = _run([_colcon(), "--log-base", os.devnull, "list", "--base-paths", "src"], cwd=workspace,
                  env=_env(workspace))
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["fuel_valve", "src/fuel_valve", "(ros.ament_python)"], result.stdout


def test_package_xml_is_valid_format_3():
    from catkin_pkg.package import parse_package      # installed with colcon-ros
    pkg = parse_package(str(ROOT))
    pkg.validate()
    assert pkg.package_format == 3
    assert pkg.name == "fuel_valve"
    assert pkg.get_build_type() == "ament_python"
    missing = EXEC_DEPENDS - {d.name for d in pkg.exec_depends}
    assert not missing, f"package.xml lacks exec_depend {missing}"


def test_executables_installed_where_ros2_run_looks(install):
    for name in EXECUTABLES:
        path = install / "lib" / "fuel_valve" / name
        assert path.is_file(), f"missing {path}"
        assert path.stat().st_mode & stat.S_IXUSR, f"{path} is not executable"
        shebang = path.read_text().splitlines()[0]
        assert shebang.startswith("#!"), shebang
        assert Path(shebang[2:].split()[0]).exists(), f"{path}: interpreter {shebang} missing"
    assert not (install / "bin").exists() or not any((install / "bin").iterdir()), \
        "console scripts went to bin/ (setup.cfg [install]/[develop] script dir)"


def test_share_directory_and_ament_index(install):
    share = install / "share" / "fuel_valve"
    assert (share / "package.xml").is_file()
    launch = share / "launch" / "fuel_valve.launch.py"
    assert launch.is_file()
    assert launch.read_text() == (ROOT / "launch" / "fuel_valve.launch.py").read_text()
    for name in CONFIGS:
        assert (share / "config" / name).is_file(), name
    scenarios = {p.name for p in (ROOT / "config" / "scenarios").glob("*.yaml")}
    assert scenarios
    assert {p.name for p in (share / "config" / "scenarios").glob("*.yaml")} == scenarios
    assert (install / "share" / "ament_index" / "resource_index" / "packages" / "fuel_valve").is_file()


def test_sourced_install_is_found_by_ament_index(install):
    code = ("from ament_index_python.packages import get_package_share_directory as g; "
            "import fuel_valve_plant.physics.params as pp; print(g('fuel_valve')); print(pp.default_config_dir())")
    result = _sourced(install, sys.executable, "-c", code)
    assert result.returncode == 0, result.stderr
    share, config = result.stdout.split()
    assert Path(share) == install / "share" / "fuel_valve"
    if install.name == "install_copy":        # the installed code reads the installed config
        assert Path(config) == install / "share" / "fuel_valve" / "config"


def test_installed_fuel_valve_sim_runs(install):
    exe = install / "lib" / "fuel_valve" / "fuel_valve_sim"
    result = _sourced(install, exe, "--scenario", "no_such_scenario")
    assert result.returncode == 2, (result.returncode, result.stdout, result.stderr)
    assert "unknown scenario 'no_such_scenario'" in result.stderr, result.stderr
    assert "step_small" in result.stderr, result.stderr     # built-ins listed from the share directory
    assert "Traceback" not in result.stderr

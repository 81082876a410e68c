"""Where the package's ``config/`` directory is: the source tree, or the installed share."""
from __future__ import annotations

import sys
from pathlib import Path


def default_config_dir() -> Path:
    """``config/`` of the source tree or of the installed package share directory."""
    here = Path(__file__).resolve().parents[2]
    if (here / "config").is_dir():
        return here / "config"
    try:  # installed with colcon / ament
        from ament_index_python.packages import get_package_share_directory
        return Path(get_package_share_directory("fuel_valve")) / "config"
    except Exception:  # noqa: BLE001 - ament index absent or package not registered
        pass
    return Path(sys.prefix) / "share" / "fuel_valve" / "config"

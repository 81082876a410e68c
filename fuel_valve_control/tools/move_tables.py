"""Fill the move-table cache ahead (task h36b): ``python -m fuel_valve_control.tools.move_tables [--params FILE]
[--set KEY=VALUE ...] [--cache DIR]``.

With ``fine.apex_policy`` the controller node reads its doublet move tables from the disk cache
(:func:`~fuel_valve_control.core.pulse_moves.default_cache_dir`, ``$FUEL_VALVE_MOVE_TABLES`` or
``$ROS_HOME/fuel_valve/move_tables``) and builds the missing ones in a background process while its fine stage runs
main's staircase.  This builds them here, in the foreground, for the controller parameters given (the node's
parameter file and overrides: the same model and settings, so the same signature): run it once after an install or a
change of the valve's model (C1, kicks to 16 A: 342 tables, ~41 s of CPU, ~43 MB), or in CI before the node tests.
Prints the cache directory, the tables built and the CPU time; exit 0 (nothing to build is success too).
"""
from __future__ import annotations

import argparse
import time

import yaml

from ..core.driver import ValveDriver
from ..core.params import load_controller_params
from ..core.pulse_moves import default_cache_dir


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m fuel_valve_control.tools.move_tables",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--params", default="default", help="controller parameter file (default: config/controller.yaml)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="controller parameter override, e.g. fine.apex_policy=true (repeatable)")
    ap.add_argument("--cache", default=None, help="cache directory (default: $FUEL_VALVE_MOVE_TABLES or "
                                                  "$ROS_HOME/fuel_valve/move_tables)")
    args = ap.parse_args(argv)
    overrides = {}
    for item in args.set:
        key, _, value = item.partition("=")
        overrides[key.strip()] = yaml.safe_load(value)
    ps = load_controller_params(args.params, overrides)
    root = args.cache if args.cache is not None else default_cache_dir()
    if root is None:
        ap.error("no cache directory: $FUEL_VALVE_MOVE_TABLES is off; give --cache")
    deferred = ValveDriver(ps).controller.defer_tables()
    if deferred is None:
        print("move tables: nothing to build (fine.apex_policy off, or every table ready)")
        return 0
    _, moves, keys = deferred
    t0 = time.process_time()
    built = moves.build_and_save(root, keys)
    print(f"move tables: {built} built, {len(keys) - built} already in the cache, {time.process_time() - t0:.1f} s "
          f"CPU: {moves.cache_dir(root)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Scenarios: what the offline simulator runs (``config/scenarios/*.yaml``).

A scenario file::

    name: step_small
    description: 20 -> 22 % at max differential pressure
    duration_s: 1.5
    pressure_differential_kpa: 6206      # applied to the plant and told to the controller
    initial_percent: 20                  # plant starts at rest there, held by the drive
                                         # (omit or 0: closed, drive off, as at power-up)
    demand: {type: step, initial: 20, final: 22, at_s: 0.5}      # see profiles.py
    plant: {coupling.stiffness_nm_per_rad: 48}                   # parameter overrides
    controller: {}
    events:
      - {at_s: 0.5, action: trip}                                # trip | reset | signature_test |
                                                                 # partial_stroke_test
      - {at_s: 2.0, action: set_plant, params: {load_torque_nm: 3}}
      - {at_s: 2.0, action: set_controller, params: {mode: pi}}
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from ..common.paramspec import ConfigError, safe_load_yaml
from ..common.config_dir import default_config_dir

from .profiles import Profile, ProfileError, make_profile

#: trip/reset and the valve tests are the controller's Trigger services of the same name
TRIGGER_ACTIONS = ("trip", "reset", "signature_test", "partial_stroke_test")
EVENT_ACTIONS = TRIGGER_ACTIONS + ("set_plant", "set_controller")
_KEYS = {"name", "description", "duration_s", "pressure_differential_kpa", "initial_percent", "demand",
         "plant", "controller", "events"}


@dataclass
class Event:
    at_s: float
    action: str
    params: dict = field(default_factory=dict)


@dataclass
class Scenario:
    name: str
    description: str
    duration_s: float
    demand: Profile
    pressure_kpa: float | None = None
    initial_percent: float = 0.0
    plant: dict = field(default_factory=dict)
    controller: dict = field(default_factory=dict)
    events: list[Event] = field(default_factory=list)
    demand_spec: dict = field(default_factory=dict)   # the demand description as written


def scenario_dir() -> Path:
    return default_config_dir() / "scenarios"


def builtin_names() -> list[str]:
    return sorted(p.stem for p in scenario_dir().glob("*.yaml"))


def load_scenario(name_or_path: str) -> Scenario:
    """A built-in scenario by name, or a scenario YAML file by path."""
    path = Path(name_or_path)
    if not path.suffix:
        path = scenario_dir() / f"{name_or_path}.yaml"
        if not path.is_file():
            raise ConfigError(f"unknown scenario {name_or_path!r}; built-in: {', '.join(builtin_names())}")
    try:
        doc = safe_load_yaml(path.read_text())
    except OSError as exc:
        raise ConfigError(f"cannot read scenario {path}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"scenario {path} is not valid YAML: {exc}") from None
    return parse_scenario(doc, path)


def parse_scenario(doc: Any, path: Path | str = "<scenario>") -> Scenario:
    if not isinstance(doc, dict):
        raise ConfigError(f"{path}: a scenario is a mapping")
    unknown = set(doc) - _KEYS
    if unknown:
        raise ConfigError(f"{path}: unknown scenario key(s) {', '.join(sorted(unknown))}")
    for key in ("name", "duration_s", "demand"):
        if key not in doc:
            raise ConfigError(f"{path}: scenario needs '{key}'")
    try:
        duration = float(doc["duration_s"])
        initial = float(doc.get("initial_percent", 0.0))
    except (TypeError, ValueError):
        raise ConfigError(f"{path}: duration_s and initial_percent must be numbers") from None
    if not 0.0 < duration <= 3600.0:
        raise ConfigError(f"{path}: duration_s must be in (0, 3600] s")
    if not 0.0 <= initial <= 100.0:
        raise ConfigError(f"{path}: initial_percent must be in 0..100")
    try:
        profile = make_profile(doc["demand"], Path(path).parent if isinstance(path, Path) else None)
    except ProfileError as exc:
        raise ConfigError(f"{path}: demand: {exc}") from None
    events = []
    for ev in doc.get("events") or []:
        if not isinstance(ev, dict) or ev.get("action") not in EVENT_ACTIONS or "at_s" not in ev:
            raise ConfigError(f"{path}: event {ev!r} needs at_s and an action in {', '.join(EVENT_ACTIONS)}")
        events.append(Event(float(ev["at_s"]), ev["action"], dict(ev.get("params") or {})))
    pressure = doc.get("pressure_differential_kpa")
    return Scenario(str(doc["name"]), str(doc.get("description", "")), duration, profile,
                    None if pressure is None else float(pressure), initial,
                    dict(doc.get("plant") or {}), dict(doc.get("controller") or {}),
                    sorted(events, key=lambda e: e.at_s), dict(doc["demand"]))

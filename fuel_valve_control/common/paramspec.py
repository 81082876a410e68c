"""Typed, range-checked parameter sets shared by the plant, the controller and the nodes.

A :class:`ParamSpec` lists every parameter of one component (name, default, type, allowed
range or choices, unit, description, whether it may change at run time).  The same list
drives three things so they cannot drift apart:

* loading and validating ``config/*.yaml`` (ROS 2 parameter-file format, nested keys are
  flattened to dotted names such as ``motor.resistance_ohm``),
* ``--set section.key=value`` overrides of the offline simulator,
* ROS parameter declaration with descriptors and the on-set-parameters validation.

Errors are :class:`ConfigError` (a ``ValueError``) whose message names the bad key, the
offending value and the allowed range, e.g.
``plant: motor.resistance_ohm = -1.0 is out of range; allowed 0 < value <= 10 [ohm]``.
"""
from __future__ import annotations

import array
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Mapping

import yaml


class ConfigError(ValueError):
    """A configuration value is unknown, of the wrong type or outside its allowed range."""


@dataclass(frozen=True)
class Param:
    """One parameter: its default, type and allowed values.

    ``low``/``high`` bound numeric values (``None`` = unbounded); ``low_open`` makes the lower
    bound exclusive (``value > low``).  ``choices`` restricts strings.  ``runtime`` marks values
    that may be changed while the loop runs (through ROS parameter services).
    """

    name: str
    default: Any
    unit: str = ""
    description: str = ""
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    choices: tuple[str, ...] | None = None
    runtime: bool = False

    def __post_init__(self):
        if isinstance(self.default, list) and not self.default:
            raise ValueError(f"{self.name}: a list parameter needs a non-empty default (it fixes the element type)")

    @property
    def kind(self) -> type:
        return type(self.default)

    @property
    def item_kind(self) -> type:
        """Element type of a list parameter (taken from its non-empty default)."""
        return type(self.default[0])

    def range_text(self) -> str:
        """Human-readable allowed range, used in error messages and ROS descriptors."""
        if self.choices is not None:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.kind is list:
            return f"a list of {self.item_kind.__name__}" + (f" [{self.unit}]" if self.unit else "")
        if self.kind is bool:
            return "true or false"
        if self.kind is str:
            return "any text"
        lo = "" if self.low is None else f"{self.low:g} {'<' if self.low_open else '<='} "
        hi = "" if self.high is None else f" <= {self.high:g}"
        text = f"{lo}value{hi}" if (lo or hi) else "any finite number"
        return text + (f" [{self.unit}]" if self.unit else "")

    def coerce(self, value: Any, where: str) -> Any:
        """Return ``value`` converted to this parameter's type, or raise :class:`ConfigError`."""
        kind = self.kind
        if kind is list:
            if not isinstance(value, (list, tuple, array.array)):     # rclpy gives arrays for numeric lists
                raise ConfigError(f"{where}: {self.name} = {value!r} is not a list; allowed {self.range_text()}")
            item = Param(self.name, self.item_kind(), self.unit, low=self.low, high=self.high,
                         low_open=self.low_open, choices=self.choices)
            return [item.coerce(v, where) for v in value]
        if kind is bool:
            if isinstance(value, bool):
                return value
            if isinstance(value, str) and value.lower() in ("true", "false"):
                return value.lower() == "true"
            raise ConfigError(f"{where}: {self.name} = {value!r} is not a boolean; allowed true or false")
        if kind is str:
            if not isinstance(value, str):
                raise ConfigError(f"{where}: {self.name} = {value!r} is not a string; allowed {self.range_text()}")
            if self.choices is not None and value not in self.choices:
                raise ConfigError(f"{where}: {self.name} = {value!r} is not allowed; allowed {self.range_text()}")
            return value
        # numeric
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            raise ConfigError(f"{where}: {self.name} = {value!r} is not a number; allowed {self.range_text()}")
        try:
            number = float(value)
        except ValueError:
            raise ConfigError(f"{where}: {self.name} = {value!r} is not a number; allowed {self.range_text()}") from None
        if not math.isfinite(number):
            raise ConfigError(f"{where}: {self.name} = {value!r} is not finite; allowed {self.range_text()}")
        if kind is int:
            if number != int(number):
                raise ConfigError(f"{where}: {self.name} = {value!r} is not an integer; allowed {self.range_text()}")
            number = int(number)
        too_low = self.low is not None and (number <= self.low if self.low_open else number < self.low)
        too_high = self.high is not None and number > self.high
        if too_low or too_high:
            raise ConfigError(f"{where}: {self.name} = {value!r} is out of range; allowed {self.range_text()}")
        return number


class ParamSpec:
    """An ordered collection of :class:`Param` for one component (e.g. ``plant``)."""

    def __init__(self, section: str, params: Iterable[Param]):
        self.section = section
        self.params: dict[str, Param] = {}
        for p in params:
            if p.name in self.params:
                raise ValueError(f"duplicate parameter {p.name}")
            p.coerce(p.default, f"{section} (default)")  # defaults must satisfy their own range
            self.params[p.name] = p

    def __iter__(self):
        return iter(self.params.values())

    def __contains__(self, name: str) -> bool:
        return name in self.params

    def extended(self, params: Iterable[Param], section: str | None = None) -> "ParamSpec":
        """A node's schema: ``params`` (node-level keys, listed first) followed by this spec's
        parameters.  The node declares, documents and writes its YAML file from the result."""
        return ParamSpec(section or self.section, [*params, *self])

    def pick(self, values: Mapping[str, Any], where: str | None = None) -> "ParamSet":
        """This spec's parameters taken from ``values`` (e.g. a node's larger set), validated;
        keys of other specs are ignored, missing keys keep their defaults."""
        return self.defaults().replace({k: v for k, v in values.items() if k in self.params}, where)

    def defaults(self) -> "ParamSet":
        return ParamSet(self, {name: p.default for name, p in self.params.items()})

    def load_from_node_file(self, node_spec: "ParamSpec", path: str | Path | None,
                            overrides: Mapping[str, Any] | None = None) -> "ParamSet":
        """This (core) spec's values from a *node's* parameter file: every key of the file is
        validated against ``node_spec`` (this spec extended by node-level keys), this spec keeps
        its own, then ``overrides`` apply."""
        return self.pick(node_spec.load(path), where=f"{self.section} ({path})").replace(overrides or {})

    def validate(self, values: Mapping[str, Any], where: str | None = None) -> dict[str, Any]:
        """Check and coerce a flat ``{dotted.name: value}`` mapping (unknown keys are errors)."""
        where = where or self.section
        out = {}
        for name, value in values.items():
            if name not in self.params:
                raise ConfigError(f"{where}: unknown parameter {name!r}; known: {', '.join(sorted(self.params))}")
            out[name] = self.params[name].coerce(value, where)
        return out

    def load(self, path: str | Path | None = None, overrides: Mapping[str, Any] | None = None) -> "ParamSet":
        """Defaults, then the YAML file (if given), then ``overrides``, all validated."""
        ps = self.defaults()
        if path is not None:
            ps = ps.replace(read_ros_param_file(path), where=f"{self.section} ({path})")
        if overrides:
            ps = ps.replace(overrides)
        return ps


class ParamSet(Mapping[str, Any]):
    """Validated parameter values (read-only mapping ``dotted.name -> value``)."""

    def __init__(self, spec: ParamSpec, values: Mapping[str, Any]):
        self.spec = spec
        self._values = dict(values)

    def __getitem__(self, name: str) -> Any:
        return self._values[name]

    def __iter__(self):
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def replace(self, changes: Mapping[str, Any], where: str | None = None) -> "ParamSet":
        """A new set with ``changes`` applied after validation; ``self`` is unchanged."""
        merged = dict(self._values)
        merged.update(self.spec.validate(changes, where))
        return ParamSet(self.spec, merged)

    def as_dict(self) -> dict[str, Any]:
        return dict(self._values)


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"motor": {"r": 1}}`` -> ``{"motor.r": 1}`` (ROS 2 nested parameter naming)."""
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten(value, name + "."))
        else:
            flat[name] = value
    return flat


#: libyaml's parser where PyYAML was built with it (the PyPI wheels are), else the pure-Python
#: one: the same constructors and resolvers, so the same values, parsed ~10x faster (the
#: controller file took 14 ms per read in pure Python, and every offline run reads two files)
_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def safe_load_yaml(text: str) -> Any:
    """``yaml.safe_load(text)`` with the fastest safe loader available (:data:`_SAFE_LOADER`);
    raises ``yaml.YAMLError`` on malformed text like ``yaml.safe_load``."""
    return yaml.load(text, Loader=_SAFE_LOADER)


def read_ros_param_file(path: str | Path) -> dict[str, Any]:
    """Read a ROS 2 parameter file and return its (single node's) parameters, flattened.

    Accepts ``{node_or_wildcard: {ros__parameters: {...}}}``; several node entries are merged
    in file order, which is how ``ros2 run --params-file`` applies ``/**`` plus a node key.
    """
    path = Path(path)
    try:
        doc = safe_load_yaml(path.read_text())
    except OSError as exc:
        raise ConfigError(f"cannot read parameter file {path}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path} is not valid YAML: {exc}") from None
    if not isinstance(doc, Mapping) or not doc:
        raise ConfigError(f"{path}: expected a ROS 2 parameter file ({{node: {{ros__parameters: ...}}}})")
    flat: dict[str, Any] = {}
    for node_key, body in doc.items():
        if not isinstance(body, Mapping) or "ros__parameters" not in body:
            raise ConfigError(f"{path}: entry {node_key!r} has no 'ros__parameters' mapping")
        params = body["ros__parameters"]
        if not isinstance(params, Mapping):
            raise ConfigError(f"{path}: {node_key}.ros__parameters must be a mapping")
        flat.update(flatten(params))
    return flat


def parse_overrides(items: Iterable[str], sections: Iterable[str]) -> dict[str, dict[str, Any]]:
    """Parse ``section.key=value`` strings (``--set``) into ``{section: {key: value}}``.

    Values are parsed as YAML scalars, so ``2``, ``2.5``, ``true`` and ``lugre`` all work.
    """
    sections = list(sections)
    out: dict[str, dict[str, Any]] = {s: {} for s in sections}
    for item in items:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected section.key=value")
        lhs, rhs = item.split("=", 1)
        section, _, key = lhs.strip().partition(".")
        if section not in out or not key:
            raise ConfigError(f"--set {item!r}: section must be one of {', '.join(sections)} (e.g. plant.friction_scale=2)")
        try:
            value = yaml.safe_load(rhs) if rhs.strip() else rhs
        except yaml.YAMLError:
            value = rhs
        out[section][key] = value
    return out


def to_ros_yaml(spec: ParamSpec, values: Mapping[str, Any] | None = None, header: str = "") -> str:
    """A ROS 2 parameter file (``/**: ros__parameters:``) for ``values`` (default: the
    defaults), nested by dotted name, each entry commented with its unit, range and meaning."""
    values = dict(spec.defaults()) if values is None else dict(values)
    lines = [f"# {line}".rstrip() for line in header.strip().splitlines()] if header else []
    lines += ["/**:", "  ros__parameters:"]
    opened: list[str] = []
    closed: set[str] = set()
    for p in spec:
        parts = p.name.split(".")
        common = 0
        while common < min(len(opened), len(parts) - 1) and opened[common] == parts[common]:
            common += 1
        closed.update(".".join(opened[:i + 1]) for i in range(common, len(opened)))
        opened = opened[:common]
        for depth in range(common, len(parts) - 1):
            group = ".".join(parts[:depth + 1])
            if group in closed:
                raise ValueError(f"{spec.section}: parameters of group {group!r} are not contiguous")
            lines.append("    " + "  " * depth + parts[depth] + ":")
            opened.append(parts[depth])
        value = values[p.name]
        text = yaml.safe_dump(value, default_flow_style=True).strip()
        if text.endswith("..."):
            text = text[:-3].strip()
        note = f"{p.description}; {p.range_text()}" + ("; run-time" if p.runtime else "")
        lines.append(f"    {'  ' * (len(parts) - 1)}{parts[-1]}: {text}  # {note}")
    return "\n".join(lines) + "\n"


#: the node parameter every publishing node of the suite (plant, controller, demand) shares:
#: when a recorder is part of the run (the launcher and the launch file set it to what it
#: records), the node holds its first publish until the recorder's subscriptions to those of
#: its topics have matched (:class:`fuel_valve_control.ros.interface.RecorderGate`), so the bag
#: holds every message.  A comma-separated string (a launch file passes it as it is): "" = no recorder
#: ``recorded_topics`` entry meaning "every topic of the node" (the recorder's default list)
ALL_TOPICS = "*"
RECORDED_TOPICS = Param("recorded_topics", "", "", "topics the run's recorder node (same namespace) records, "
                        "comma-separated: '*' = every topic, else names (relative ones follow the namespace); "
                        "empty = no recorder.  The node publishes once the recorder has matched each of its "
                        "topics in the list (at most 20 s of wall time), so no message is lost to discovery")

"""One run's set-up, written once and ROS-free: the :class:`RunPlan`.

A run is a scenario (``config/scenarios``, see :mod:`.scenarios`) plus the user's overrides,
a resolver-noise seed and a timing:

* ``offline`` -- ``fuel_valve_sim``: plant and driver objects in one process;
* ``real_time`` / ``lockstep`` -- ``fuel_valve_demo``, the node tests and the benchmarks: the
  plant, controller and demand nodes as processes (:mod:`.launcher` starts them).

The plan holds everything that follows from that, so no tool derives it a second time:

* the plant and controller parameter sets, layered config file < scenario < overrides
  (< seed, controller mode), and the few overrides themselves (what the node parameter files
  carry on top of ``config/*.yaml``);
* the initial state: ``initial_percent`` > 0 starts the plant at rest there, held by the drive
  (coupling twisted, holding current flowing), and the loop from that holding current --
  :meth:`RunPlan.start_held` for objects, :meth:`RunPlan.node_parameters` for nodes
  (``start_held`` / ``initial_position_rad`` on the plant, ``initial_current_a`` on the
  controller, which both nodes turn into exactly the calls :meth:`start_held` makes);
* the demand profile (object and demand-node parameters);
* the timed events (trip, reset, set_plant, set_controller), due at
  :meth:`EventQueue.due`, applied to objects by :func:`apply_event`;
* the run's length (``stop_after_s`` of a lockstep plant, so a run has exactly this length).

Δp is a plant-side setting: a scenario's ``pressure_differential_kpa`` goes to the plant.
(The controller is still *told* the same value as its own parameter, in one marked line of
:func:`plan_run`, until the controller measures Δp as an input.)

Units: angles rad, percent of the stroke, currents A, times s, Δp kPa.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable

from fuel_valve_plant.physics.params import PLANT_SPEC, load_plant_params
from fuel_valve_plant.physics.plant import Plant

from ..common.paramspec import ConfigError, ParamSet
from ..core.driver import ValveDriver
from ..core.params import CONTROLLER_SPEC, MODES, load_controller_params
from .profiles import Profile, ProfileError, make_profile
from .scenarios import Event, Scenario, parse_scenario

OFFLINE, REAL_TIME, LOCKSTEP = "offline", "real_time", "lockstep"
TIMINGS = (OFFLINE, REAL_TIME, LOCKSTEP)
#: the node processes of a run, in start order
NODES = ("plant", "controller", "demand")
#: what a run without a scenario plays: the demand node's start-up profile at the configured Δp
STARTUP = {"name": "startup_profile", "duration_s": 20.0, "demand": {"type": "startup"},
           "description": "start-up to core idle at maximum differential pressure"}
#: events due within this of a period start are applied in that period (float sums of periods)
EVENT_TOLERANCE_S = 1e-12


@dataclass(frozen=True)
class RunPlan:
    """Everything one run needs, derived once from a scenario (see the module docstring)."""

    name: str
    description: str
    timing: str                          # offline | real_time | lockstep
    duration_s: float
    demand: Profile                      # percent of stroke over time
    demand_spec: dict                    # the profile as written (profiles.py keys)
    plant_params: ParamSet               # complete, validated
    controller_params: ParamSet
    plant_overrides: dict                # on top of config/plant.yaml (node parameter file)
    controller_overrides: dict           # on top of config/controller.yaml
    demand_overrides: dict = field(default_factory=dict)   # demand-node extras (publish_rate_hz ...)
    initial_percent: float = 0.0         # > 0: start held there by the drive
    events: tuple[Event, ...] = ()

    @property
    def lockstep(self) -> bool:
        return self.timing == LOCKSTEP

    @property
    def mode(self) -> str:
        """The controller mode."""
        return self.controller_params["mode"]

    @property
    def initial_angle_rad(self) -> float | None:
        """Valve angle the run starts held at, rad (None: closed, drive off, as at power-up)."""
        if self.initial_percent <= 0.0:
            return None
        return self.initial_percent / 100.0 * self.plant_params["valve.stroke_rad"]

    def hold_current_a(self) -> float:
        """q-current that holds the valve at :attr:`initial_angle_rad` (0 when not held), A."""
        angle = self.initial_angle_rad
        return 0.0 if angle is None else Plant(self.plant_params).hold_at(angle)

    def start_held(self, plant: Plant, driver: ValveDriver) -> None:
        """Put ``plant`` at rest at the initial angle held by the drive and let ``driver`` take
        over from the holding current (its nominal torque constant turns it into torque, as the
        controller node does with ``initial_current_a``).  No-op when the run starts closed."""
        angle = self.initial_angle_rad
        if angle is None:
            return
        hold_a = plant.hold_at(angle)
        driver.start_from_torque(hold_a * driver.controller.model.torque_constant_nm_per_a)

    def event_queue(self) -> "EventQueue":
        return EventQueue(self.events)

    def node_parameters(self) -> dict[str, dict]:
        """``{node: {parameter: value}}`` for the plant, controller and demand node processes:
        the run's overrides on top of ``config/*.yaml``, the initial state and the timing.
        (Clock wiring -- ``use_sim_time``, ``lockstep_participants`` -- is the launcher's.)"""
        plant = dict(self.plant_overrides)
        controller = dict(self.controller_overrides)
        demand = demand_node_parameters(self.demand_spec)
        demand.update(self.demand_overrides)
        angle = self.initial_angle_rad
        if angle is not None:
            plant.update(initial_position_rad=angle, start_held=True)
            controller["initial_current_a"] = self.hold_current_a()
        for params in (plant, controller, demand):
            params["lockstep"] = self.lockstep
        if self.lockstep:                  # the demand is evaluated on the loop's period grid
            demand.setdefault("tick_period_s", 1.0 / self.controller_params["loop_rate_hz"])
        if self.lockstep:                  # an explicit override (0 = run until stopped) wins
            plant.setdefault("stop_after_s", self.duration_s)
        return {"plant": plant, "controller": controller, "demand": demand}


class EventQueue:
    """A plan's timed events, handed out once each when the run's clock passes them."""

    def __init__(self, events: Iterable[Event]):
        self._events = sorted(events, key=lambda e: e.at_s)

    def due(self, t: float) -> list[Event]:
        """Events at or before ``t`` (s) not handed out yet, in time order."""
        out = []
        while self._events and self._events[0].at_s <= t + EVENT_TOLERANCE_S:
            out.append(self._events.pop(0))
        return out

    def __len__(self) -> int:
        return len(self._events)


def apply_event(event: Event, plant: Plant, driver: ValveDriver) -> None:
    """Apply a scenario event to plant and driver objects (the offline simulator; the demo sends
    the same events through the nodes' services, see :mod:`.monitor`)."""
    if event.action == "trip":
        driver.trip("scenario trip")
    elif event.action in ("signature_test", "partial_stroke_test"):
        from ..core.valve_tests import ValveTests
        tests = driver.valve_test if driver.valve_test is not None else ValveTests(driver)
        tests.start(event.action[:-len("_test")])      # a refusal is kept in tests.refusals
    elif event.action == "reset":
        driver.reset()
    elif event.action == "set_plant":
        plant.set_params(event.params)
    elif event.action == "set_controller":
        driver.set_params(event.params)


def _typed(overrides: dict, ps: ParamSet, spec) -> dict:
    """``overrides`` with every value of a parameter in ``spec`` as the parameter set ``ps`` holds it (converted to
    the parameter's type); others (node-only parameters) as given."""
    return {k: ps[k] if k in spec.params else v for k, v in overrides.items()}


def plan_run(scenario: Scenario | None, timing: str = OFFLINE, *, mode: str | None = None,
             seed: int | None = None, duration_s: float | None = None, plant_overrides: dict | None = None,
             controller_overrides: dict | None = None, demand_overrides: dict | None = None) -> RunPlan:
    """The plan of one run: config defaults < ``scenario`` < overrides < ``seed`` / ``mode``.

    ``scenario`` None: the start-up profile (:data:`STARTUP`).  ``duration_s`` overrides the
    scenario's length.  Offline every override must be a plant/controller parameter; for node
    processes, overrides outside the schema (node settings such as ``telemetry_decimation``)
    are passed on to the node, which checks them.  Raises :class:`ConfigError` on bad input.
    """
    if timing not in TIMINGS:
        raise ConfigError(f"unknown timing {timing!r}; allowed: {', '.join(TIMINGS)}")
    if mode is not None and mode not in MODES:
        raise ConfigError(f"unknown controller mode {mode!r}; allowed: {', '.join(MODES)}")
    if scenario is None:
        scenario = parse_scenario(STARTUP)
    plant = dict(scenario.plant)
    controller = dict(scenario.controller)
    if scenario.pressure_kpa is not None:      # set on the plant only: the controller measures it
        plant["pressure_differential_kpa"] = scenario.pressure_kpa
    plant.update(plant_overrides or {})
    if "command_timeout_s" in plant:   # one drive timeout: what the controller assumes follows the plant's
        controller["faults.drive_command_timeout_s"] = plant["command_timeout_s"]
    controller.update(controller_overrides or {})
    if seed is not None:
        plant["seed"] = seed
    if mode is not None:
        controller["mode"] = mode
    strict = timing == OFFLINE
    plant_ps = load_plant_params(overrides=_in_schema(plant, PLANT_SPEC, strict))
    controller_ps = load_controller_params(overrides=_in_schema(controller, CONTROLLER_SPEC, strict))
    duration = float(scenario.duration_s if duration_s is None else duration_s)
    if not duration > 0.0:
        raise ConfigError(f"run duration must be > 0 s, got {duration!r}")
    # the node processes get the overrides typed as the schema says (a ROS parameter typed DOUBLE refuses the
    # INTEGER 2 that `--set controller.fine.late_loop_holdoff_first_s=2` parses to; the offline run took it)
    plant = _typed(plant, plant_ps, PLANT_SPEC)
    controller = _typed(controller, controller_ps, CONTROLLER_SPEC)
    return RunPlan(scenario.name, scenario.description, timing, duration, scenario.demand,
                   dict(scenario.demand_spec), plant_ps, controller_ps, plant, controller,
                   dict(demand_overrides or {}), scenario.initial_percent, tuple(scenario.events))


def _in_schema(overrides: dict, spec, strict: bool) -> dict:
    """The overrides the parameter schema validates (all of them when ``strict``: unknown names
    then raise in the loader)."""
    return dict(overrides) if strict else {k: v for k, v in overrides.items() if k in spec}


def demand_node_parameters(spec: dict) -> dict:
    """Demand-node parameters for a profile description (profiles.py keys).  A ``plateaus``
    sequence goes to the node as its corner points (``points``, ``interpolation: previous``:
    the very profile object :func:`~.profiles.make_profile` builds from it, so node and
    simulator play the same demand); the node plays no analog noise or glitches on it."""
    if spec.get("type") == "plateaus":
        if spec.get("noise_rms_pct") or spec.get("glitches"):
            raise ConfigError("a plateaus demand with noise_rms_pct or glitches cannot be played by the demand node")
        try:
            corners = make_profile(spec).points
        except ProfileError as exc:
            raise ConfigError(f"demand: {exc}") from None
        spec = {"type": "points", "interpolation": "previous", "points": corners}
    out = {}
    for key, value in spec.items():
        if key == "type":
            out["profile"] = value
        elif key == "points":
            out["points"] = [float(x) for pair in value for x in pair]
        elif key == "path":
            out["csv_path"] = str(value)
        else:
            out[key] = float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else value
    return out

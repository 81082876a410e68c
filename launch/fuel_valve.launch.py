"""Launch the fuel-valve actuator stack: plant, controller and demand (+ recorder).

    ros2 launch fuel_valve fuel_valve.launch.py
    ros2 launch fuel_valve fuel_valve.launch.py mode:=pi lockstep:=true
    ros2 launch fuel_valve fuel_valve.launch.py record:=true bag:=run1 demand_profile:=step
    ros2 launch fuel_valve fuel_valve.launch.py valves:=valve1,valve2 lockstep:=true

All nodes run in the namespace ``namespace`` (default ``fuel_valve``; topics are relative, so
they follow it) with the parameter files ``config/plant.yaml``, ``config/controller.yaml`` and
``config/demand.yaml`` of the installed package share directory.

Launch arguments:

* ``namespace`` -- namespace of every node (default ``fuel_valve``).
* ``valves`` -- comma-separated namespaces, e.g. ``valve1,valve2``: one launch starts a
  complete stack (plant, controller, demand, + recorder) per namespace, every one configured by
  the other arguments, and one Ctrl-C stops them all.  Empty (default): one valve in
  ``namespace``.
* ``mode`` -- controller ``mode`` (empty: the one in ``config/controller.yaml``).
* ``lockstep`` -- ``true``: deterministic simulated time.  The plant gets ``lockstep: true``
  and publishes the clock (its own ``use_sim_time`` stays false); the controller, the demand
  node (both ``lockstep: true``) and the recorder run with ``use_sim_time: true``; the plant
  waits for ``lockstep_participants`` = 2 clock subscribers (3 with ``record:=true``).  Each
  valve has a clock of its own: every node of the launch gets the remapping
  ``/clock:=/<namespace>/clock``, so several valves (``valves:=...``, or one launch per
  ``namespace``) each run their own deterministic lockstep.
* ``record`` -- ``true``: also start the ``recorder`` node, writing the bag ``bag`` (with
  ``valves``: one bag per valve, ``<bag>_<namespace>``); plant, controller and demand get
  ``recorded_topics: '*'`` (they publish once it has matched).
* ``bag`` -- recorder ``output`` directory (default ``fuel_valve_bag``).
* ``autostart`` -- ``true`` (default): the controller (a managed lifecycle node) configures
  and activates itself; ``false``: it starts unconfigured with the drive disabled and a
  supervisor drives it through ``<namespace>/controller/change_state`` (lifecycle_msgs).
* ``demand_profile`` -- overrides the demand node's ``profile`` (empty: the one in
  ``config/demand.yaml``).
* ``learned_state_file`` -- the controller's ``learned_state_file``, one file per valve:
  ``{namespace}`` in it becomes the valve's namespace (slashes inside it as ``_``), e.g.
  ``learned_state_file:=~/fuel_valve/{namespace}.json``; ``per_valve`` is
  ``$ROS_HOME/fuel_valve/{namespace}.json`` (``~/.ros`` without ``ROS_HOME``).  Empty (default):
  the one in ``config/controller.yaml`` ('': not persisted, so a lockstep run does not start
  from the previous run's learning).  With several ``valves`` a path without ``{namespace}`` is
  refused at launch: the valves would share one file, and each controller refuses a file
  another valve owns (h24u).

Boolean arguments accept ``true``/``false`` (any case) and ``1``/``0``.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PACKAGE = 'fuel_valve'

ARGUMENTS = (
    ('namespace', 'fuel_valve', 'namespace of all nodes (topic names are relative)'),
    ('valves', '', 'comma-separated namespaces, one complete valve stack each (e.g. valve1,valve2); '
                   'empty: one valve in namespace'),
    ('mode', '', "controller mode: pi, pi_dither, observer, observer_fc, kalman_fc, fc_gain, "
                 "observer_ff, observer_fp (empty: config/controller.yaml, observer_fp)"),
    ('lockstep', 'false', 'true: deterministic simulated time, the plant publishes /clock and '
                          'advances one control period per command'),
    ('record', 'false', 'true: also start the recorder (rosbag2 of the suite topics)'),
    ('autostart', 'true', 'true: the controller configures and activates itself; false: it waits '
                          'unconfigured (drive disabled) for ~/change_state'),
    ('bag', 'fuel_valve_bag', 'bag directory written by the recorder (record:=true)'),
    ('demand_profile', '', 'demand profile: constant, step, ramp, sine, chirp, points, startup, '
                           'csv (empty: config/demand.yaml)'),
    ('learned_state_file', '', "controller learned_state_file, '{namespace}' replaced by the valve's namespace; "
                               "per_valve: $ROS_HOME/fuel_valve/{namespace}.json (empty: config/controller.yaml)"),
)
#: ``learned_state_file:=per_valve``: under ROS_HOME (rcl's own per-user directory, ~/.ros)
PER_VALVE_STATE = os.path.join('{ros_home}', 'fuel_valve', '{namespace}.json')


def _flag(context, name):
    """A boolean launch argument, parsed like launch's own conditions."""
    text = LaunchConfiguration(name).perform(context).strip().lower()
    if text in ('true', '1'):
        return True
    if text in ('false', '0'):
        return False
    raise ValueError(f"launch argument '{name}' must be true or false, got {text!r}")


def _namespaces(context):
    """The valves' namespaces: the ``valves`` list, else ``namespace`` alone."""
    valves = [v.strip() for v in LaunchConfiguration('valves').perform(context).split(',') if v.strip()]
    if len(set(v.strip('/') for v in valves)) != len(valves):
        raise ValueError(f"launch argument 'valves' lists a namespace twice: {valves}")
    return valves or [LaunchConfiguration('namespace').perform(context)]


def learned_state_file(text, namespace):
    """The controller's learned-state file of the valve in ``namespace`` for the launch argument
    ``text`` ('' : none given; ``per_valve``: :data:`PER_VALVE_STATE`; else ``{namespace}``
    replaced).  The controller expands ``~`` and ``$VARS`` itself."""
    text = text.strip()
    if text == 'per_valve':
        text = PER_VALVE_STATE.replace('{ros_home}', os.environ.get('ROS_HOME') or '~/.ros')
    name = namespace.strip('/').replace('/', '_') or 'root'
    return text.replace('{namespace}', name)


def _nodes(context, *args, **kwargs):
    """The nodes of every valve, once the launch arguments are known."""
    namespaces = _namespaces(context)
    state = LaunchConfiguration('learned_state_file').perform(context).strip()
    if state and len(namespaces) > 1 and '{namespace}' not in state and state != 'per_valve':
        raise ValueError(f"launch argument 'learned_state_file' ({state}) would be one file for the valves "
                         f"{', '.join(namespaces)}, and each controller refuses a file another valve owns: "
                         "put '{namespace}' in it (or use per_valve)")
    return [node for namespace in namespaces
            for node in _valve(context, namespace, bag_suffix=f'_{namespace.strip("/")}' if len(namespaces) > 1 else '')]


def _valve(context, namespace, bag_suffix=''):
    """One valve's nodes in ``namespace``."""
    config = os.path.join(get_package_share_directory(PACKAGE), 'config')
    mode = LaunchConfiguration('mode').perform(context).strip()
    profile = LaunchConfiguration('demand_profile').perform(context).strip()
    bag = LaunchConfiguration('bag').perform(context) + bag_suffix
    lockstep = _flag(context, 'lockstep')
    record = _flag(context, 'record')

    # later entries of `parameters` override earlier ones (the YAML file)
    plant = {'lockstep': lockstep}
    controller = {'lockstep': lockstep, 'autostart': _flag(context, 'autostart')}
    demand = {'lockstep': lockstep}
    recorder = {'output': bag}
    if lockstep:
        plant['use_sim_time'] = False          # the plant owns /clock
        plant['lockstep_participants'] = 3 if record else 2
        for params in (controller, demand, recorder):
            params['use_sim_time'] = True
    if record:     # publish once the recorder matched (tools/launcher.recording_parameters)
        for params in (plant, controller, demand):
            params['recorded_topics'] = '*'        # the recorder's default: every topic
    if mode:
        controller['mode'] = mode
    if profile:
        demand['profile'] = profile
    state = learned_state_file(LaunchConfiguration('learned_state_file').perform(context), namespace)
    if state:
        controller['learned_state_file'] = state

    # the valve's own simulated clock (what fuel_valve_control.tools.launcher.clock_remap gives)
    ns = namespace.strip('/')
    remappings = [('/clock', f'/{ns}/clock' if ns else '/clock')] if lockstep else []

    def node(executable, params_file, overrides):
        parameters = [os.path.join(config, params_file)] if params_file else []
        return Node(package=PACKAGE, executable=executable, name=executable, namespace=namespace,
                    parameters=parameters + [overrides], remappings=remappings, output='screen')

    nodes = [node('plant', 'plant.yaml', plant),
             node('controller', 'controller.yaml', controller),
             node('demand', 'demand.yaml', demand)]
    if record:
        nodes.append(node('recorder', None, recorder))
    return nodes


def generate_launch_description():
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text)
         for name, default, text in ARGUMENTS]
        + [OpaqueFunction(function=_nodes)])

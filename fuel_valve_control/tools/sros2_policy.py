"""``fuel_valve_sros2_policy``: the SROS2 access-control policy of the suite, generated from the
nodes themselves (issue 13, item 10).

Without DDS security any participant on the domain can publish ``current_command`` or
``drive_enable``, set parameters and call ``~/reset``.  SROS2 closes that with one *enclave*
(certificate + signed permissions) per node; the permissions come from a policy XML.  Written by
hand, such a policy drifts from the code (a new topic, a renamed service) and the drift shows up
only on the secured plant, as a node that silently receives nothing.  So this module builds the
policy the way ``ros2 security generate_policy`` does -- from each node's own endpoints -- but
from the node objects in this process instead of a live graph, for every configuration a user
runs (real time and lockstep), and the repository keeps the result in ``config/sros2/policy.xml``
(``test_sros2_policy.py`` fails when it is stale).

Who may do what follows from the endpoints, so the policy states the contract's ownership:
only the ``controller`` enclave may publish ``current_command`` / ``drive_enable`` and reply on
``~/reset`` / ``~/trip``; only the ``plant`` publishes the resolvers, ``joint_states``, ``drive``,
``drive_status``, ``pressure_differential`` and (lockstep) the clock; only ``demand`` publishes
the demand; the ``recorder`` only subscribes.  Operator tools (``ros2 param``, ``ros2 service``,
the demo's monitor) are not suite nodes: give them their own enclave and profile.

Names follow sros2's rules: ``~/x`` for the node's private names, names relative to the
namespace for the namespace's topics, absolute otherwise (``/parameter_events``, ``/rosout``).

Usage::

    fuel_valve_sros2_policy [--namespace /fuel_valve] [--output config/sros2/policy.xml]
    fuel_valve_sros2_policy --check          # exit 1 if config/sros2/policy.xml is stale

then, on a ROS 2 install with the security plugins (see README "Safety and security")::

    ros2 security create_keystore ~/fv_keystore
    ros2 security create_enclave ~/fv_keystore /fuel_valve/controller      # one per node
    ros2 security create_permission ~/fv_keystore /fuel_valve/controller config/sros2/policy.xml
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

from ..common import contract
from ..common.config_dir import default_config_dir

#: the suite's nodes, in enclave order; each runs in enclave ``/<namespace>/<node>``
SUITE_NODES = ("plant", "controller", "demand", "recorder")
#: SROS2 policy format version (sros2/policy/schemas/policy.xsd: fixed)
POLICY_VERSION = "0.2.0"
#: published by rcl itself, not by an rclpy publisher object (sros2 common/node/logging.xml)
RCL_PUBLISHED = ("/rosout",)
#: published by rcl_lifecycle for a managed node (sros2 common/lifecycle_node.xml)
LIFECYCLE_PUBLISHED = "~/transition_event"
DEFAULT_NAMESPACE = "/fuel_valve"


def policy_path() -> Path:
    """The policy the repository keeps: ``config/sros2/policy.xml``."""
    return default_config_dir() / "sros2" / "policy.xml"


def relative_name(fqn: str, namespace: str, node: str) -> str:
    """``fqn`` as an sros2 policy expression for node ``node`` in ``namespace`` (the rule of
    ``ros2 security generate_policy``): ``~/x`` below the node, relative below the namespace,
    absolute otherwise."""
    ns = namespace.rstrip("/") or "/"
    node_fqn = (ns if ns != "/" else "") + "/" + node
    if fqn.startswith(node_fqn + "/"):
        return "~" + fqn[len(node_fqn):]
    if ns != "/" and fqn.startswith(ns + "/"):
        return fqn[len(ns) + 1:]
    if ns == "/" and fqn.count("/") == 1:
        return fqn[1:]
    return fqn


def node_endpoints(node) -> dict[str, set[str]]:
    """``{publish, subscribe, reply, request: {fully qualified names}}`` of an rclpy node, from
    its public endpoint lists (plus what rcl publishes for it), names expanded and remapped as
    the node's own arguments make them (``~``, namespace, ``-r`` rules)."""
    from rclpy.lifecycle import LifecycleNode

    topic, service = node.resolve_topic_name, node.resolve_service_name
    rcl = set(RCL_PUBLISHED)
    if isinstance(node, LifecycleNode):     # rcl_lifecycle's own publisher (its services are rclpy's)
        rcl.add(topic(LIFECYCLE_PUBLISHED))
    return {"publish": {topic(p.topic_name) for p in node.publishers} | rcl,
            "subscribe": {topic(s.topic_name) for s in node.subscriptions},
            "reply": {service(s.srv_name) for s in node.services},
            "request": {service(c.srv_name) for c in node.clients}}


def _build_nodes(context, namespace: str, lockstep: bool, bag_dir: Path) -> dict:
    """The four suite nodes as the launcher starts them (namespace, clock wiring), in
    ``context``; lockstep adds the simulated clock's endpoints."""
    from rclpy.parameter import Parameter

    from fuel_valve_plant.ros.plant_node import PlantNode

    from ..ros.controller_node import ControllerNode
    from ..ros.demand_node import DemandNode
    from .launcher import clock_remap, lockstep_parameters
    from .recorder import Recorder

    classes = {"plant": PlantNode, "controller": ControllerNode, "demand": DemandNode, "recorder": Recorder}
    made = {}
    for name in SUITE_NODES:
        params = dict(lockstep_parameters(name, lockstep, participants=3))
        if name in ("plant", "controller", "demand"):
            params["lockstep"] = lockstep
        if name == "recorder":
            params.update(output=str(bag_dir / ("lockstep" if lockstep else "real_time")), overwrite=True)
        args = ["--ros-args", "-r", f"__ns:={namespace}", *clock_remap(namespace, lockstep)]
        made[name] = classes[name](context=context, cli_args=args,
                                   parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    return made


def suite_endpoints(namespace: str = DEFAULT_NAMESPACE) -> dict[str, dict[str, set[str]]]:
    """``{node: endpoints}`` of the suite's nodes in ``namespace``: the union over real time and
    lockstep.  Creates the nodes in a private rclpy context (no spinning, nothing published
    beyond discovery); needs rclpy."""
    import rclpy

    out: dict[str, dict[str, set[str]]] = {n: {"publish": set(), "subscribe": set(), "reply": set(),
                                               "request": set()} for n in SUITE_NODES}
    with tempfile.TemporaryDirectory(prefix="fuel_valve_policy_") as tmp:
        for lockstep in (False, True):
            context = rclpy.Context()
            rclpy.init(context=context)
            made = {}
            try:
                made = _build_nodes(context, namespace, lockstep, Path(tmp))
                for name, node in made.items():
                    for kind, names in node_endpoints(node).items():
                        out[name][kind] |= names
            finally:
                for node in made.values():
                    for end in ("stop", "finish"):      # the plant's tick thread; the bag
                        if callable(getattr(node, end, None)):
                            getattr(node, end)()
                    node.destroy_node()
                rclpy.shutdown(context=context)
    return out


def policy_xml(endpoints: dict[str, dict[str, set[str]]], namespace: str = DEFAULT_NAMESPACE) -> str:
    """The SROS2 policy (``policy.xsd`` 0.2.0) giving each node's enclave exactly its endpoints,
    names sorted so the text is stable."""
    ns = "/" + namespace.strip("/") if namespace.strip("/") else "/"
    root = ET.Element("policy", version=POLICY_VERSION)
    enclaves = ET.SubElement(root, "enclaves")
    for node in SUITE_NODES:
        enclave = ET.SubElement(enclaves, "enclave", path=(ns.rstrip("/") + "/" + node))
        profile = ET.SubElement(ET.SubElement(enclave, "profiles"), "profile", ns=ns, node=node)
        for kind, tag, rule in (("publish", "topic", "publish"), ("subscribe", "topic", "subscribe"),
                                ("reply", "service", "reply"), ("request", "service", "request")):
            names = sorted({relative_name(n, ns, node) for n in endpoints[node][kind]})
            if not names:
                continue
            group = ET.SubElement(profile, tag + "s", {rule: "ALLOW"})
            for name in names:
                ET.SubElement(group, tag).text = name
    ET.indent(root, space="  ")
    header = ("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
              "<!-- Generated by fuel_valve_sros2_policy from the suite's nodes (namespace "
              f"{ns}); do not edit by hand. -->\n")
    return header + ET.tostring(root, encoding="unicode") + "\n"


def publishers_of(policy_text: str, topic: str) -> set[str]:
    """Enclave paths whose profile may publish ``topic`` (a policy expression, e.g.
    ``current_command``) in ``policy_text``."""
    root = ET.fromstring(policy_text)
    return {enc.get("path") for enc in root.iter("enclave")
            for group in enc.iter("topics") if group.get("publish") == "ALLOW"
            for t in group.iter("topic") if t.text == topic}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="fuel_valve_sros2_policy", description=__doc__.split("\n\n")[0])
    parser.add_argument("--namespace", default=DEFAULT_NAMESPACE, help="the valve's namespace (default %(default)s)")
    parser.add_argument("--output", type=Path, default=None, help="where to write (default: config/sros2/policy.xml)")
    parser.add_argument("--check", action="store_true", help="exit 1 if config/sros2/policy.xml differs from the nodes")
    args = parser.parse_args(argv)
    text = policy_xml(suite_endpoints(args.namespace), args.namespace)
    if args.check:
        path = policy_path()
        if not path.is_file() or path.read_text() != text:
            print(f"out of date (run fuel_valve_sros2_policy): {path}", file=sys.stderr)
            return 1
        return 0
    path = args.output or policy_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

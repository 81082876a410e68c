"""Thin ROS 2 adapters over the core: controller and demand nodes, QoS and message helpers, loop I/O."""

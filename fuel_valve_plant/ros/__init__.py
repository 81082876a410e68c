"""The plant node: a thin ROS 2 adapter over the Plant."""

"""ROS-free plant core: the simulated actuator physics."""

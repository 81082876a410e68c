"""ROS-free control core: controllers, observers, limits, faults, metrics, scenarios, simulator."""

"""ROS-free controller core: nominal model, design, laws, observers, compensation, limits, driver (runs on real hardware without the simulated plant)."""

"""The plant node: a thin ROS 2 adapter over the Plant.

Importing it imports :mod:`fuel_valve_control.ros` first, before numpy: OpenBLAS's idle worker
spin limited in the plant process too (``fuel_valve_control.ros.limit_blas_spin``)."""
import fuel_valve_control.ros  # noqa: F401  (first: before numpy is loaded)

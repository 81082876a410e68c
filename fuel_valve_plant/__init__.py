"""The simulated fuel-valve actuator (SPEC §2): the stand-in for hardware.

Layers:

* :mod:`.physics` -- ROS-free plant core: :mod:`~.physics.plant` (the Plant object),
  :mod:`~.physics.kernel` (20 kHz fixed-step integrator, numba-compiled when available),
  :mod:`~.physics.params` (parameter schema), :mod:`~.physics.motor`, :mod:`~.physics.friction`,
  :mod:`~.physics.resolver`;
* :mod:`.ros` -- the ``plant`` node, a thin adapter over :class:`~.physics.plant.Plant`;
* :mod:`.tools` -- ``fuel_valve_datasheet`` (open-loop data-sheet experiments).

The plant imports only the shared interface of :mod:`fuel_valve_control.common` (contract,
parameter schema machinery, the friction law), never controller internals.
"""

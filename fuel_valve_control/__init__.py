"""The fuel-valve driver (SPEC §3, §4) and the suite's tools.

Layers:

* :mod:`.common` -- ROS-free pieces shared with the plant: the interface contract
  (:mod:`~.common.contract`), the parameter-schema machinery (:mod:`~.common.paramspec`),
  the friction law (:mod:`~.common.friction`);
* :mod:`.core` -- ROS-free controller core: nominal model, gain design, control laws,
  observers, friction compensation, current limiting and the valve driver (fault logic).
  It needs neither ROS nor the simulated plant: it is what runs on the real actuator;
* :mod:`.ros` -- thin ROS 2 adapters: the ``controller`` and ``demand`` nodes, QoS and
  message helpers, loop I/O;
* :mod:`.tools` -- offline simulator, demo launcher, recorder, report, metrics, plotting.
"""

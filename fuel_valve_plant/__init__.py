"""ROS-free simulation core of the fuel-valve actuator (SPEC §2).

Modules: :mod:`.plant` (the Plant object), :mod:`.kernel` (fixed-step physics),
:mod:`.plant_params` (parameters and validation), :mod:`.motor`, :mod:`.friction`,
:mod:`.resolver`, :mod:`.datasheet` (open-loop data-sheet experiments).
"""

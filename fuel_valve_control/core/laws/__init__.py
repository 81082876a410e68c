"""Position control laws (SPEC §3).  Each turns a demand and a resolver sample into a motor
torque request once per loop period; :class:`~..position_controller.PositionController` picks
one, converts torque to current and applies the current limits.

* :mod:`.base` — :class:`ControlLaw`, the interface every law implements;
* :mod:`.pid` — :class:`PIDLaw`, the existing analog driver (modes ``pi``, ``pi_dither``);
* :mod:`.state_feedback` — :class:`StateFeedbackLaw`, observer-based state feedback with
  friction compensation (the other modes);
* :mod:`.fine` — :class:`FinePositioningLaw`, ``observer_ff`` plus the fine-positioning stage
  (mode ``observer_fp``).
"""
from .base import ControlLaw
from .fine import FinePositioningLaw
from .pid import PIDLaw
from .state_feedback import StateFeedbackLaw

__all__ = ["ControlLaw", "FinePositioningLaw", "PIDLaw", "StateFeedbackLaw"]

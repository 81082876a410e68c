"""A real-time loop's late answers, emulated offline and seeded (docs/control_results.md §113).

On the nodes in real time the controller's answer to a resolver sample sometimes misses the drive's next tick
(0.7-2.5 % of the periods of ``scripts/demo.sh`` on this 2-core machine, stalls up to tens of ms).  For such a
period the drive applies what ``contract.current_without_command`` says: the last command again, or the fallback
current the controller has set (``contract.CURRENT_FALLBACK``).  The fine stage's preloads and pulses are timed
open-loop torques, so a held kick is a longer kick: the main job's real-time overshoots (§111.5b) came from that.
Offline and in lockstep the loop never misses a period, so the mechanism was visible only in noisy real-time runs;
this module makes it a seeded, repeatable experiment.

Model (:class:`LoopStalls`), two kinds of stall, each starting in a period with its own probability and lasting
``L`` periods, ``L`` log-uniform on 1 .. its longest:

* *transit* (``transit_rate``, ``transit_max``): the controller runs on time, but its commands reach the drive late
  (on the nodes: the plant process's command callback waits behind its own tick thread, the transport, the
  scheduler).  The controller does not know: its law believes each command acted.  ``demo.sh`` on this machine,
  20 s: 86 commands acted longer than two periods, the longest 5.0 ms, while the controller saw its loop late 5
  times.  When the commands arrive again the drive takes the newest (keep-last-1).
* *controller* (``controller_rate``, ``controller_max``): the controller is not scheduled.  It does not run; when
  it wakes it reads the newest sample, and the driver is told its stamp (``ValveDriver.loop_timing``, no transport
  delay): a gap beyond ``fine.late_loop_s`` marks the loop late, as on the nodes.

During either, the drive (:class:`StalledDrive`, the plant node's rules) applies its no-command current, and after
``command_timeout_periods`` without a command it switches itself off (its watchdog) until the controller re-enables
it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..common import contract


@dataclass(frozen=True)
class LoopStalls:
    """Seeded late answers of the real-time loop (module docstring): per kind the probability that a stall starts in a
    period and its longest length (periods); ``command_timeout_periods``: the drive's command
    watchdog in periods (``command_timeout_s`` 5 ms at 1 kHz); ``fallback``: the drive honours the controller's
    fallback current (False: it holds the last command whatever the controller says, a drive without the feature)."""
    transit_rate: float = 0.004
    transit_max: int = 5
    controller_rate: float = 0.0003
    controller_max: int = 8
    seed: int = 0
    command_timeout_periods: int = 5
    fallback: bool = True

    def schedule(self, periods: int) -> tuple[np.ndarray, np.ndarray]:
        """Per period (bool arrays of ``periods``): whether the command does not reach the drive (either kind), and
        whether the controller does not run (its own stalls)."""
        rng = np.random.default_rng(self.seed)
        lost = np.zeros(periods, dtype=bool)
        asleep = np.zeros(periods, dtype=bool)
        for rate, longest, marks in ((self.transit_rate, self.transit_max, (lost,)),
                                     (self.controller_rate, self.controller_max, (lost, asleep))):
            starts = np.flatnonzero(rng.random(periods) < rate)
            lengths = np.floor(np.exp(rng.uniform(0.0, math.log(longest + 1), starts.size))).astype(int)
            for k, n in zip(starts, np.maximum(lengths, 1)):
                for m in marks:
                    m[k:k + n] = True
        return lost, asleep


class StalledDrive:
    """The plant node's command rules in real time (``plant_node``), offline: the last command, or the fallback, over
    a period without a command; the command watchdog; a tripped drive back on only when a ``drive_enable`` true
    reaches it -- the controller node publishes one on an enable edge and on a re-enable
    (``DriverOutput.reenable``); resumed commands alone do not.  ``benchmarks/vcpu_freezes.py`` runs its
    scripted freezes on it too (``test_held_command.py`` keeps its own: its traced drive trips late, at the stall's
    end, which no command timeout here reproduces)."""

    def __init__(self, stalls: LoopStalls):
        self.stalls = stalls
        self.current_a = 0.0
        self.enabled = False
        self.fallback_a: tuple[float, ...] = ()
        self.silent = 0                 # periods since the last command
        self.tripped = False
        self.trips = 0
        self.fallback_periods = 0
        self.reenable_pending = False   # a re-enable sent in a period whose command was late, not yet delivered
        self.enable_sent = False        # the drive_enable the controller last sent (an edge to true re-enables)

    def command(self, out) -> tuple[float, bool]:
        """A period the controller answered with ``out`` (a ``DriverOutput``): the current and enable applied."""
        self.silent = 0
        self.fallback(out.fallback_currents_a)
        reenable = out.enable and (out.reenable or self.reenable_pending or not self.enable_sent)
        self.reenable_pending, self.enable_sent = False, out.enable
        if self.tripped and not reenable:
            return 0.0, False           # off until re-enabled (resumed commands do not re-enable it)
        self.tripped = False
        self.current_a, self.enabled = out.current_a, out.enable
        return self.current_a, self.enabled

    def fallback(self, amps: tuple) -> None:
        """The controller's fallback schedule (A; empty: hold), honoured if ``LoopStalls.fallback`` (refused, as by
        the plant node, if not finite)."""
        self.fallback_a = tuple(amps) if self.stalls.fallback and contract.fallback_valid(amps) else ()

    def missed(self, out) -> tuple[float, bool]:
        """A period the controller answered with ``out`` whose command did not reach the drive in time (a transit
        stall): the no-command current and enable.  A re-enable in it is not lost: ``drive_enable`` is latched and
        reliable, so it arrives with the commands when they resume (the plant node then takes it; dropped, the
        drive stayed off until the driver sent it again ``DRIVE_BACK_TIMEOUT_S`` later, and the spring closed the
        valve: stall seed 97 of the start-up profile, a 1 % step read 2700 % overshoot)."""
        # (latched: the newest value wins -- a disable after it cancels it)
        self.reenable_pending = out.enable and (self.reenable_pending or out.reenable or not self.enable_sent)
        self.enable_sent = out.enable
        return self.no_command()

    def no_command(self) -> tuple[float, bool]:
        """A period without a command: the current and enable applied."""
        self.silent += 1
        if self.enabled and not self.tripped and self.silent > self.stalls.command_timeout_periods:
            self.tripped, self.enabled = True, False
            self.trips += 1
        if self.tripped:
            return 0.0, False
        if self.fallback_a:
            self.fallback_periods += 1
        self.current_a = contract.current_without_command(self.current_a, self.fallback_a, self.silent)
        return self.current_a, self.enabled

    @property
    def state(self) -> int:
        """The drive's state word (``contract.DRIVE_STATE_*``) the controller reads when it runs."""
        if self.tripped:
            return contract.DRIVE_STATE_WATCHDOG
        return contract.DRIVE_STATE_ENABLED if self.enabled else contract.DRIVE_STATE_DISABLED

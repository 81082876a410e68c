"""Test-side cache of simulated states: build an expensive state once (a driver and plant that
have already run a while), hand every test a copy of its own.

Why: hundreds of parametrised cases start from the same held loop; each building it again
costs 0.3-0.6 s of simulated control periods, a copy about 4 ms.  The original is never handed
out, so no test can change what the next one starts from.  ``copy.deepcopy``, not a pickle
round trip: a deep copy continues bit for bit as the original would
(``test_runtime_params.test_a_copied_held_loop_continues_as_a_fresh_run``); an unpickled
observer-mode driver drifted from a fresh run by 2e-15 A within 100 periods (measured), which
would make "identical to an unchanged run" comparisons meaningless.
"""
from __future__ import annotations

import copy
from typing import Any, Callable, Hashable


class Snapshots:
    """``Snapshots(build)``: ``self[key]`` is a fresh deep copy of ``build(key)``, built on first use."""

    def __init__(self, build: Callable[[Any], Any]):
        self._build = build
        self._originals: dict[Hashable, Any] = {}

    def __getitem__(self, key: Hashable):
        if key not in self._originals:
            self._originals[key] = self._build(key)
        return copy.deepcopy(self._originals[key])

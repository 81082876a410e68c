"""The look-ahead workers (test/prefetch.py) themselves: a forked worker must not run the
finalizers of garbage it inherits (stop 23: after a ROS module, rclpy objects left for the
collector killed the workers of the next look-ahead module -- BrokenProcessPool)."""
import gc
import os

from prefetch import Ahead


class _ParentOnly:
    """Dies with the process that finalizes it unless that is the process that made it (a
    finalizer that needs the parent's threads, like a DDS entity's)."""

    def __init__(self):
        self.pid = os.getpid()
        self.cycle = self             # only the cyclic collector frees it

    def __del__(self):
        if os.getpid() != self.pid:
            os._exit(70)


def _work(n: int) -> int:
    """A worker's run: long enough that the cyclic collector makes a full pass."""
    gc.collect()
    return n


def test_a_worker_does_not_finalize_the_garbage_it_inherits():
    held = [_ParentOnly() for _ in range(10)]
    gc.collect()                      # survivors: in the oldest generation, collected only by a full pass
    del held                          # ... now garbage there, as a torn-down module's nodes
    with Ahead(_work, [(1,), (2,)], jobs=2) as ahead:
        assert ahead.result(1) == 1 and ahead.result(2) == 2

"""Thin ROS 2 adapters over the core: controller and demand nodes, QoS and message helpers, loop I/O.

Importing this package (every node process does, the plant's too, before numpy is loaded) limits
OpenBLAS's idle spin, :func:`limit_blas_spin`."""
import os
import sys

#: OpenBLAS's idle spin of its worker threads, as the exponent it reads from
#: ``OPENBLAS_THREAD_TIMEOUT`` at load time: a worker busy-waits 2**n CPU cycles after each
#: threaded BLAS call before it sleeps.  OpenBLAS's default, 28, is ~0.11 s of a core at 2.4 GHz
#: (each of numpy's and scipy's OpenBLAS has a worker on this 2-core machine); 4, OpenBLAS's
#: least, is 16 cycles.  Why (docs/control_results.md section 107): the controller's gain
#: design at start-up (``ValveDriver(...)``) wakes scipy's worker, which then spun ~0.1 s at
#: the node's SCHED_FIFO priority while the controller's main thread ran on the other core --
#: the plant's tick thread (same priority) got no core for ~110 ms, and the armed controller
#: latched "no resolver sample for 1xx ms".  The spin length changes no result: the same
#: threads split the same products (only how long an idle worker waits before it sleeps).
BLAS_THREAD_TIMEOUT = 4
#: environment variable OpenBLAS reads (a value set by the user is kept)
BLAS_TIMEOUT_ENV = "OPENBLAS_THREAD_TIMEOUT"


def limit_blas_spin() -> bool:
    """Set :data:`BLAS_TIMEOUT_ENV` to :data:`BLAS_THREAD_TIMEOUT` unless already set (in this
    process and the processes it starts).  OpenBLAS reads it when it is loaded, so this must run
    before numpy / scipy are imported: returns whether it did (False: numpy was loaded already,
    this process keeps the spin it has)."""
    os.environ.setdefault(BLAS_TIMEOUT_ENV, str(BLAS_THREAD_TIMEOUT))
    return "numpy" not in sys.modules


#: whether :func:`limit_blas_spin` ran before numpy was loaded in this process (the node
#: processes: yes, test/test_nodes.py checks the three node entry points)
BLAS_SPIN_LIMITED = limit_blas_spin()

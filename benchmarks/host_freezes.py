#!/usr/bin/env python3
"""Freezes of this machine's CPUs that no priority inside it avoids: one SCHED_FIFO thread per
CPU (pinned, priority 50: above the suite's loop at 10) sleeps 1 ms at a time and records every
wake-up later than ``--threshold-ms``.

Why: the soak's drive watchdog trips all came with 6-9 ms silences of the controller *and* of
the other processes on its CPU, on a 100 ms wall-clock grid.  On a VM whose host deschedules
the vCPUs (steal time) this probe sees the same freezes; then no in-guest lever (SCHED_FIFO,
gc, affinity) can keep a 1 kHz loop inside a 5 ms watchdog, and the product has to ride through
the trips instead (ValveDriver's re-arm; benchmarks/vcpu_freezes.py).  Without root the probe
runs at normal priority (said in the output).

    python benchmarks/host_freezes.py [--seconds 60] [--threshold-ms 3]

Last line: one JSON object (per CPU: the freezes' wall-clock times and lengths, ms; the steal
time /proc/stat counted meanwhile, s).
"""
from __future__ import annotations

import argparse
import json
import os
import time


def steal_s() -> float | None:
    """Steal time of all CPUs so far (/proc/stat, USER_HZ ticks), s; None where unavailable."""
    try:
        fields = open("/proc/stat").readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


def probe(cpu: int, seconds: float, threshold_s: float, fifo: bool, fd: int) -> None:
    """Child process: sleep-until-next-ms on ``cpu``; writes one line per freeze to ``fd``."""
    os.sched_setaffinity(0, {cpu})
    if fifo:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))
        except OSError:
            pass
    end = time.monotonic() + seconds
    due = time.monotonic()
    while due < end:
        due += 0.001
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        late = time.monotonic() - due
        if late > threshold_s:
            os.write(fd, f"{cpu} {time.time():.4f} {late * 1e3:.2f}\n".encode())
            due = time.monotonic()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--threshold-ms", type=float, default=3.0)
    args = parser.parse_args()
    fifo = hasattr(os, "SCHED_FIFO") and os.geteuid() == 0
    read, write = os.pipe()
    steal0 = steal_s()
    children = []
    for cpu in sorted(os.sched_getaffinity(0)):
        pid = os.fork()
        if pid == 0:
            os.close(read)
            probe(cpu, args.seconds, args.threshold_ms * 1e-3, fifo, write)
            os._exit(0)
        children.append(pid)
    os.close(write)
    with os.fdopen(read) as fh:
        lines = fh.read().split("\n")
    for pid in children:
        os.waitpid(pid, 0)
    steal1 = steal_s()
    per_cpu: dict[str, list] = {}
    for line in filter(None, lines):
        cpu, wall, late = line.split()
        per_cpu.setdefault(f"cpu{cpu}", []).append([float(wall), float(late)])
        print(f"cpu{cpu}: woke {late} ms late at wall {wall} (phase in the 100 ms grid {float(wall) % 0.1 * 1e3:.1f} ms)")
    freezes = [f for v in per_cpu.values() for f in v]
    print(f"{len(freezes)} freezes > {args.threshold_ms:g} ms in {args.seconds:g} s on {len(children)} CPUs "
          f"({'SCHED_FIFO 50' if fifo else 'normal priority: not root'}); longest "
          f"{max((f[1] for f in freezes), default=0.0):.2f} ms; steal time meanwhile "
          f"{None if steal0 is None or steal1 is None else round(steal1 - steal0, 2)} s")
    print(json.dumps({"seconds": args.seconds, "threshold_ms": args.threshold_ms, "fifo": fifo,
                      "freezes": per_cpu, "steal_s": None if steal0 is None or steal1 is None else steal1 - steal0}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

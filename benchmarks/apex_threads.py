#!/usr/bin/env python3
"""Does the apex policy's choice depend on BLAS's thread count? (task h38x, docs §99)

Runs the same choices -- ``FinePositioner._choose_apex`` on ``--draws`` random stage states per level law (errors,
scatters, floors none / inside the law / beyond it, valve angles, both directions, the crossing guard; the C1 build,
the default) -- in one subprocess per ``--threads`` value with ``OPENBLAS_NUM_THREADS`` / ``OMP_NUM_THREADS`` /
``MKL_NUM_THREADS`` set to it (read by OpenBLAS when it loads: only a fresh process can change it), and compares
each choice's outcome (the return value and everything the choice sets on the stage: :data:`apex_choice.EFFECTS`)
by its repr, i.e. to the last bit.  Also the raw product the mixture law scored its "one more try" with in main
(``hit @ trunc.T``, 89 x 81 x 89, random inputs): its bytes' hash per thread count.  Prints per law the draws that
differ between thread counts; last line: one JSON object.

    python benchmarks/apex_threads.py [--draws 12] [--laws normal,mixture] [--threads 1,2,4] [--json PATH]
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _stage(law: str):
    from fuel_valve_control.core.params import CONTROLLER_SPEC
    from fuel_valve_control.core.position_controller import PositionController
    pc = PositionController(CONTROLLER_SPEC.defaults().replace({"mode": "observer_fp", "fine.apex_level_law": law}))
    return pc.law.fine, pc.model


def choices(laws: list[str], draws: int, seed: int = 38) -> dict:
    """{law: [repr of each draw's outcome]} in this process (its BLAS threads as the environment set them)."""
    import numpy as np
    from apex_choice import draw_try
    out, moves = {}, None
    for li, law in enumerate(laws):
        fine, model = _stage(law)
        if moves is not None and fine._moves is None:
            from fuel_valve_control.core.fine_positioning import _pulse_moves
            fine._moves = _pulse_moves(fine)
        rng = np.random.default_rng(seed)
        res = []
        for n in range(draws):
            d = 1 if n % 2 == 0 else -1
            p = model.pressure_max_kpa
            thl = float(rng.uniform(0.4, 0.6))
            phi_e, phi_b, _ = fine._twists(thl, p, d)
            apex = fine._choose_apex(*draw_try(fine, rng, n, d, p, thl, phi_e, phi_b))
            res.append(repr((apex, fine._apex_plan, fine._apex_kick, fine._apex_rise, fine._apex_last,
                             fine._apex_try)))
        out[law] = res
    return out


def raw_product(seed: int = 7, shape=(89, 81, 89)) -> str:
    """sha1 of ``hit @ trunc.T`` on random inputs of the mixture law's size (through BLAS)."""
    import numpy as np
    rng = np.random.default_rng(seed)
    hit = rng.uniform(0.0, 1.0, shape[:2])
    trunc = rng.uniform(0.0, 1.0, shape[1:][::-1])
    return hashlib.sha1((hit @ trunc.T).tobytes()).hexdigest()


def variant_env(variant: str) -> dict:
    """A variant's environment: "2" = 2 BLAS threads; "Haswell" = OpenBLAS's kernels for that core type
    (``OPENBLAS_CORETYPE``, as a machine of that kind would pick them) at the default threads; "noavx512" = numpy's
    own SIMD loops (exp, log, ...) without their AVX-512 versions (``NPY_DISABLE_CPU_FEATURES``, as a machine without
    AVX-512 runs them; only where numpy dispatched them)."""
    if variant.isdigit():
        return {v: variant for v in THREAD_VARS}
    if variant == "noavx512":
        return {"NPY_DISABLE_CPU_FEATURES": "AVX512_ICL X86_V4"}
    return {"OPENBLAS_CORETYPE": variant}


def start_in(variant: str, laws: list[str], draws: int) -> subprocess.Popen:
    env = {**os.environ, **variant_env(variant)}
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", "--laws", ",".join(laws), "--draws", str(draws)]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=str(ROOT))


def result_of(proc: subprocess.Popen) -> dict:
    out, err = proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"child failed ({proc.returncode}): {err[-2000:]}")
    return json.loads(out.strip().splitlines()[-1])


def compare(laws: list[str], draws: int, threads: list[str], parallel: int = 2) -> dict:
    """Each variant's (thread count's or core type's) choices (a subprocess each) against the first's: {law: [draws
    that differ]}, the raw product's hashes, the outcomes.  ``parallel`` subprocesses at a time."""
    got = {}
    for i in range(0, len(threads), max(parallel, 1)):
        procs = {t: start_in(t, laws, draws) for t in threads[i:i + max(parallel, 1)]}
        got.update({t: result_of(p) for t, p in procs.items()})
    ref = got[threads[0]]
    differ = {law: sorted({n for t in threads[1:] for n in range(draws)
                           if got[t]["choices"][law][n] != ref["choices"][law][n]}) for law in laws}
    return {"threads": threads, "draws": draws, "differ": differ,
            "raw_product_sha1": {t: got[t]["raw"] for t in threads},
            "chose": {law: sum("(None," not in c[:6] for c in ref["choices"][law]) for law in laws},
            "outcomes": {t: got[t]["choices"] for t in threads}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--draws", type=int, default=12)
    ap.add_argument("--laws", default="normal,mixture")
    ap.add_argument("--threads", default="1,2,4",
                    help="variants: BLAS thread counts, OpenBLAS core types, noavx512 (e.g. 1,2,4,Haswell,noavx512)")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    laws = a.laws.split(",")
    sys.path.insert(0, str(ROOT))
    if a.child:
        print(json.dumps({"choices": choices(laws, a.draws), "raw": raw_product()}))
        return 0
    res = compare(laws, a.draws, a.threads.split(","))
    for law in laws:
        print(f"{law}: {len(res['differ'][law])} of {a.draws} draws differ between BLAS variants "
              f"{res['threads']} ({res['chose'][law]} chose a try)")
    print("raw 89x81x89 product sha1 per variant:", res["raw_product_sha1"])
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))
    res.pop("outcomes")
    print(json.dumps(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())

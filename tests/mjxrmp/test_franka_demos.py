"""The Franka demonstration loader (mjxrmp/data/franka_demos.py, thesis §5.2.3)."""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mjxrmp  # noqa: F401  (XLA flags first)
from mjxrmp.data import franka_demos as fd
from mjxrmp.robots import franka

pytestmark = pytest.mark.skipif(not os.path.isdir(fd.DEFAULT_ROOT),
                                reason="Franka demonstrations not available")


@pytest.fixture(scope="module")
def drawer():
    return fd.load_task("drawer_closing", dt=0.1)


def test_shapes_dt_and_velocities(drawer):
    assert len(drawer) == 6
    for d in drawer:
        T = d.length
        assert d.q.shape == (T, 7) and d.qd.shape == (T, 7) and d.fingers.shape == (T, 2)
        assert d.points.shape == (T, 3, 3) and d.point_velocities.shape == (T, 3, 3)
        np.testing.assert_allclose(np.diff(d.t), 0.1, atol=1e-12)
        # explicit Euler with the forward differences reproduces the samples
        np.testing.assert_allclose(d.q[:-1] + 0.1 * d.qd[:-1], d.q[1:], atol=1e-12)
        np.testing.assert_allclose(d.qd[-1], 0.0)
        assert d.t[-1] < 12.0  # the drawer recordings last 8.4–9.5 s before trimming


def test_resampling_interpolates_the_raw_rows(drawer):
    raw = fd.read_raw(os.path.join(fd.DEFAULT_ROOT, "drawer_closing", "0.txt"))
    untrimmed = fd.load_task("drawer_closing", dt=0.05, trim_tol=None)[0]
    t = raw[:, 0] - raw[0, 0]
    for j in range(7):
        np.testing.assert_allclose(untrimmed.q[:, j], np.interp(untrimmed.t, t, raw[:, 1 + j]),
                                   atol=1e-12)
    # trimming removes the motionless head: the first step moves (almost) at once
    assert np.max(np.abs(drawer[0].q[2] - drawer[0].q[0])) > 1e-3


def test_control_points_are_fk_and_goals_are_final_points(drawer):
    for d in drawer[:2]:
        frames = jax.vmap(franka.link_frames)(jnp.asarray(d.q, jnp.float32))
        for k, name in enumerate(fd.control_point_names("hand")):
            np.testing.assert_allclose(d.points[:, k], np.asarray(frames[name][1]), atol=1e-6)
        np.testing.assert_allclose(d.goals, d.points[-1])
        final = np.asarray(fd.hand_points(jnp.asarray(d.q[-1], jnp.float32)))
        np.testing.assert_allclose(final, d.goals, atol=1e-6)
        # fingertips 2 × 0.04 m apart; centre 0.1034 m along the hand axis from their midpoint
        tips = np.linalg.norm(d.points[:, 1] - d.points[:, 2], axis=-1)
        np.testing.assert_allclose(tips, 2 * fd.MODEL_FINGER_WIDTH, atol=1e-5)
        mid = 0.5 * (d.points[:, 1] + d.points[:, 2])
        np.testing.assert_allclose(np.linalg.norm(mid - d.points[:, 0], axis=-1), 0.1034,
                                   atol=1e-5)


def test_stack_pads_with_zero_velocity_and_mask(drawer):
    s = fd.stack(drawer)
    T = max(d.length for d in drawer)
    assert s.q.shape == (6, T, 7) and s.mask.shape == (6, T) and s.goals.shape == (6, 3, 3)
    for i, d in enumerate(drawer):
        assert float(s.mask[i].sum()) == d.length
        np.testing.assert_allclose(s.q[i, d.length:], np.broadcast_to(d.q[-1], (T - d.length, 7)),
                                   atol=1e-6)
        assert float(jnp.abs(s.qd[i, d.length:]).sum()) == 0.0


def test_clear_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        fd.load_task("drawer_closing", tmp_path / "missing")
    with pytest.raises(ValueError, match="task must be one of"):
        fd.load_task("wiping")
    with pytest.raises(ValueError, match="dt must be"):
        fd.load_task("drawer_closing", dt=0.0)
    bad = tmp_path / "drawer_closing"
    bad.mkdir()
    (bad / "0.txt").write_text("0.0 1 2 3\n0.1 1 2 3\n")
    with pytest.raises(ValueError, match="10 columns"):
        fd.load_task("drawer_closing", tmp_path)
    (bad / "0.txt").write_text("0.0 " + "0 " * 7 + "0.04 0.04\n0.0 " + "0 " * 7 + "0.04 0.04\n")
    with pytest.raises(ValueError, match="time must increase"):
        fd.load_task("drawer_closing", tmp_path)
    (bad / "0.txt").write_text("".join(f"{t} " + "0 " * 7 + "0.01 0.01\n" for t in (0, 1)))
    with pytest.raises(ValueError, match="finger widths"):
        fd.load_task("drawer_closing", tmp_path)

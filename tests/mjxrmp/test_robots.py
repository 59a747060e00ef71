"""Robot kinematics (docs/design.md §4.2): Franka DH chain, planar 3-link, and their MJCF/MJX twins.

The Franka chain is checked against an independent float64 NumPy formulation that composes 4×4
homogeneous matrices ``RotX(α) · TransX(a) · RotZ(q) · TransZ(d)`` literally; MJX kinematics of
the generated MJCF must reproduce every named frame. Compiled functions are module-level and
shared between tests.
"""

from __future__ import annotations

import ast
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

import mjxrmp  # noqa: F401  (sets the XLA:CPU flag MJX needs before any JAX computation)
from mjxrmp.robots import FRANKA, THREE_LINK, Robot, franka, get, mjcf, three_link

RNG = np.random.default_rng(20261101)
N_CONFIGS = 20
TOL = 1e-5  # metres (float32 JAX vs float64 NumPy / float32 MJX)


# --------------------------------------------------------------------------- NumPy reference


def _rot_x(t: float) -> np.ndarray:
    c, s = math.cos(t), math.sin(t)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]], dtype=np.float64)


def _rot_z(t: float) -> np.ndarray:
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=np.float64)


def _trans(x: float, y: float, z: float) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = (x, y, z)
    return t


# The DH table restated here (not imported) so the reference is independent of franka.py.
_REF_DH = [
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -math.pi / 2),
    (0.0, 0.316, math.pi / 2),
    (0.0825, 0.0, math.pi / 2),
    (-0.0825, 0.384, -math.pi / 2),
    (0.0, 0.0, math.pi / 2),
    (0.088, 0.0, math.pi / 2),
    (0.0, 0.107, 0.0),  # flange, no joint
]
_REF_OFFSETS = [  # (name, parent, translation in the parent frame)
    ("forearm_end_pt", "link4", (-0.09, 0.02, 0.0)),
    ("forearm_mid_pt", "forearm_end_pt", (0.0, 0.175, 0.0)),
    ("forearm_mid_pt_shifted", "forearm_mid_pt", (0.0, 0.0, -0.05)),
    ("forearm_distal", "link5", (0.0, 0.1, 0.0)),
    ("wrist_end_pt", "link7", (0.0, 0.0, -0.07)),
    ("face_left", "hand", (0.0, 0.07, 0.04)),
    ("face_right", "hand", (0.0, -0.07, 0.04)),
    ("face_back_left", "hand", (0.0, 0.07, 0.0)),
    ("face_back_right", "hand", (0.0, -0.07, 0.0)),
    ("left_finger", "hand", (0.0, 0.03999065, 0.0584)),
    ("right_finger", "hand", (0.0, -0.03999065, 0.0584)),
    ("left_fingertip", "left_finger", (0.0, 0.0, 0.045)),
    ("right_fingertip", "right_finger", (0.0, 0.0, 0.045)),
    ("grasp_target", "hand", (0.0, 0.0, 0.105)),
]
_REF_SEGMENTS = [
    ("link1", "link3", 10, 0.1),
    ("forearm_end_pt", "forearm_mid_pt", 5, 0.1),
    ("forearm_mid_pt_shifted", "forearm_distal", 5, 0.075),
    ("wrist_end_pt", "link8", 8, 0.05),
    ("face_back_left", "face_back_right", 5, 0.03),
    ("face_left", "face_right", 5, 0.02),
    ("hand", "left_fingertip", 5, 0.01),
    ("hand", "right_fingertip", 5, 0.01),
]


def reference_frames(q: np.ndarray) -> dict[str, np.ndarray]:
    """4×4 homogeneous transforms of every named Franka frame, float64."""
    t = np.eye(4)
    out = {"link0": t}
    for i, (a, d, alpha) in enumerate(_REF_DH):
        qi = float(q[i]) if i < 7 else 0.0
        t = t @ _rot_x(alpha) @ _trans(a, 0, 0) @ _rot_z(qi) @ _trans(0, 0, d)
        out[f"link{i + 1}"] = t
    out["hand"] = out["link8"] @ _rot_z(-math.pi / 4)
    for name, parent, offset in _REF_OFFSETS:
        out[name] = out[parent] @ _trans(*offset)
    return out


def reference_control_points(q: np.ndarray) -> np.ndarray:
    """The 48 control points by an explicit loop over segments and points."""
    f = reference_frames(q)
    pts = []
    for start, end, n, _ in _REF_SEGMENTS:
        a, b = f[start][:3, 3], f[end][:3, 3]
        for i in range(1, n + 1):
            pts.append(a + (i / n) * (b - a))
    return np.array(pts)


# --------------------------------------------------------------------------- shared compiled fns

_franka_frames = jax.jit(jax.vmap(franka.link_frames))
_franka_cps = jax.jit(jax.vmap(franka.control_points))
_franka_ee = jax.jit(jax.vmap(franka.end_effector))
_three_cps = jax.jit(jax.vmap(three_link.control_points))
_three_ee = jax.jit(jax.vmap(three_link.end_effector))


def _random_franka_q(n: int) -> np.ndarray:
    return RNG.uniform(franka.Q_LOWER, franka.Q_UPPER, size=(n, 7))


@pytest.fixture(scope="module")
def franka_qs() -> np.ndarray:
    qs = _random_franka_q(N_CONFIGS)
    qs[0] = 0.0  # q = 0 lies inside the limits except at j4's upper bound (which is 0)
    qs[1] = franka.DEFAULT_Q
    return qs


def _mjx_sites(xml: str, qs: np.ndarray) -> tuple[mujoco.MjModel, np.ndarray, np.ndarray]:
    """Site positions/rotations from ``mjx.kinematics`` for a batch of configurations."""
    m = mujoco.MjModel.from_xml_string(xml)
    mx = mjx.put_model(m)
    d0 = mjx.make_data(mx)

    def kin(q: jax.Array) -> tuple[jax.Array, jax.Array]:
        d = mjx.kinematics(mx, d0.replace(qpos=q))
        return d.site_xpos, d.site_xmat

    pos, mat = jax.jit(jax.vmap(kin))(jnp.asarray(qs, dtype=jnp.float32))
    return m, np.asarray(pos), np.asarray(mat).reshape(len(qs), m.nsite, 3, 3)


# --------------------------------------------------------------------------- Franka


def test_franka_frames_match_independent_numpy_chain(franka_qs: np.ndarray) -> None:
    frames = _franka_frames(jnp.asarray(franka_qs, dtype=jnp.float32))
    assert set(frames) == set(franka.FRAME_NAMES)
    for k, q in enumerate(franka_qs):
        ref = reference_frames(q)
        assert set(ref) == set(franka.FRAME_NAMES)
        for name, t in ref.items():
            r, p = frames[name]
            np.testing.assert_allclose(np.asarray(p[k]), t[:3, 3], atol=TOL, err_msg=name)
            np.testing.assert_allclose(np.asarray(r[k]), t[:3, :3], atol=TOL, err_msg=name)


def test_franka_control_points_and_end_effector(franka_qs: np.ndarray) -> None:
    cps = np.asarray(_franka_cps(jnp.asarray(franka_qs, dtype=jnp.float32)))
    ee = np.asarray(_franka_ee(jnp.asarray(franka_qs, dtype=jnp.float32)))
    assert cps.shape == (N_CONFIGS, 48, 3)
    assert ee.shape == (N_CONFIGS, 3)
    for k, q in enumerate(franka_qs):
        np.testing.assert_allclose(cps[k], reference_control_points(q), atol=TOL)
        np.testing.assert_allclose(ee[k], reference_frames(q)["grasp_target"][:3, 3], atol=TOL)
    assert FRANKA.num_control_points == 48
    assert FRANKA.control_point_radii == tuple(r for _, _, n, r in _REF_SEGMENTS for _ in range(n))


def test_franka_known_values_at_zero() -> None:
    # At q = 0 the arm is straight up with the elbow offsets: joint origins at heights
    # 0.333 (j1, j2), 0.649 (j3, j4 at x = 0.0825), 1.033 (j5, j6; j7 at x = 0.088), and the
    # flange's z-axis points down, so the flange is 0.107 below j7 and the grasp target another
    # 0.105 lower. Verified against the NumPy chain in the previous tests.
    frames = franka.link_frames(jnp.zeros(7))
    expected = {
        "link1": (0.0, 0.0, 0.333),
        "link3": (0.0, 0.0, 0.649),
        "link4": (0.0825, 0.0, 0.649),
        "link5": (0.0, 0.0, 1.033),
        "link7": (0.088, 0.0, 1.033),
        "link8": (0.088, 0.0, 0.333 + 0.316 + 0.384 - 0.107),
        "grasp_target": (0.088, 0.0, 0.926 - 0.105),
    }
    for name, p in expected.items():
        np.testing.assert_allclose(np.asarray(frames[name][1]), p, atol=1e-6, err_msg=name)
    np.testing.assert_allclose(
        np.asarray(frames["link8"][0]), np.diag([1.0, -1.0, -1.0]), atol=1e-6
    )
    np.testing.assert_allclose(
        np.asarray(franka.end_effector(jnp.zeros(7))), expected["grasp_target"], atol=1e-6
    )


def test_franka_jacobian_matches_finite_differences() -> None:
    q = np.asarray(franka.DEFAULT_Q)
    jac = np.asarray(jax.jacfwd(franka.end_effector)(jnp.asarray(q, dtype=jnp.float32)))
    h = 1e-6
    fd = np.stack(
        [
            (
                reference_frames(q + h * e)["grasp_target"][:3, 3]
                - reference_frames(q - h * e)["grasp_target"][:3, 3]
            )
            / (2 * h)
            for e in np.eye(7)
        ],
        axis=1,
    )
    np.testing.assert_allclose(jac, fd, atol=1e-5)


def test_franka_robot_fields() -> None:
    assert isinstance(FRANKA, Robot)
    assert (FRANKA.name, FRANKA.dof, FRANKA.workspace_dim) == ("franka", 7, 3)
    lo, hi = np.array(FRANKA.q_lower), np.array(FRANKA.q_upper)
    mlo, mhi = np.array(franka.MANUFACTURER_Q_LOWER), np.array(franka.MANUFACTURER_Q_UPPER)
    assert lo.shape == hi.shape == (7,)
    assert np.all(lo < hi) and np.all(mlo < mhi)
    assert np.all(lo <= mlo) and np.all(mhi <= hi)  # the manufacturer's limits are tighter
    q0 = np.array(FRANKA.default_q)
    assert np.all(mlo < q0) and np.all(q0 < mhi)
    assert FRANKA.qd_max == (2.175,) * 4 + (2.61,) * 3
    assert len(FRANKA.control_point_radii) == 48


# --------------------------------------------------------------------------- planar 3-link


def test_three_link_closed_form() -> None:
    qs = RNG.uniform(-math.pi, math.pi, size=(N_CONFIGS, 3))
    cps = np.asarray(_three_cps(jnp.asarray(qs, dtype=jnp.float32)))
    ee = np.asarray(_three_ee(jnp.asarray(qs, dtype=jnp.float32)))
    assert cps.shape == (N_CONFIGS, 15, 2)
    for k, q in enumerate(qs):
        th = np.cumsum(q)
        step = 0.25 * np.stack([np.cos(th), np.sin(th)], axis=1)
        np.testing.assert_allclose(ee[k], step.sum(axis=0), atol=TOL)
        base = np.concatenate([np.zeros((1, 2)), np.cumsum(step, axis=0)])[:3]
        ref = [base[j] + (i / 5) * step[j] for j in range(3) for i in range(1, 6)]
        np.testing.assert_allclose(cps[k], np.array(ref), atol=TOL)


def test_three_link_robot_fields() -> None:
    r = THREE_LINK
    assert (r.name, r.dof, r.workspace_dim, r.num_control_points) == ("three_link", 3, 2, 15)
    assert r.q_lower == (-math.inf,) * 3 and r.q_upper == (math.inf,) * 3
    assert r.qd_max == (1.0,) * 3
    assert r.control_point_radii == (0.025,) * 15


def test_get() -> None:
    assert get("franka") is FRANKA
    assert get("three_link") is THREE_LINK
    with pytest.raises(ValueError, match=r"name='ur5'.*franka.*three_link"):
        get("ur5")


# --------------------------------------------------------------------------- MJCF / MJX


def test_mjcf_package_does_not_import_mujoco() -> None:
    files = sorted(Path(mjcf.__file__).parent.glob("*.py"))
    assert len(files) >= 4
    for path in files:
        tree = ast.parse(path.read_text())
        imported = [
            alias.name
            for node in ast.walk(tree)
            if isinstance(node, ast.Import)
            for alias in node.names
        ] + [node.module or "" for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)]
        assert not any(name.split(".")[0] == "mujoco" for name in imported), path.name


def test_franka_mjx_kinematics_equals_jax(franka_qs: np.ndarray) -> None:
    xml = mjcf.franka_mjcf()
    m, pos, mat = _mjx_sites(xml, franka_qs)
    assert m.nq == m.nv == 7 and m.nu == 14
    for i, j in enumerate(mjcf.joint_names("franka")):
        jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j)
        assert jid == i
        np.testing.assert_allclose(m.jnt_range[jid], (franka.Q_LOWER[i], franka.Q_UPPER[i]))
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(m.nu)]
    assert tuple(names) == mjcf.actuator_names("franka")
    assert set(mjcf.site_names("franka")) == {*franka.FRAME_NAMES, "end_effector"}

    frames = _franka_frames(jnp.asarray(franka_qs, dtype=jnp.float32))
    ee = np.asarray(_franka_ee(jnp.asarray(franka_qs, dtype=jnp.float32)))
    for name in franka.FRAME_NAMES:
        sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name)
        r, p = frames[name]
        np.testing.assert_allclose(pos[:, sid], np.asarray(p), atol=TOL, err_msg=name)
        np.testing.assert_allclose(mat[:, sid], np.asarray(r), atol=TOL, err_msg=name)
    sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "end_effector")
    np.testing.assert_allclose(pos[:, sid], ee, atol=TOL)


def test_three_link_mjx_kinematics_equals_jax() -> None:
    qs = RNG.uniform(-math.pi, math.pi, size=(N_CONFIGS, 3))
    m, pos, _ = _mjx_sites(mjcf.three_link_mjcf(), qs)
    assert m.nq == 3 and m.nu == 6
    assert tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_SITE, i) for i in range(m.nsite)) == (
        mjcf.site_names("three_link")
    )
    joints = np.stack([np.asarray(three_link.joint_positions(jnp.asarray(q))) for q in qs])
    np.testing.assert_allclose(pos[:, :, :2], joints, atol=TOL)
    heights = (*three_link.LINK_HEIGHTS, three_link.LINK_HEIGHTS[-1])
    np.testing.assert_allclose(pos[:, :, 2], np.broadcast_to(heights, (N_CONFIGS, 4)), atol=TOL)


def test_mjcf_options() -> None:
    m = mujoco.MjModel.from_xml_string(mjcf.franka_mjcf(actuators=False, floor=False))
    assert m.nu == 0 and m.ngeom > 0
    assert m.opt.timestep == pytest.approx(1 / 240)
    assert np.all(m.geom_contype == 0) and np.all(m.geom_conaffinity == 0)
    extra = '<body name="ball" mocap="true"><geom type="sphere" size="0.05"/></body>'
    m = mujoco.MjModel.from_xml_string(mjcf.three_link_mjcf(worldbody_extra=extra, kp=(1, 2, 3)))
    assert m.nmocap == 1 and np.all(m.geom_contype == 0)
    np.testing.assert_allclose(m.actuator_gainprm[:3, 0], (1, 2, 3))
    mjx.put_model(m)
    with pytest.raises(ValueError, match="kp"):
        mjcf.franka_mjcf(kp=(1.0, 2.0))
    with pytest.raises(ValueError, match="robot_name"):
        mjcf.joint_names("ur5")


def test_franka_servo_holds_and_stays_finite() -> None:
    """With gravity compensation the PD servo holds the default pose (MuJoCo C, 1 s)."""
    m = mujoco.MjModel.from_xml_string(mjcf.franka_mjcf())
    d = mujoco.MjData(m)
    q0 = np.array(franka.DEFAULT_Q)
    d.qpos[:] = q0 + 0.05
    d.ctrl[:7] = q0
    for _ in range(240):
        mujoco.mj_step(m, d)
    assert np.all(np.isfinite(d.qpos))
    np.testing.assert_allclose(d.qpos, q0, atol=1e-3)

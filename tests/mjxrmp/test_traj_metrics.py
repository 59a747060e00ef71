"""Trajectory metrics (mjxrmp.metrics.trajectory): hand-computed cases, properties, JAX vs NumPy."""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import mjxrmp  # noqa: F401  (XLA flags first)
from mjxrmp.metrics import trajectory as tm

NUMPY_METRICS = {
    "rmse": tm.rmse,
    "mean_error": tm.mean_error,
    "dtw": tm.dtw,
    "dtw_normalized": tm.dtw_normalized,
    "frechet": tm.frechet,
    "swept_error_area": tm.swept_error_area,
    "final_point_error": tm.final_point_error,
}
JAX_METRICS = {
    "rmse": tm.rmse_jax,
    "mean_error": tm.mean_error_jax,
    "dtw": tm.dtw_jax,
    "dtw_normalized": tm.dtw_normalized_jax,
    "frechet": tm.frechet_jax,
    "swept_error_area": tm.swept_error_area_jax,
    "final_point_error": tm.final_point_error_jax,
}


def _line(n: int, length: float = 2.0, y: float = 0.0) -> np.ndarray:
    return np.stack([np.linspace(0.0, length, n), np.full(n, y)], axis=1)


def _naive_dp(a, b, kind):
    """Textbook double loop (test oracle for the wavefront implementations)."""
    n, m = len(a), len(b)
    table = np.full((n, m), np.inf)
    for i in range(n):
        for j in range(m):
            cost = np.linalg.norm(a[i] - b[j])
            if i == j == 0:
                table[i, j] = cost
                continue
            prev = min(
                table[i - 1, j - 1] if i and j else np.inf,
                table[i - 1, j] if i else np.inf,
                table[i, j - 1] if j else np.inf,
            )
            table[i, j] = cost + prev if kind == "dtw" else max(cost, prev)
    return table[-1, -1]


# ---------------------------------------------------------------------------------------------
# Hand-computed cases
# ---------------------------------------------------------------------------------------------


def test_identical_curves_score_zero():
    a = np.stack([np.cos(np.linspace(0, 3, 17)), np.sin(np.linspace(0, 3, 17))], axis=1)
    for name, fn in NUMPY_METRICS.items():
        assert fn(a, a) == pytest.approx(0.0, abs=1e-12), name
    assert tm.dtw_path(a, a)[1].tolist() == [[i, i] for i in range(17)]


def test_parallel_shift():
    """Segment of length L vs its parallel shift by δ: RMSE = Fréchet = DTW/K = δ, area δ·L."""
    length, delta, n = 2.0, 0.3, 11
    a, b = _line(n, length), _line(n, length, y=delta)
    assert tm.rmse(a, b) == pytest.approx(delta)
    assert tm.mean_error(a, b) == pytest.approx(delta)
    assert tm.frechet(a, b) == pytest.approx(delta)
    assert tm.dtw(a, b) == pytest.approx(n * delta)
    assert tm.dtw_normalized(a, b) == pytest.approx(delta)
    assert tm.swept_error_area(a, b) == pytest.approx(delta * length)
    assert tm.final_point_error(a, b) == pytest.approx(delta)
    # Different sampling of the same two lines: resampled in normalised time, same RMSE/area.
    b_fine = _line(2 * n + 3, length, y=delta)
    assert tm.rmse(a, b_fine) == pytest.approx(delta)
    assert tm.swept_error_area(a, b_fine) == pytest.approx(delta * length)


def test_dtw_and_frechet_by_hand():
    # a = 0, 1, 3 and b = 0, 2, 3 on a line. Cost |a_i - b_j| rows: [0 2 3], [1 1 2], [3 1 0];
    # DTW table rows [0 2 5], [1 1 3], [4 2 1] -> 1 along the diagonal (K = 3); Fréchet 1.
    a = np.array([[0.0], [1.0], [3.0]])
    b = np.array([[0.0], [2.0], [3.0]])
    cost, path = tm.dtw_path(a, b)
    assert cost == pytest.approx(1.0)
    assert path.tolist() == [[0, 0], [1, 1], [2, 2]]
    assert tm.dtw_normalized(a, b) == pytest.approx(1.0 / 3.0)
    assert tm.frechet(a, b) == pytest.approx(1.0)
    # a = 0, 1, 2, 3 and b = 0, 3: optimal path (0,0) (1,0) (2,1) (3,1), costs 0 1 1 0.
    a = np.array([[0.0], [1.0], [2.0], [3.0]])
    b = np.array([[0.0], [3.0]])
    cost, path = tm.dtw_path(a, b)
    assert cost == pytest.approx(2.0)
    assert path.tolist() == [[0, 0], [1, 0], [2, 1], [3, 1]]
    assert tm.dtw_normalized(a, b) == pytest.approx(0.5)
    assert tm.frechet(a, b) == pytest.approx(1.0)


def test_time_warping_dtw_below_rmse():
    # Repeating samples is a pure time warp: DTW and Fréchet ignore it, RMSE does not.
    a = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 1.0], [3.0, 1.0]])
    b = a[[0, 0, 0, 1, 2, 3]]
    assert tm.dtw(a, b) == pytest.approx(0.0)
    assert tm.frechet(a, b) == pytest.approx(0.0)
    assert tm.rmse(a, b) > 0.3
    # The same curve sampled late by 5 of 60 steps: DTW per step is far below RMSE.
    t = np.linspace(0.0, 1.0, 60)
    curve = lambda s: np.stack([np.cos(2 * np.pi * s), np.sin(4 * np.pi * s)], axis=1)  # noqa: E731
    early, late = curve(t), curve(np.clip(t - 5 / 59, 0.0, 1.0))
    assert tm.dtw_normalized(early, late) < 0.25 * tm.rmse(early, late)
    assert tm.dtw(early, late) < 0.25 * 60 * tm.mean_error(early, late)


def test_swept_area_counts_both_lobes_where_curves_cross():
    # (0,0)->(2,0) vs (0,1)->(2,-1) cross at (1,0): two triangles of area 1/2 each. The plain
    # shoelace formula of the self-intersecting quadrilateral would give 0.
    a = np.array([[0.0, 0.0], [2.0, 0.0]])
    b = np.array([[0.0, 1.0], [2.0, -1.0]])
    assert tm.swept_error_area(a, b) == pytest.approx(1.0)
    # Rungs crossing (correspondence twisted) is the other bow tie: lobes 1/2 + 1/2 again.
    b_twisted = np.array([[2.0, 1.0], [0.0, 1.0]])
    assert tm.swept_error_area(a, b_twisted) == pytest.approx(1.0)
    # A non-convex (simple) quadrilateral: exact shoelace area.
    a = np.array([[0.0, 0.0], [4.0, 0.0]])
    b = np.array([[2.0, 1.0], [4.0, 4.0]])  # dart (0,0) (4,0) (4,4) (2,1): 8 - 2 = 6
    assert tm.swept_error_area(a, b) == pytest.approx(6.0)


def _winding_area(quad: np.ndarray, n: int = 300) -> float:
    """∫ |winding number| over a grid (brute-force check of the quadrilateral areas)."""
    lo, hi = quad.min(0), quad.max(0)
    xs, ys = np.meshgrid(np.linspace(lo[0], hi[0], n), np.linspace(lo[1], hi[1], n))
    pts = np.stack([xs.ravel(), ys.ravel()], axis=1)
    winding = np.zeros(len(pts))
    for k in range(4):
        p, q = quad[k] - pts, quad[(k + 1) % 4] - pts
        turn = np.arctan2(q[:, 1], q[:, 0]) - np.arctan2(p[:, 1], p[:, 0])
        winding += (turn + np.pi) % (2 * np.pi) - np.pi
    return float(np.mean(np.abs(np.round(winding / (2 * np.pi)))) * np.prod(hi - lo))


def test_quadrilateral_areas_match_winding_number_integral():
    rng = np.random.default_rng(3)
    for _ in range(6):
        q = rng.normal(size=(4, 2))
        area = tm.swept_error_area(q[[0, 1]], q[[3, 2]])  # quad a0 a1 b1 b0
        assert area == pytest.approx(_winding_area(q), rel=0.03)


def test_wavefront_dp_matches_double_loop():
    rng = np.random.default_rng(0)
    for n, m in [(1, 1), (1, 6), (7, 3), (9, 9)]:
        a, b = rng.normal(size=(n, 2)), rng.normal(size=(m, 2))
        assert tm.dtw(a, b) == pytest.approx(_naive_dp(a, b, "dtw"))
        assert tm.frechet(a, b) == pytest.approx(_naive_dp(a, b, "frechet"))
        cost, path = tm.dtw_path(a, b)
        steps = np.linalg.norm(a[path[:, 0]] - b[path[:, 1]], axis=1)
        assert cost == pytest.approx(steps.sum())
        assert max(n, m) <= len(path) <= n + m - 1
        assert np.all(np.diff(path, axis=0) >= 0) and np.all(np.diff(path, axis=0).sum(1) >= 1)
        assert tm.dtw_normalized(a, b) == pytest.approx(cost / len(path))


def test_resample():
    x = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 3.0]])
    by_time = tm.resample(x, 5)
    np.testing.assert_allclose(by_time, [[0, 0], [0.5, 0], [1, 0], [1, 1.5], [1, 3]])
    by_arc = tm.resample(np.insert(x, 1, x[0], axis=0), 5, by="arclength")  # zero step dropped
    np.testing.assert_allclose(by_arc, [[0, 0], [1, 0], [1, 1], [1, 2], [1, 3]])
    np.testing.assert_allclose(tm.resample(x[:1], 3), np.repeat(x[:1], 3, axis=0))
    np.testing.assert_allclose(tm.resample_jax(jnp.asarray(x), 5), by_time, atol=1e-6)


# ---------------------------------------------------------------------------------------------
# Properties
# ---------------------------------------------------------------------------------------------

_traj = st.integers(2, 7).flatmap(
    lambda n: hnp.arrays(np.float64, (n, 2), elements=st.floats(-5, 5, width=32))
)


@settings(max_examples=15, deadline=None)
@given(a=_traj, b=_traj)
def test_symmetry_and_bounds(a, b):
    for name in ("rmse", "mean_error", "dtw", "frechet", "swept_error_area", "final_point_error"):
        fn = NUMPY_METRICS[name]
        assert fn(a, b) == pytest.approx(fn(b, a), rel=1e-9, abs=1e-9), name
    assert tm.rmse(a, b) >= tm.mean_error(a, b) - 1e-12
    frechet = tm.frechet(a, b)
    assert frechet >= max(np.linalg.norm(a[0] - b[0]), np.linalg.norm(a[-1] - b[-1])) - 1e-12
    if len(a) == len(b):  # the diagonal coupling is one candidate
        err = np.linalg.norm(a - b, axis=1)
        assert frechet <= err.max() + 1e-12
        assert tm.dtw(a, b) <= err.sum() + 1e-12


# ---------------------------------------------------------------------------------------------
# JAX agreement
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("shapes", [((13, 2), (9, 2)), ((12, 2), (12, 2))])
def test_jax_matches_numpy(shapes):
    rng = np.random.default_rng(sum(map(sum, shapes)))
    a, b = rng.normal(size=shapes[0]), rng.normal(size=shapes[1])
    with jax.enable_x64(True):
        for name, fn in JAX_METRICS.items():
            got = float(jax.jit(fn)(jnp.asarray(a), jnp.asarray(b)))
            assert got == pytest.approx(NUMPY_METRICS[name](a, b), rel=1e-10, abs=1e-12), name
    # Default float32 still agrees to single precision.
    assert float(tm.dtw_jax(a, b)) == pytest.approx(tm.dtw(a, b), rel=1e-5)


def test_jax_vmap_over_demonstrations():
    rng = np.random.default_rng(7)
    a, b = rng.normal(size=(4, 10, 2)), rng.normal(size=(4, 10, 2))
    batched = jax.jit(jax.vmap(lambda x, y: jnp.stack([tm.dtw_jax(x, y), tm.frechet_jax(x, y)])))
    got = np.asarray(batched(a, b))
    want = np.array([[tm.dtw(x, y), tm.frechet(x, y)] for x, y in zip(a, b, strict=True)])
    np.testing.assert_allclose(got, want, rtol=1e-5)


def test_all_metrics():
    a, b = _line(5), _line(5, y=0.5)
    out = tm.all_metrics(a, b)
    assert set(out) == set(NUMPY_METRICS)
    assert out["swept_error_area"] == pytest.approx(1.0)
    assert "swept_error_area" not in tm.all_metrics(np.zeros((4, 3)), np.ones((4, 3)))


# ---------------------------------------------------------------------------------------------
# Errors
# ---------------------------------------------------------------------------------------------


def test_bad_shapes_raise_clear_errors():
    good = np.zeros((5, 2))
    with pytest.raises(ValueError, match=r"a must be a trajectory of shape \(T, d\).*\(5,\)"):
        tm.rmse(np.zeros(5), good)
    with pytest.raises(ValueError, match=r"b must be a trajectory.*\(2, 5, 2\)"):
        tm.dtw(good, np.zeros((2, 5, 2)))
    with pytest.raises(ValueError, match="same dimension"):
        tm.frechet(good, np.zeros((5, 3)))
    with pytest.raises(ValueError, match="at least 1 sample"):
        tm.final_point_error(np.zeros((0, 2)), good)
    with pytest.raises(ValueError, match=r"2-D, shape \(T, 2\)"):
        tm.swept_error_area(np.zeros((5, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError, match="at least 2 sample"):
        tm.swept_error_area(np.zeros((1, 2)), good)
    with pytest.raises(ValueError, match="same dimension"):
        tm.dtw_jax(jnp.zeros((5, 2)), jnp.zeros((5, 3)))
    with pytest.raises(ValueError, match="num must be at least 1"):
        tm.resample(good, 0)
    with pytest.raises(ValueError, match="by must be"):
        tm.resample(good, 3, by="space")


# ---------------------------------------------------------------------------------------------
# Distance to demonstrated paths
# ---------------------------------------------------------------------------------------------


def test_distance_to_paths_by_hand():
    seg = np.array([[-1.0, 0.0], [1.0, 0.0]])
    x = np.array([[0.0, 1.0], [2.0, 0.0], [2.0, 1.0], [0.5, 0.0], [-3.0, -4.0]])
    np.testing.assert_allclose(tm.distance_to_paths(x, [seg]),
                               [1.0, 1.0, np.sqrt(2.0), 0.0, np.sqrt(4.0 + 16.0)])
    # the nearer of two paths; a one-sample path is a point; a repeated sample is harmless
    other = np.array([[2.0, 1.0]])
    repeated = np.array([[0.0, 3.0], [0.0, 3.0], [0.0, 5.0]])
    np.testing.assert_allclose(tm.distance_to_paths(x, [seg, other, repeated]),
                               [1.0, 1.0, 0.0, 0.0, np.sqrt(4.0 + 16.0)])


@settings(max_examples=25, deadline=None)
@given(hnp.arrays(np.float64, (6, 3), elements=st.floats(-1, 1)),
       hnp.arrays(np.float64, (4, 3), elements=st.floats(-1, 1)))
def test_distance_to_paths_matches_dense_sampling(x, path):
    """Exact projection vs the path sampled at 2001 points per segment (upper bound, close)."""
    u = np.linspace(0.0, 1.0, 2001)[:, None]
    dense = np.concatenate([a + u * (b - a) for a, b in itertools.pairwise(path)])
    brute = np.min(np.linalg.norm(x[:, None] - dense[None], axis=2), axis=1)
    exact = tm.distance_to_paths(x, [path])
    assert np.all(exact <= brute + 1e-12)
    np.testing.assert_allclose(exact, brute, atol=2e-3)


def test_distance_to_paths_bad_input():
    with pytest.raises(ValueError, match="paths must hold at least one path"):
        tm.distance_to_paths(np.zeros((3, 2)), [])
    with pytest.raises(ValueError, match=r"paths\[1\] must be 2-D"):
        tm.distance_to_paths(np.zeros((3, 2)), [np.zeros((2, 2)), np.zeros((2, 3))])
    with pytest.raises(ValueError, match="wrap a single path in a list"):
        tm.distance_to_paths(np.zeros((3, 2)), np.zeros((4, 2)))

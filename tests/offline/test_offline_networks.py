"""offline/learners/networks.py: Frobenius projection (ATAC's Proj_F, thesis Algorithm 3 line 7) and
Polyak averaging (line 11) against float64 NumPy; the Q ensemble and the state network."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from offline.learners.networks import (
    FROBENIUS_BOUND,
    QEnsemble,
    StateNet,
    polyak,
    project_frobenius,
)


def np_project(x: np.ndarray, bound: float) -> np.ndarray:
    """Per matrix (the last two axes) rescale to Frobenius norm <= bound, float64."""
    x = np.asarray(x, np.float64)
    norms = np.sqrt(np.sum(x * x, axis=(-2, -1), keepdims=True))
    return x * np.minimum(1.0, bound / np.maximum(norms, 1e-300))


@pytest.fixture(scope="module")
def ensemble_params():
    q = QEnsemble(num_critics=3, hidden_sizes=(8, 8))
    return q, jax.jit(q.init)(jax.random.key(0), jnp.zeros((1, 4)), jnp.zeros((1, 2)))


def test_projection_matches_numpy_per_member_biases_untouched(ensemble_params):
    _, params = ensemble_params
    big = jax.tree.map(lambda x: 3.0 * x + 0.5, params)  # biases non-zero, kernels large
    bound = 2.0
    out = project_frobenius(big, bound)
    flat_in = dict(jax.tree_util.tree_leaves_with_path(big))
    n_kernels = 0
    for path, y in jax.tree_util.tree_leaves_with_path(out):
        x = np.asarray(flat_in[path])
        if path[-1].key == "kernel":
            n_kernels += 1
            assert x.ndim == 3 and x.shape[0] == 3       # one matrix per ensemble member
            np.testing.assert_allclose(y, np_project(x, bound), rtol=2e-6, atol=1e-7)
            norms = np.linalg.norm(np.asarray(y, np.float64), axis=(1, 2))
            assert np.all(norms <= bound * (1 + 1e-6))
        else:
            np.testing.assert_array_equal(y, x)
    assert n_kernels == 3


def test_projection_keeps_small_kernels_and_mixed_members():
    k = np.stack([np.full((2, 2), 0.1), np.full((2, 2), 10.0)]).astype(np.float32)
    params = {"layer": {"kernel": jnp.asarray(k), "bias": jnp.ones(2)}}
    out = project_frobenius(params, 1.0)
    np.testing.assert_array_equal(out["layer"]["kernel"][0], k[0])     # inside: unchanged
    np.testing.assert_allclose(np.linalg.norm(out["layer"]["kernel"][1]), 1.0, rtol=1e-6)
    np.testing.assert_array_equal(out["layer"]["bias"], 1.0)
    assert FROBENIUS_BOUND == 100.0


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-50, 50, allow_nan=False, width=32), min_size=6, max_size=6),
       st.floats(0.1, 20.0))
def test_projection_invariants(values, bound):
    x = jnp.asarray(np.array(values, np.float32).reshape(2, 3))
    y = project_frobenius({"kernel": x}, bound)["kernel"]
    norm_x, norm_y = float(jnp.linalg.norm(x)), float(jnp.linalg.norm(y))
    assert norm_y <= bound * (1 + 1e-5)
    # Idempotent and direction preserving (a non-negative rescaling).
    np.testing.assert_allclose(project_frobenius({"kernel": y}, bound)["kernel"], y,
                               rtol=1e-5, atol=1e-6)
    if norm_x > 1e-6:
        np.testing.assert_allclose(np.asarray(y) * norm_x, np.asarray(x) * norm_y,
                                   rtol=1e-4, atol=1e-4 * max(norm_x, 1.0))


def test_polyak_matches_numpy(ensemble_params):
    _, params = ensemble_params
    online = jax.tree.map(lambda x: x + 1.0, params)
    tau = 0.3
    out = polyak(params, online, tau)
    for t, o, y in zip(jax.tree.leaves(params), jax.tree.leaves(online), jax.tree.leaves(out),
                       strict=True):
        ref = (1 - tau) * np.asarray(t, np.float64) + tau * np.asarray(o, np.float64)
        np.testing.assert_allclose(y, ref, rtol=1e-6, atol=1e-7)
    leaves_id = jax.tree.leaves(polyak(params, online, 0.0))
    for a, b in zip(leaves_id, jax.tree.leaves(params), strict=True):
        np.testing.assert_array_equal(a, b)


def test_q_ensemble_members_independent_and_shapes(ensemble_params):
    q, params = ensemble_params
    obs, act = jnp.ones((5, 4)), jnp.ones((5, 2))
    apply = jax.jit(q.apply)
    out = apply(params, obs, act)
    assert out.shape == (5, 3)
    assert len(np.unique(np.round(np.asarray(out[0]), 5))) == 3    # different initialisations
    # Changing member 1's parameters changes only column 1.
    bumped = jax.tree.map(lambda x: x.at[1].add(0.1), params)
    diff = np.abs(np.asarray(apply(bumped, obs, act) - out))
    assert np.all(diff[:, [0, 2]] == 0) and np.all(diff[:, 1] > 0)
    assert q.apply(params, obs[0], act[0]).shape == (3,)
    with pytest.raises(ValueError, match="batch shape"):
        q.apply(params, obs, act[:3])


def test_state_net_squeezes_single_output():
    for out_size, shape in ((1, (7,)), (3, (7, 3))):
        net = StateNet(out_size, hidden_sizes=(4,))
        shapes = jax.eval_shape(lambda net=net: net.apply(
            net.init(jax.random.key(1), jnp.zeros((1, 3))), jnp.ones((7, 3))))
        assert shapes.shape == shape

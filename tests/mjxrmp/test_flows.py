"""Euclideanizing flow (thesis §4.2.2, eqs 4.4–4.5): identity at init, exact inverse, Jacobian.

Compile time dominates on CPU, so a few small flows (3 coupling layers, 16 features) are shared by
all tests and every flow is evaluated through one cached, jitted function.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mjxrmp  # noqa: F401  (XLA flags first)
from mjxrmp.learned.flows import CONSTANTS, EuclideanizingFlow, coupling_mask, jacobian, subtask_map

SMALL = dict(num_layers=3, num_features=16, hidden_sizes=(16,))
#: Perturbation of every learnable parameter (``scale · N(0, 1)``): |s| of a few tenths per layer,
#: the map moves unit-scale points by O(0.1–1).
SCALE = 0.05


@pytest.fixture
def x64():
    jax.config.update("jax_enable_x64", True)
    yield
    jax.config.update("jax_enable_x64", False)


def make_flow(dim, net="rff", dtype="float32", **kw):
    return EuclideanizingFlow(dim=dim, net=net, param_dtype=jnp.dtype(dtype), **{**SMALL, **kw})


@functools.cache
def _init(flow):
    return flow.init(jax.random.key(0), jnp.zeros((flow.dim,), flow.param_dtype))


def perturbed(flow, seed, scale=SCALE):
    """The flow's initial variables with every learnable parameter moved by ``scale·N(0, 1)``
    (drawn on the host: no compilation)."""
    rng = np.random.default_rng(seed)
    variables = dict(_init(flow))
    variables["params"] = jax.tree.map(
        lambda p: p + jnp.asarray(scale * rng.standard_normal(p.shape), p.dtype),
        variables["params"])
    return variables


@functools.cache
def analysis(flow):
    """Jitted ``(variables, x (B, d)) -> dict`` of everything the tests look at."""

    def layer_by_layer(module, y):
        out = [y]
        for layer in module.layers:
            out.append(layer(out[-1])[0])
        return jnp.stack(out)

    def fn(variables, x):
        y, ld = flow.apply(variables, x, method="forward_and_log_det")
        x_back, ld_inv = flow.apply(variables, y, method="inverse_and_log_det")
        y_back = flow.apply(variables, flow.apply(variables, x, method="inverse"))
        return dict(y=y, ld=ld, x_back=x_back, ld_inv=ld_inv, y_back=y_back,
                    J=jacobian(flow, variables, x),
                    J_inv=jacobian(flow, variables, y, inverse=True),
                    layers=flow.apply(variables, x, method=layer_by_layer))

    return jax.jit(fn)


def test_defaults_follow_anchor_facts():
    """M = 10 layers, N = 200 features, l = 0.45, α ~ N(0, l⁻²), β ~ U[0, 2π), w = 0."""
    flow = EuclideanizingFlow(dim=2)
    assert (flow.num_layers, flow.num_features, flow.length_scale, flow.net) == (
        10, 200, 0.45, "rff")
    variables = flow.init(jax.random.key(0), jnp.zeros(2))
    consts = variables[CONSTANTS]
    assert len(consts) == 10
    alpha = consts["coupling_0"]["scale"]["alpha"]
    assert alpha.shape == (2, 200) and consts["coupling_0"]["scale"]["beta"].shape == (200,)
    alphas = np.concatenate([np.ravel(c[n]["alpha"]) for c in consts.values()
                             for n in ("scale", "translate")])
    betas = np.concatenate([np.ravel(c[n]["beta"]) for c in consts.values()
                            for n in ("scale", "translate")])
    assert abs(alphas.std() * 0.45 - 1.0) < 0.05  # 8000 draws
    assert betas.min() >= 0.0 and betas.max() < 2 * np.pi and abs(betas.mean() - np.pi) < 0.1
    # Every layer and each of its two nets has its own features.
    assert not np.allclose(alpha, consts["coupling_1"]["scale"]["alpha"])
    assert not np.allclose(alpha, consts["coupling_0"]["translate"]["alpha"])
    # The read-outs (the only learnable parameters) start at zero: the flow is the identity.
    assert all(np.all(p == 0) for p in jax.tree.leaves(variables["params"]))
    x = jnp.array([[0.3, -1.2], [2.0, 0.1]])
    np.testing.assert_array_equal(flow.apply(variables, x), x)


@pytest.mark.parametrize("net,dim,dtype", [("rff", 5, "float32"), ("mlp", 3, "float64")])
def test_identity_at_init(x64, net, dim, dtype):
    flow = make_flow(dim, net, dtype)
    x = np.random.default_rng(4).normal(size=(8, dim)).astype(dtype)
    out = analysis(flow)(_init(flow), x)
    for k in ("y", "x_back", "y_back"):
        np.testing.assert_array_equal(out[k], x)
    np.testing.assert_array_equal(out["ld"], 0.0)
    np.testing.assert_array_equal(out["ld_inv"], 0.0)
    np.testing.assert_array_equal(out["J"], np.broadcast_to(np.eye(dim), (8, dim, dim)))


def test_coupling_masks_alternate():
    assert coupling_mask(2, 0) == (False, True)
    assert coupling_mask(2, 1) == (True, False)
    assert coupling_mask(5, 0) == (False, True, False, True, False)
    for d in (2, 3, 5):
        for k in range(4):
            m = coupling_mask(d, k)
            assert any(m) and not all(m)
            assert coupling_mask(d, k + 1) == tuple(not b for b in m)


@pytest.mark.parametrize("net,dim,dtype", [("rff", 2, "float32"), ("rff", 2, "float64"),
                                           ("rff", 5, "float32"), ("mlp", 3, "float64")])
@settings(max_examples=5, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_exact_inverse(net, dim, dtype, seed):
    """‖φ⁻¹(φ(x)) − x‖ ≤ 1e-5 and ‖φ(φ⁻¹(y)) − y‖ ≤ 1e-5 away from the identity."""
    jax.config.update("jax_enable_x64", dtype == "float64")
    try:
        flow = make_flow(dim, net, dtype)
        variables = perturbed(flow, seed)
        x = np.random.default_rng(seed).uniform(-1.0, 1.0, (16, dim)).astype(dtype)
        out = jax.tree.map(np.asarray, analysis(flow)(variables, x))
        assert out["y"].dtype == np.dtype(dtype)
        assert np.max(np.abs(out["y"] - x)) > 1e-2  # really not the identity
        assert np.max(np.linalg.norm(out["x_back"] - x, axis=-1)) <= 1e-5  # φ⁻¹∘φ
        assert np.max(np.linalg.norm(out["y_back"] - x, axis=-1)) <= 1e-5  # φ∘φ⁻¹
        np.testing.assert_allclose(out["ld_inv"], -out["ld"], atol=1e-5)
    finally:
        jax.config.update("jax_enable_x64", False)


def _fd_jacobian(fn, x, h=1e-6):
    cols = [(fn(x + h * e) - fn(x - h * e)) / (2 * h) for e in np.eye(x.shape[0])]
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("net,dim", [("rff", 2), ("mlp", 3)])
def test_jacobian_and_log_det_float64(x64, net, dim):
    """Autodiff J_φ vs float64 central differences; log|det J_φ| (eq 4.4) vs slogdet; J_{φ⁻¹}."""
    flow = make_flow(dim, net, "float64")
    variables = perturbed(flow, 11)
    xs = np.random.default_rng(0).uniform(-1, 1, (16, dim))
    out = jax.tree.map(np.asarray, analysis(flow)(variables, xs))

    def phi(p, i):  # φ of row i through the same compiled function
        batch = xs.copy()
        batch[i] = p
        return np.asarray(analysis(flow)(variables, batch)["y"][i])

    for i in range(3):
        J_fd = _fd_jacobian(lambda p, i=i: phi(p, i), xs[i])
        np.testing.assert_allclose(out["J"][i], J_fd, rtol=1e-6, atol=1e-7)
    sign, logabs = np.linalg.slogdet(np.asarray(out["J"]))
    assert np.all(sign > 0)  # orientation-preserving: each layer scales by exp(s) > 0
    np.testing.assert_allclose(out["ld"], logabs, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(out["ld_inv"], -logabs, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(out["J_inv"] @ out["J"],
                               np.broadcast_to(np.eye(dim), out["J"].shape), atol=1e-10)


def test_each_layer_passes_its_conditioning_coordinates():
    """Eq 4.4: a coupling layer leaves y^a untouched and moves y^b."""
    flow = make_flow(5)
    variables = perturbed(flow, 5)
    x = np.random.default_rng(0).normal(size=(16, 5)).astype(np.float32)
    out = jax.tree.map(np.asarray, analysis(flow)(variables, x))
    ys = out["layers"]  # (layers + 1, 16, 5)
    for k in range(flow.num_layers):
        keep = np.asarray(coupling_mask(5, k))
        np.testing.assert_array_equal(ys[k + 1][:, keep], ys[k][:, keep])
        assert np.all(ys[k + 1][:, ~keep] != ys[k][:, ~keep])
    np.testing.assert_allclose(ys[-1], out["y"], rtol=1e-5, atol=1e-6)


def test_points_batches_vmap_jit_gradients_and_subtask_map():
    flow = make_flow(2)
    variables = perturbed(flow, 2)
    x = np.random.default_rng(1).normal(size=(2, 8, 2)).astype(np.float32)

    @jax.jit
    def fn(params, x):
        v = {"params": params, CONSTANTS: variables[CONSTANTS]}
        batched = flow.apply(v, x)  # leading axes (2, 8)
        single = jax.vmap(jax.vmap(lambda p: flow.apply(v, p)))(x)
        # Gradients reach the learnable read-outs (the training signal of chapter 5).
        grad = jax.grad(lambda p: jnp.sum(flow.apply({"params": p, CONSTANTS: v[CONSTANTS]},
                                                     x) ** 2))(params)
        psi = subtask_map(flow, v, x, x[0, 0])  # ψ(g) = 0 (§4.2)
        return batched, single, grad, psi

    batched, single, grad, psi = fn(variables["params"], x)
    assert batched.shape == (2, 8, 2)
    np.testing.assert_allclose(batched, single, rtol=1e-6, atol=1e-6)
    flat = analysis(flow)(variables, x.reshape(16, 2))
    np.testing.assert_allclose(flat["y"].reshape(2, 8, 2), batched, rtol=1e-6, atol=1e-6)
    _, ld = jax.eval_shape(lambda p: flow.apply(variables, p, method="forward_and_log_det"),
                           x[0, 0])
    assert ld.shape == ()
    assert all(np.all(np.isfinite(leaf)) for leaf in jax.tree.leaves(grad))
    assert all(np.any(leaf != 0) for leaf in jax.tree.leaves(grad))
    np.testing.assert_allclose(psi[0, 0], 0.0, atol=1e-6)
    assert np.all(np.linalg.norm(np.asarray(psi).reshape(16, 2)[1:], axis=-1) > 0)


def test_normalized_features_are_a_reparameterisation():
    """Eq 4.5's √(2/N) feature scale equals the original's 1 with w ↦ w/√(2/N)."""
    plain = make_flow(2)
    normed = make_flow(2, normalize_features=True)
    variables = perturbed(plain, 4)
    rescaled = {"params": jax.tree.map(lambda w: w / np.sqrt(2.0 / SMALL["num_features"]),
                                       variables["params"]),
                CONSTANTS: variables[CONSTANTS]}
    x = np.array([[0.2, -0.7], [0.9, 0.1]], np.float32)
    a, b = jax.jit(lambda x: (normed.apply(rescaled, x), plain.apply(variables, x)))(x)
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)


def test_bad_configuration_and_shapes_raise():
    with pytest.raises(ValueError, match="dim"):
        EuclideanizingFlow(dim=1)
    with pytest.raises(ValueError, match="net"):
        EuclideanizingFlow(dim=2, net="conv")
    with pytest.raises(ValueError, match="length_scale"):
        EuclideanizingFlow(dim=2, length_scale=0.0)
    with pytest.raises(ValueError, match="activation"):
        EuclideanizingFlow(dim=2, net="mlp", activation="nope")
    flow = make_flow(2)
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 2\)"):
        flow.apply(_init(flow), jnp.zeros(3))

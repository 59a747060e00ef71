"""The offline learners' NN-RESIDUAL actor (:mod:`offline.learners.residual_actor`).

* The RMP² base ``b(s)`` decoded from observations equals ``atanh(clip(a_h/a_max))`` computed in
  float64 from the environment's own policy inputs (not decoded) and the preset's acceleration.
* With the MLP's output layer zeroed, the actor's mode is the base policy's clipped action and
  its log-probability equals a float64 change-of-variables reference.
* Learners build with ``actor="nn_residual"``: BC, ATAC (Oracle), IQL and CQL train with finite
  losses and their ``act`` starts from the base; bad input names the argument.
* The bases the learners precompute per transition (``dataset_bases``, batched with a
  remainder) equal the float64 reference, minibatches drawn with ``sample_with`` carry the rows
  of the transitions they hold, and a loss and its gradient are the same with the precomputed
  base as with the base evaluated inside the actor.
"""

from __future__ import annotations

import argparse
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from mjxrmp import policies as rmp_policies
from offline.data import dataset as odata
from offline.experiment import run as experiment
from offline.experiment import settings
from offline.learners import atac, bc, cql, iql, registry, residual_actor
from offline.learners.base import actor_params
from offline.learners.residual_actor import (
    BASE_CLIP,
    BASE_VARIANT,
    ResidualTanhGaussianPolicy,
    apply_actor,
    base_pre_tanh,
    check_actor,
    dataset_bases,
    make_actor,
)
from offline.learners.tanh_gaussian import TanhGaussianPolicy
from offline.survival import sweep

ENV = "three_link/env3"
N = 12
HIDDEN = (16, 16)
META = {"env": ENV, "action_limit": 1.0, "reward_range": [-5.0, 1.0]}


@pytest.fixture(scope="module")
def states():
    """Observations of ``N`` env3 scenes with random joint positions and velocities, and the
    environment's own policy inputs ``(q, q̇, goal, obstacles)`` behind them."""
    env = envs.make(ENV)
    reset = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(3), N))
    q, _, goal, obstacles = jax.vmap(env.policy_inputs)(reset)
    k1, k2 = jax.random.split(jax.random.PRNGKey(4))
    q = q + jax.random.uniform(k1, q.shape, minval=-1.0, maxval=1.0)
    qd = jax.random.uniform(k2, q.shape, minval=-1.5, maxval=1.5)
    obs = jax.jit(jax.vmap(env.observe))(q, qd, goal, obstacles)
    return env, obs, (q, qd, goal, obstacles)


def _reference_base(inputs) -> np.ndarray:
    cfg = rmp_policies.default_config("three_link", BASE_VARIANT)
    a_h = jax.jit(jax.vmap(lambda *a: rmp_policies.acceleration(cfg, *a)))(*inputs)
    return np.arctanh(np.clip(np.asarray(a_h, np.float64), -BASE_CLIP, BASE_CLIP))


def _zeroed(params):
    """``params`` with the residual MLP's output layer set to zero (mean and log-std 0)."""
    p = jax.tree.map(lambda x: x, params)
    mlp = p["params"]["residual"]["mlp"]
    mlp["out"] = jax.tree.map(jnp.zeros_like, mlp["out"])
    return p


def test_base_matches_float64_reference_from_the_true_state(states):
    _, obs, inputs = states
    actor = make_actor("nn_residual", META, 3, HIDDEN)
    ref = _reference_base(inputs)
    base = jax.jit(lambda o: base_pre_tanh(actor.spec, actor.rmp_config, 1.0, o))
    got = np.asarray(base(obs), np.float64)
    assert np.abs(ref).max() > 0.3, "the scenes must exercise the base"
    # Decoding q from (sin q, cos q) and the goal from g − x costs float32 rounding; atanh
    # amplifies it near the clip, so compare the squashed actions too.
    np.testing.assert_allclose(np.tanh(got), np.tanh(ref), atol=2e-4)
    np.testing.assert_allclose(got, ref, atol=5e-3)
    assert np.abs(got).max() <= np.arctanh(BASE_CLIP) + 1e-4


def test_zero_residual_is_the_base_and_log_prob_matches_float64(states):
    _, obs, inputs = states
    actor = make_actor("nn_residual", META, 3, HIDDEN)
    assert isinstance(actor, ResidualTanhGaussianPolicy)
    params = _zeroed(jax.jit(actor.init)(jax.random.PRNGKey(0), obs[:1]))
    dist = jax.jit(actor.apply)(params, obs)
    ref_b = _reference_base(inputs)
    np.testing.assert_allclose(np.asarray(dist.mode()), np.tanh(ref_b), atol=2e-4)
    np.testing.assert_array_equal(np.asarray(dist.log_std), 0.0)
    # log π(a|s) = Σ log N(atanh a; b, 1) − log(1 − a²), float64.
    a = np.random.default_rng(0).uniform(-0.95, 0.95, size=(N, 3))
    u = np.arctanh(a)
    b = np.asarray(dist.mean, np.float64)
    ref = np.sum(-0.5 * (u - b) ** 2 - 0.5 * np.log(2 * np.pi) - np.log1p(-a * a), axis=-1)
    np.testing.assert_allclose(np.asarray(dist.log_prob(jnp.asarray(a, jnp.float32))), ref,
                               rtol=1e-4, atol=1e-3)


def _dataset(obs: jax.Array) -> odata.Dataset:
    n = obs.shape[0]
    rng = np.random.default_rng(1)
    ids = np.repeat(np.arange(3), n // 3)
    timeouts = np.tile(np.arange(n // 3) == n // 3 - 1, 3)
    o = np.asarray(obs, np.float32)
    return odata.create(o, rng.uniform(-1, 1, (n, 3)).astype(np.float32),
                        rng.uniform(-1, 1, n).astype(np.float32), o[::-1].copy(),
                        np.zeros(n), timeouts, ids, META)


def test_precomputed_bases_are_the_actors_own(states, monkeypatch):
    _, obs, inputs = states
    actor = make_actor("nn_residual", META, 3, HIDDEN)
    monkeypatch.setattr(residual_actor, "BASE_CHUNK", 5)  # 12 rows: two batches + a remainder
    bases = dataset_bases(actor, obs, obs[::-1])
    ref = _reference_base(inputs)
    np.testing.assert_allclose(np.tanh(np.asarray(bases.observations, np.float64)), np.tanh(ref),
                               atol=2e-4)
    np.testing.assert_array_equal(np.asarray(bases.next_observations),
                                  np.asarray(bases.observations)[::-1])
    assert dataset_bases(make_actor("mlp", META, 3, HIDDEN), obs) == residual_actor.NO_BASES

    # The minibatch of sample_with holds the bases of its own transitions.
    ds = _dataset(obs)
    batch, rows = odata.sample_with(ds, bases, jax.random.PRNGKey(7), 32)
    plain = odata.sample(ds, jax.random.PRNGKey(7), 32)
    np.testing.assert_array_equal(np.asarray(batch.observations), np.asarray(plain.observations))
    online = jax.jit(jax.vmap(lambda o: base_pre_tanh(actor.spec, actor.rmp_config, 1.0, o)))
    np.testing.assert_allclose(np.asarray(rows.observations),
                               np.asarray(online(batch.observations)), atol=1e-5)
    with pytest.raises(ValueError, match="one entry per transition"):
        odata.sample_with(ds, bases.observations[:3], jax.random.PRNGKey(7), 4)

    # Loss and gradient with the precomputed base equal those with the base evaluated inside.
    params = jax.jit(actor.init)(jax.random.PRNGKey(0), obs[:1])
    acts = jnp.tanh(jnp.asarray(ref, jnp.float32) * 0.5)

    def loss(p, base):
        return bc.bc_loss(actor, p, obs, acts, base)[0]

    with_base = jax.jit(jax.value_and_grad(loss))(params, bases.observations)
    inside = jax.jit(jax.value_and_grad(lambda p: loss(p, None)))(params)
    for got, want in zip(jax.tree.leaves(with_base), jax.tree.leaves(inside), strict=True):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-4, atol=1e-5)
    mean = jax.jit(lambda p, b: apply_actor(actor, p, obs, b).mean)(params, bases.observations)
    np.testing.assert_allclose(np.asarray(mean),
                               np.asarray(jax.jit(actor.apply)(params, obs).mean), atol=1e-5)


def test_learners_train_from_the_base_with_the_residual_actor(states):
    _, obs, inputs = states
    ds = _dataset(obs)
    budget = registry.Budget(steps=20, hidden=HIDDEN, batch=8, actor="nn_residual")
    ref = np.clip(np.tanh(_reference_base(inputs)), -1, 1)
    for learner in ("BC", "Oracle", "IQL", "CQL"):
        trainer = experiment.build(learner, ds, None, budget)
        state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
        act = jax.jit(trainer.act)
        params = _zeroed(actor_params(state))
        np.testing.assert_allclose(np.asarray(act(params, obs)), ref, atol=2e-4)
        state, metrics = jax.jit(trainer.run, static_argnums=1)(state, 20)
        assert all(np.isfinite(np.asarray(v)).all() for v in jax.tree.leaves(metrics)), learner
        assert np.isfinite(np.asarray(act(actor_params(state), obs))).all()


def test_reward_batched_programs_get_concrete_bases(states, monkeypatch):
    """The chapter-8 programs build each learner inside the traced ``run``
    (``offline.survival.sweep.reward_batched``); the RMP² bases must still be computed from
    concrete data — once, when traced — not staged into the program and recomputed on every
    call."""
    _, obs, _ = states
    ds = _dataset(obs)
    seen = []

    def spy(actor, observations, next_observations=None):
        seen.append(isinstance(observations, jax.core.Tracer))
        return dataset_bases(actor, observations, next_observations)

    for module in (atac, iql, cql):
        monkeypatch.setattr(module, "dataset_bases", spy)
    budget = registry.Budget(steps=10, hidden=HIDDEN, batch=8, actor="nn_residual")
    base, rows = sweep.reward_rows(ds, ["original", "zero"], "keep", sweep.reward_key(0, "x"))
    for learner in ("ATAC", "IQL", "CQL"):
        trainer = sweep.reward_batched(learner, base, budget)
        state = experiment.init_runs(trainer, sweep.reward_seed_keys(rows, [0]), None)
        seen.clear()
        jax.make_jaxpr(lambda s, t=trainer: jax.vmap(t.run, in_axes=(0, None))(s, 2))(state)
        assert seen and not any(seen), learner


def test_mlp_actor_is_the_default_and_unchanged():
    for cfg in (atac.ATACConfig(), bc.BCConfig(), iql.IQLConfig(), cql.CQLConfig(),
                registry.Budget(steps=10)):
        assert cfg.actor == "mlp"
    actor = make_actor("mlp", {}, 3, HIDDEN)
    assert actor == TanhGaussianPolicy(3, HIDDEN, "relu")


def test_bad_input_names_the_argument(states):
    with pytest.raises(ValueError, match="actor must be one of"):
        check_actor("rmp")
    for cls in (atac.ATACConfig, bc.BCConfig, iql.IQLConfig, cql.CQLConfig):
        with pytest.raises(ValueError, match="actor must be one of"):
            cls(actor="transformer")
        with pytest.raises(ValueError, match="normalize_observations"):
            cls(actor="nn_residual", normalize_observations=True)
    with pytest.raises(ValueError, match="normalize_observations"):
        registry.Budget(steps=10, actor="nn_residual", normalize_observations=True)
    with pytest.raises(ValueError, match=r"lacks \['env'\]"):
        make_actor("nn_residual", {"action_limit": 1.0}, 3, HIDDEN)
    with pytest.raises(ValueError, match="action_size=9"):
        make_actor("nn_residual", META, 9, HIDDEN)


def test_scripts_give_non_default_actors_their_own_cells():
    p = argparse.ArgumentParser()
    for option in settings.LEARNER_OPTIONS:
        p.add_argument(*option.flags, **option.spec)
    default = p.parse_args([])
    legacy = p.parse_args(["--actor-rate", "scaled"])  # the settings of our first results
    residual = p.parse_args(["--actor", "nn_residual", "--actor-rate", "scaled"])
    assert default.actor == "mlp" and default.actor_rate == "published"
    assert settings.setting_key(legacy) == []
    assert settings.setting_key(default) == ["actor_rate", "published"]
    assert settings.setting_key(residual) == ["actor", "nn_residual"]
    longer = p.parse_args(["--warmstart", "0.5"])
    assert settings.setting_key(longer) == ["warmstart", 0.5, "actor_rate", "published"]
    assert registry.Budget(steps=100, **settings.setting_fields(longer)).warmstart == 0.5
    keys = {json.dumps(settings.setting_key(a)) for a in (default, legacy, residual, longer)}
    assert len(keys) == 4  # every setting its own cells
    with pytest.raises(SystemExit):
        p.parse_args(["--actor", "rmp"])


def test_actor_rate_rule_of_shortened_atac_runs():
    # Published (default): 5e-7; scaled: 5e-7 × 1e6 / steps keeps the published rate × steps.
    scaled = registry.atac_config(registry.Budget(steps=20_000, actor_rate="scaled"))
    published = registry.atac_config(registry.Budget(steps=20_000))
    assert scaled.actor_lr == pytest.approx(2.5e-5) and published.actor_lr == 5e-7
    assert scaled.warmstart_steps == published.warmstart_steps == 2_000
    assert scaled.critic_lr == published.critic_lr
    with pytest.raises(ValueError, match="actor_rate must be one of"):
        registry.Budget(steps=10, actor_rate="fast")

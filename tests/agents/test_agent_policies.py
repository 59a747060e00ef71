"""Policy classes of thesis §6.2.2 (agents/ppo/policies.py) on the reaching environments."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from agents.ppo import PPOConfig, make_trainer
from agents.ppo.networks import GaussianPolicy, PPONetworks, ValueMLP
from agents.ppo.normalization import RunningStats
from agents.ppo.policies import (
    KINDS,
    HandDesignedPolicy,
    NNResidualPolicy,
    RMPResidualPolicy,
    decode_observation,
    make_env_and_policy,
    make_policy,
    packed_kind,
    policy_groups,
)
from envs.wrappers import RMPInEnv
from mjxrmp import policies as rmp_policies
from mjxrmp.geometry import Obstacles

N = 4


@pytest.fixture(scope="module")
def three_link():
    """The 3-link env3 environment and a batch of ``N`` reset states."""
    env = envs.make("three_link/env3")
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), N))
    return env, states


def _inputs(env, states):
    return jax.vmap(env.policy_inputs)(states)


def _preset_acceleration(variant, q, qd, goal, obstacles):
    cfg = rmp_policies.default_config("three_link", variant)
    return jax.jit(jax.vmap(lambda *a: rmp_policies.acceleration(cfg, *a)))(
        q, qd, goal, obstacles)


def _init_apply(pol, seed, obs):
    """``pol``'s parameters from ``PRNGKey(seed)`` and its jitted ``apply`` (RMP² run op by op
    costs several times its compile)."""
    return jax.jit(pol.init)(jax.random.PRNGKey(seed), obs[0]), jax.jit(pol.apply)


def _zero_subtree(params, name):
    """``params`` with every array under the submodule ``name``'s output layer set to zero."""
    p = jax.tree.map(lambda x: x, params)
    p["params"][name]["out"] = jax.tree.map(jnp.zeros_like, p["params"][name]["out"])
    return p


def test_decode_matches_policy_inputs(three_link):
    env, states = three_link
    q, qd, goal, obstacles = _inputs(env, states)
    dq, dqd, dgoal, dobs = decode_observation(env, states.obs)
    np.testing.assert_allclose(dqd, qd, atol=1e-6)
    np.testing.assert_allclose(dq, q, atol=1e-5)
    np.testing.assert_allclose(dqd, qd, atol=1e-5)
    np.testing.assert_allclose(dgoal, goal, atol=1e-5)
    np.testing.assert_allclose(dobs.center, obstacles.center, atol=1e-5)
    np.testing.assert_allclose(dobs.radius, obstacles.radius, atol=1e-5)
    np.testing.assert_array_equal(dobs.active, obstacles.active)
    # single observation
    single = decode_observation(env, states.obs[0])
    np.testing.assert_allclose(single[0], q[0], atol=1e-5)
    np.testing.assert_allclose(single[2], goal[0], atol=1e-5)


def test_decode_padded_obstacles_inactive():
    env = envs.make("three_link/env1", num_obstacles=1)
    q = jnp.array([0.3, -0.2, 0.1])
    obstacles = Obstacles(
        jnp.array([[0.5, 0.5]]), jnp.array([0.07]), jnp.array([0.0])
    )
    obs = env.observe(q, jnp.zeros(3), jnp.array([-0.3, 0.2]), obstacles)
    _, _, goal, dobs = decode_observation(env, obs)
    np.testing.assert_allclose(goal, [-0.3, 0.2], atol=1e-5)
    np.testing.assert_array_equal(dobs.active, [0.0])


def test_make_policy_defaults(three_link):
    env, _ = three_link
    nn_pol = make_policy("nn", env)
    assert isinstance(nn_pol, GaussianPolicy)
    assert nn_pol.hidden_sizes == (256, 128) and nn_pol.activation == "relu"
    assert nn_pol.out_scale == 0.1
    res = make_policy("nn_residual", env)
    assert isinstance(res, NNResidualPolicy)
    assert res.hidden_sizes == (256, 128) and res.rmp_config == rmp_policies.default_config(
        "three_link", "residual_base")
    rmp = make_policy("rmp_residual", env)
    assert isinstance(rmp, RMPResidualPolicy)
    assert rmp.hidden_sizes == (128, 64) and rmp.activation == "elu" and rmp.out_scale == 0.01
    assert math.isclose(rmp.metric_scale, math.sqrt(5.0))
    hd = make_policy("hand_designed", env)
    assert isinstance(hd, HandDesignedPolicy)
    assert make_policy("rmp_residual", env, hidden_sizes=[8]).hidden_sizes == (8,)
    with pytest.raises(ValueError, match="unknown policy kind"):
        make_policy("transformer", env)


@pytest.mark.parametrize("kind", [k for k in KINDS if k != "rmp_residual_env"])
def test_log_std_init_and_shapes(three_link, kind):
    env, states = three_link
    pol = make_policy(kind, env)
    params, apply = _init_apply(pol, 1, states.obs)
    mean, log_std = apply(params, states.obs)
    assert mean.shape == (N, 3)
    np.testing.assert_array_equal(log_std, -jnp.ones(3))
    mean1, _ = apply(params, states.obs[0])
    np.testing.assert_allclose(mean1, mean[0], rtol=1e-5, atol=1e-6)
    assert bool(jnp.all(jnp.isfinite(mean)))


def test_nn_residual_is_base_plus_small_mlp(three_link):
    env, states = three_link
    base = _preset_acceleration("residual_base", *_inputs(env, states))
    pol = make_policy("nn_residual", env)
    params, apply = _init_apply(pol, 2, states.obs)
    mean, _ = apply(params, states.obs)
    assert float(jnp.max(jnp.abs(mean - base))) < 0.5
    assert float(jnp.max(jnp.abs(mean - base))) > 0.0
    mean0, _ = apply(_zero_subtree(params, "mean"), states.obs)
    np.testing.assert_allclose(mean0, base, rtol=1e-4, atol=1e-5)


def test_nn_is_nn_residual_with_base_weight_zero(three_link):
    """One network serves both kinds in a packed sweep (agents.ppo.policies.packed_kind): the
    same key initialises the same parameters, and the base scaled by weight 0 (exactly 0 even
    where the base is not finite) gives the nn policy's mean; weight 1 the nn_residual mean."""
    env, states = three_link
    nn_pol, res_pol = make_policy("nn", env), make_policy("nn_residual", env)
    nn_params, nn_apply = _init_apply(nn_pol, 3, states.obs)
    res_params, res_apply = _init_apply(res_pol, 3, states.obs)
    for a, b in zip(jax.tree.leaves(nn_params), jax.tree.leaves(res_params), strict=True):
        np.testing.assert_array_equal(a, b)
    assert jax.tree.structure(nn_params) == jax.tree.structure(res_params)
    nets = PPONetworks(res_pol, ValueMLP())
    features, precompute = jax.jit(nets.policy_features), jax.jit(res_pol.precompute)
    obs = states.obs
    np.testing.assert_array_equal(features(obs, jnp.float32(1.0)), precompute(obs))
    mean0, _ = res_apply(res_params, obs, None, features(obs, jnp.float32(0.0)))
    np.testing.assert_array_equal(mean0, nn_apply(nn_params, obs)[0])
    bad = obs.at[0, 0].set(jnp.nan)
    assert not bool(jnp.all(jnp.isfinite(precompute(bad))))
    np.testing.assert_array_equal(features(bad, jnp.float32(0.0)), 0.0)
    with pytest.raises(ValueError, match="base_weight needs"):
        PPONetworks(nn_pol, ValueMLP()).policy_features(obs, jnp.float32(0.0))
    assert packed_kind(("nn", "nn_residual")) == "nn_residual" == packed_kind(("nn_residual",))
    assert policy_groups(("nn", "rmp_residual", "nn_residual")) == [("nn", "nn_residual"),
                                                                     ("rmp_residual",)]


def test_rmp_residual_zero_residual_is_preset(three_link):
    env, states = three_link
    base = _preset_acceleration("residual_rmp", *_inputs(env, states))
    pol = make_policy("rmp_residual", env)
    params, apply = _init_apply(pol, 3, states.obs)
    mean0, _ = apply(_zero_subtree(params, "residual"), states.obs)
    np.testing.assert_allclose(mean0, base, rtol=1e-4, atol=1e-4)
    mean, _ = apply(params, states.obs)
    assert float(jnp.max(jnp.abs(mean - base))) < 0.5


def test_hand_designed_equals_preset(three_link):
    env, states = three_link
    base = _preset_acceleration("hand_designed", *_inputs(env, states))
    pol = make_policy("hand_designed", env)
    params, apply = _init_apply(pol, 5, states.obs)
    assert list(params["params"]) == ["log_std"]
    mean, _ = apply(params, states.obs)
    np.testing.assert_allclose(mean, base, rtol=1e-4, atol=1e-4)


def test_rmp_residual_gradients_finite_nonzero(three_link):
    env, states = three_link
    pol = make_policy("rmp_residual", env)
    params = jax.jit(pol.init)(jax.random.PRNGKey(6), states.obs[0])
    w = jax.random.normal(jax.random.PRNGKey(7), (N, 3))
    grads = jax.jit(jax.grad(lambda p: jnp.sum(w * pol.apply(p, states.obs)[0])))(params)
    for path, g in jax.tree_util.tree_leaves_with_path(grads["params"]["residual"]):
        assert bool(jnp.all(jnp.isfinite(g))), path
        assert float(jnp.max(jnp.abs(g))) > 0.0, path


TINY = PPOConfig(num_envs=4, rollout_length=8, num_minibatches=1, update_epochs=1,
                 total_iterations=1, episode_length=16)


def test_rmp_residual_trains_one_iteration(three_link):
    """One iteration of the residual RMP policy: the rollout's transitions carry the policy's
    parameter-free part at every state (what ``precompute`` gives for the stored observation),
    and the update that reads them equals the update in which the policy computes that part
    itself in every minibatch; parameters and metrics finite."""
    env, _ = three_link
    pol = make_policy("rmp_residual", env)
    trainer = make_trainer(env, pol, TINY)
    ts, tr = jax.jit(trainer.rollout)(jax.jit(trainer.init)(jax.random.PRNGKey(8)),
                                      jax.random.PRNGKey(9))
    stored = jax.tree.leaves(tr.policy_features)
    again = jax.tree.leaves(jax.jit(jax.vmap(pol.precompute))(tr.obs))
    for a, b in zip(stored, again, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
    update, key = jax.jit(trainer.update), jax.random.PRNGKey(10)
    (ts, metrics), (plain, plain_metrics) = (update(ts, tr, key),
                                             update(ts, tr._replace(policy_features=None), key))
    assert set(ts.params["policy"]["params"]) == {"log_std", "residual"}
    for a, b in zip(jax.tree.leaves(ts.params), jax.tree.leaves(plain.params), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
    for k in ("loss", "policy_loss", "value_loss", "mean_reward"):
        assert bool(jnp.isfinite(metrics[k])), k
        np.testing.assert_allclose(metrics[k], plain_metrics[k], rtol=1e-5, atol=1e-6)
    assert bool(jnp.all(jnp.isfinite(jnp.concatenate(
        [x.ravel() for x in jax.tree.leaves(ts.params)]))))


def test_rmp_residual_env_pair():
    """``rmp_residual_env``: RMPInEnv on the residual-RMP observation + a small Gaussian MLP whose
    zero output reproduces the ``residual_rmp`` base policy inside the environment."""
    env, pol = make_env_and_policy("three_link/env3", "rmp_residual_env")
    assert isinstance(env, RMPInEnv) and env.unwrapped.observation_variant == "residual_rmp"
    assert isinstance(pol, GaussianPolicy) and pol.action_size == 6
    assert pol.hidden_sizes == (128, 64) and pol.activation == "elu" and pol.out_scale == 0.01
    with pytest.raises(ValueError, match="RMPInEnv"):
        make_policy("rmp_residual_env", envs.make("three_link/env3"))
    with pytest.raises(ValueError, match="RMPInEnv"):
        make_policy("nn", env)
    with pytest.raises(ValueError, match="valid kinds"):
        make_env_and_policy("three_link/env3", "mlp")
    with pytest.raises(ValueError, match="valid names"):
        make_env_and_policy("three_link/env9", "nn")


def test_normalisation_never_reaches_rmp2(three_link):
    """Observation statistics change what MLPs read, never what RMP² reads."""
    env, states = three_link
    stats = RunningStats(jnp.float32(10.0), jnp.full((26,), 3.0), jnp.full((26,), 0.01))
    for kind in ("hand_designed", "rmp_residual"):
        params, apply = _init_apply(make_policy(kind, env), 9, states.obs)
        np.testing.assert_array_equal(apply(params, states.obs, stats)[0],
                                      apply(params, states.obs)[0])
    params, apply = _init_apply(make_policy("nn_residual", env), 9, states.obs)
    zeroed = _zero_subtree(params, "mean")
    np.testing.assert_array_equal(apply(zeroed, states.obs, stats)[0],
                                  apply(zeroed, states.obs)[0])
    assert not np.allclose(apply(params, states.obs, stats)[0], apply(params, states.obs)[0])


def test_rmp_in_env_squashes_and_plumbs_the_residual_action(three_link):
    """RMPInEnv's raw action → (√5·tanh, tanh) residual and its state → RMP² inputs."""
    env, states = three_link
    wrapped = RMPInEnv(env)
    raw = jax.random.normal(jax.random.PRNGKey(4), (N, 6))
    expected = jax.jit(jax.vmap(wrapped.joint_acceleration))(states, raw)
    A_r = math.sqrt(5.0) * jnp.tanh(raw[:, :4]).reshape(N, 2, 2)
    a_r = jnp.tanh(raw[:, 4:])
    cfg = rmp_policies.default_config("three_link", "residual_rmp")
    got = jax.jit(jax.vmap(lambda *a: rmp_policies.residual_rmp_acceleration(cfg, *a)))(
        *_inputs(env, states), A_r, a_r)
    np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-4)


@pytest.fixture(scope="module")
def franka():
    """The Franka environment and 2 reset states."""
    env = envs.make("franka")
    return env, jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(1), 2))


def test_franka_decode_and_sizes(franka):
    """The Franka (45-d observation, 7 joints; thesis §6.3 sizes): RMP² inputs decoded exactly,
    the thesis network sizes, rmp_residual_env acts 3×3 + 3."""
    env, states = franka
    q, qd, goal, obstacles = jax.vmap(env.policy_inputs)(states)
    dq, dqd, dgoal, dobs = decode_observation(env, states.obs)
    np.testing.assert_allclose(dqd, qd, atol=1e-6)
    np.testing.assert_allclose(dq, q, atol=1e-5)
    np.testing.assert_allclose(dgoal, goal, atol=1e-5)
    np.testing.assert_allclose(dobs.radius, obstacles.radius, atol=1e-6)
    for kind, hidden in (("nn", (512, 256)), ("nn_residual", (512, 256)),
                         ("rmp_residual", (256, 128))):
        assert tuple(make_policy(kind, env).hidden_sizes) == hidden, kind
    wrapped, pol = make_env_and_policy("franka", "rmp_residual_env")
    assert wrapped.action_size == 12 and pol.action_size == 12
    assert wrapped.observation_size == 45 + 9  # goal, end-effector position and velocity


# The same checks on the 3-link: test_log_std_init_and_shapes, test_hand_designed_equals_preset,
# test_nn_residual_is_base_plus_small_mlp, test_rmp_residual_zero_residual_is_preset (here the
# second robot: four Franka policies compiled, 15 CPU s).
@pytest.mark.slow  # second robot of the 3-link checks named above
def test_franka_policy_classes(franka):
    """Every kind on the Franka: shapes, finite means, zero residuals give the presets."""
    env, states = franka
    q, qd, goal, obstacles = jax.vmap(env.policy_inputs)(states)

    def preset(variant):
        cfg = rmp_policies.default_config("franka", variant)
        return jax.jit(jax.vmap(lambda *a: rmp_policies.acceleration(cfg, *a)))(
            q, qd, goal, obstacles)

    for kind in ("nn", "nn_residual", "rmp_residual", "hand_designed"):
        pol = make_policy(kind, env)
        params = jax.jit(pol.init)(jax.random.PRNGKey(2), states.obs[0])
        apply = jax.jit(pol.apply)
        mean, log_std = apply(params, states.obs)
        assert mean.shape == (2, 7) and log_std.shape == (7,), kind
        assert bool(jnp.all(jnp.isfinite(mean))), kind
        if kind == "hand_designed":
            np.testing.assert_allclose(mean, preset("hand_designed"), rtol=1e-4, atol=1e-4)
        elif kind in ("nn_residual", "rmp_residual"):
            sub = "mean" if kind == "nn_residual" else "residual"
            variant = "residual_base" if kind == "nn_residual" else "residual_rmp"
            np.testing.assert_allclose(apply(_zero_subtree(params, sub), states.obs)[0],
                                       preset(variant), rtol=1e-4, atol=1e-4)

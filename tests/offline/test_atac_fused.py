"""The fused ATAC gradient step (offline/learners/atac_step.py) against a plain formulation of
Algorithm 3 (thesis §7.3.3, eqs 7.1, 7.2, 7.11) written here: two separate critics, separate
forward passes for every action set, separate ``jax.grad`` calls of the losses, the original
per-step randomness (``fold_in`` → ``split`` → :func:`offline.data.dataset.sample_with` and
``TanhGaussian.sample``) in a plain ``lax.scan`` of one step per iteration.

* one step from the same state and draws gives the same losses, parameters, targets and
  optimiser states — float32 within ``rtol 2e-5``, float64 within ``rtol 1e-9`` — in the BC warm
  start, at the switch and in the game phase, for ATAC (relative, ``clip_v``) and for PSPI
  (absolute) with a reward player trained online (MAHALO's Algorithm 3 line 6);
* 50 steps × 2 seeds of ``make_train`` (blocks of 8 and a remainder, warm start for 20 steps) give
  the reference's metrics within ``max |Δ| ≤ 1e-3·max |x|`` per metric and its final parameters
  within ``5e-3·max |x|`` per tensor: float32 rounding grown over 50 steps of Adam, which turns
  the rounding of a near-zero gradient into a step of full size (``lr``) on that one entry.
  Other blocks (2 steps, unrolled) give the same within the same bounds (without this file's
  fast-compile option, blocks of 8 and of 1 give bitwise the same metrics);
* ``offline.experiment.step_profile`` counts the operations of a tiny compiled step by part.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from agents.ppo.networks import MLP
from offline.data import dataset as odata
from offline.experiment import step_profile
from offline.learners import atac, atac_step
from offline.learners.base import scan_steps
from offline.learners.residual_actor import apply_actor

FAST = {"xla_backend_optimization_level": 0}
OBS, ACT, N = 4, 2, 300
CFG = atac.ATACConfig(hidden_sizes=(16, 16), batch_size=32, warmstart_steps=3, num_steps=8,
                      critic_lr=1e-2, actor_lr=3e-3, bc_lr=1e-2, alpha_lr=1e-2, tau=0.05,
                      beta=4.0, norm_bound=2.0, clip_v=True, dqra_weight=0.3)
VARIANTS = {"atac": CFG, "pspi_reward_player": dataclasses.replace(
    CFG, pessimism="absolute", clip_v=False, beta=0.5)}


def dataset() -> odata.Dataset:
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(N, OBS)).astype(np.float32)
    act = np.clip(rng.normal(0.3, 0.8, size=(N, ACT)), -1.5, 1.5).astype(np.float32)
    rew = (obs[:, 0] + 0.5 * act[:, 1]).astype(np.float32)
    term = (np.arange(N) % 10) == 9
    return odata.create(obs, act, rew, rng.normal(size=(N, OBS)).astype(np.float32), term,
                        np.zeros(N), np.arange(N) // 10, {"action_limit": 1.5})


def reward_player() -> atac.RewardModel:
    """A linear ``g(s) = s·w`` fitted online to targets ``s_0`` (a stand-in for MAHALO's)."""
    def mse(p, key):
        s = jax.random.normal(key, (16, OBS), p["w"].dtype)
        return jnp.mean(jnp.square(s @ p["w"] - s[:, 0]))

    return atac.RewardModel(init=lambda key: {"w": jax.random.normal(key, (OBS,)) * 0.1},
                            predict=lambda p, b: b.observations @ p["w"], fit_loss=mse,
                            weight=lambda beta: 10.0 * beta, lr=1e-2)


def make_core(name: str) -> atac_step.ATACCore:
    reward = reward_player() if name == "pspi_reward_player" else atac.dataset_rewards()
    return atac.build_core(dataset(), VARIANTS[name], reward, reward_range=(-2.0, 2.0))


# --------------------------------------------------------------------------------------------
# The plain formulation


def critics_of(ensemble_params):
    """The ensemble's parameters as a list of separate critics' MLP parameters."""
    layers = ensemble_params["params"]["critics"]
    k = layers["out"]["bias"].shape[0]
    return [{"params": jax.tree.map(lambda x, i=i: x[i], layers)} for i in range(k)]


def combine(loss, reg, w):
    """eq 7.1's weighted sum ``loss + w·reg``, rescaled by ``1/w`` for ``w > 1``."""
    big = w > 1.0
    return jnp.where(big, loss / jnp.where(big, w, 1.0) + reg, loss + w * reg)


def critic_fn(core):
    """``f(critic_params, s, a) -> (B,)``: one critic, an MLP on ``concat(s, a)``."""
    mlp = MLP(tuple(core.config.hidden_sizes), 1, "relu", 1.0)
    return lambda c, s, a: mlp.apply(c, jnp.concatenate([s, a], -1))[..., 0]


def policy_sample(core, actor_params, obs, base, noise):
    """``(tanh(u), log π)`` with ``u = μ + σ·noise`` (the reparameterised sample)."""
    dist = apply_actor(core.actor, actor_params, obs, base)
    u = dist.mean + jnp.exp(dist.log_std) * noise
    return jnp.tanh(u), dist.log_prob_pre_tanh(u)


def plain_critics(core, state, d, a_next, a_pi):
    """Algorithm 3 lines 5–7 and 11 (and line 6 with a trained reward player), each critic
    alone: ``(params, opt_states, target critics, metrics)``."""
    cfg, p, b, f = core.config, state.params, d.batch, critic_fn(core)
    warm = state.step < cfg.warmstart_steps
    clip = lambda y: y if core.bounds is None else y + jax.lax.stop_gradient(  # noqa: E731
        jnp.clip(y, *core.bounds) - y)
    cont = cfg.discount * (1.0 - b.terminals.astype(a_pi.dtype))
    y_bar = jnp.min(jnp.stack([f(c, b.next_observations, a_next)
                               for c in critics_of(state.target_critic)]), 0)

    def bellman(c, r):
        q = f(c, b.observations, b.actions)
        y_t = jax.lax.stop_gradient(clip(r + cont * y_bar))
        y_r = clip(r + cont * f(c, b.next_observations, a_next))
        return (cfg.dqra_weight * jnp.mean((q - y_t) ** 2)
                + (1 - cfg.dqra_weight) * jnp.mean((q - y_r) ** 2)), q

    rewards = jax.lax.stop_gradient(core.reward.predict(p["reward"], b))

    def critic_loss(cs):
        total, game, info = 0.0, 0.0, []
        for c in cs:
            e, q = bellman(c, rewards)
            q_pi = f(c, b.observations, a_pi)
            pess = jnp.mean(q_pi - q) if cfg.pessimism == "relative" else jnp.mean(q_pi)
            total, game = total + e, game + combine(pess, e, state.beta)
            info.append((e, pess, jnp.mean(q), jnp.mean(q_pi)))
        means = [jnp.mean(jnp.stack(x)) for x in zip(*info, strict=True)]
        return jnp.where(warm, total, game), means

    cs = critics_of(p["critic"])
    (c_loss, (bell, pess, q_data, q_pi)), grads = jax.value_and_grad(
        critic_loss, has_aux=True)(cs)
    m = dict(bellman=bell, pessimism=pess, q_data=q_data, q_pi=q_pi, critic_loss=c_loss)
    new_p, new_os = dict(p), dict(state.opt_states)
    if core.reward.fit_loss is not None:
        def reward_loss(rp):
            e = sum(bellman(jax.lax.stop_gradient(c), core.reward.predict(rp, b))[0] for c in cs)
            fit = core.reward.fit_loss(rp, d.reward_key)
            return fit + state.beta / core.reward.weight(state.beta) * e, fit

        (m["reward_loss"], m["reward_fit"]), g = jax.value_and_grad(
            reward_loss, has_aux=True)(p["reward"])
        upd, new_os["reward"] = optax.adam(core.reward.lr).update(g, state.opt_states["reward"])
        new_p["reward"] = optax.apply_updates(p["reward"], upd)
    stacked = jax.tree.map(lambda *x: jnp.stack(x), *grads)
    upd, new_os["critic"] = optax.adam(cfg.critic_lr).update(
        {"params": {"critics": stacked["params"]}}, state.opt_states["critic"])
    critic = optax.apply_updates(p["critic"], upd)
    for layer in critic["params"]["critics"].values():   # Proj_F per critic and weight matrix
        norms = jnp.stack([jnp.linalg.norm(layer["kernel"][i]) for i in range(len(cs))])
        layer["kernel"] = layer["kernel"] * jnp.minimum(1.0, cfg.norm_bound / norms)[:, None,
                                                                                   None]
    new_p["critic"] = critic
    target = jax.tree.map(lambda t, o: (1 - cfg.tau) * t + cfg.tau * o, state.target_critic,
                          critic)
    return new_p, new_os, target, m


def plain_step(core, state, d):
    """Algorithm 3 with separate critics and separate gradients (module docstring)."""
    cfg, p, b = core.config, state.params, d.batch
    warm, switch = state.step < cfg.warmstart_steps, state.step == cfg.warmstart_steps
    sel = lambda fresh, cur: jax.tree.map(  # noqa: E731
        lambda a, c: jnp.where(switch, a, c), fresh, cur)
    actor_os = sel(optax.scale_by_adam().init(p["actor"]), state.opt_states["actor"])
    log_alpha = sel(core.log_alpha0, p["log_alpha"])
    alpha_os = sel(optax.adam(cfg.alpha_lr).init(core.log_alpha0), state.opt_states["alpha"])
    a_next, _ = policy_sample(core, p["actor"], b.next_observations, d.base.next_observations,
                              d.noise_next)
    a_pi, logp = policy_sample(core, p["actor"], b.observations, d.base.observations,
                               d.noise_pi)
    new_p, new_os, target, m = plain_critics(core, state, d, jax.lax.stop_gradient(a_next),
                                             jax.lax.stop_gradient(a_pi))
    entropy = -jnp.mean(logp)
    upd, new_os["alpha"] = optax.adam(cfg.alpha_lr).update(entropy - core.target_entropy,
                                                           alpha_os)
    new_p["log_alpha"] = log_alpha + upd
    alpha = jnp.exp(new_p["log_alpha"])
    first, f = critics_of(new_p["critic"])[0], critic_fn(core)

    def actor_loss(ap):
        bc = -jnp.mean(apply_actor(core.actor, ap, b.observations, d.base.observations
                                   ).log_prob(b.actions))
        a, lp = policy_sample(core, ap, b.observations, d.base.observations, d.noise_pi)
        return jnp.where(warm, bc, combine(-jnp.mean(f(first, b.observations, a)),
                                           jnp.mean(lp), alpha))

    m["actor_loss"], g = jax.value_and_grad(actor_loss)(p["actor"])
    upd, new_os["actor"] = optax.scale_by_adam().update(g, actor_os)
    lr = jnp.where(warm, cfg.bc_lr, cfg.actor_lr)
    new_p["actor"] = jax.tree.map(lambda x, u: x - lr * u, p["actor"], upd)
    m.update(alpha=alpha, entropy=entropy)
    return state._replace(params=new_p, target_critic=target, opt_states=new_os), m


def plain_draws(core, key):
    """The original per-step randomness: ``split(key, 4)``, the minibatch of ``sample_with`` and
    the noises ``TanhGaussian.sample`` draws."""
    k_batch, k_next, k_pi, k_reward = jax.random.split(key, 4)
    batch, base = odata.sample_with(core.ds, core.bases, k_batch, core.config.batch_size)
    noise = [jax.random.normal(k, batch.actions.shape, batch.actions.dtype)
             for k in (k_next, k_pi)]
    return atac_step.StepDraws(batch, base, *noise, k_reward)


def plain_run(core, state, n):
    return scan_steps(lambda s, k: plain_step(core, s, plain_draws(core, k)), state, n)


# --------------------------------------------------------------------------------------------
# One step


def close(a, b, rtol, atol, per_tensor=False):
    """Leaf by leaf ``|x − y| ≤ atol + rtol·|y|`` elementwise, or with ``per_tensor``
    ``max |x − y| ≤ atol + rtol·max |y|`` (for runs, where Adam turns the rounding of a
    near-zero gradient into a step of full size on that one entry)."""
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        if jnp.issubdtype(x.dtype, jax.dtypes.prng_key):
            x, y = jax.random.key_data(x), jax.random.key_data(y)
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        if per_tensor:
            assert np.max(np.abs(x - y)) <= atol + rtol * np.max(np.abs(y)), (x, y)
        else:
            np.testing.assert_allclose(x, y, rtol=rtol, atol=atol)


def jitted(core):
    """The fused and the plain step, compiled once: ``(state, key) -> (state, metrics)``."""
    fused = lambda s, k: atac_step.atac_step(core, s, atac_step.draw(core, k))  # noqa: E731
    plain = lambda s, k: plain_step(core, s, plain_draws(core, k))  # noqa: E731
    return jax.jit(fused, compiler_options=FAST), jax.jit(plain, compiler_options=FAST)


@pytest.fixture(scope="module", params=sorted(VARIANTS))
def variant(request):
    """The core, its compiled steps and states in the warm start, at the switch and in the game
    phase, reached by two real steps (so the optimiser moments and temperature have moved)."""
    core = make_core(request.param)
    fused, plain = jitted(core)
    state = atac.make_core(dataset(), core.config, core.reward,
                           reward_range=(-2.0, 2.0)).init(jax.random.key(5))
    for i in range(2):
        state = fused(state, jax.random.key(i))[0]
    states = [state._replace(step=jnp.asarray(t, jnp.int32))
              for t in (1, CFG.warmstart_steps, CFG.warmstart_steps + 4)]
    return core, fused, plain, states


def test_one_step_equals_plain_formulation_float32(variant):
    core, fused, plain, states = variant
    for i, state in enumerate(states):
        key = jax.random.key(11 + i)
        (s1, m1), (s2, m2) = fused(state, key), plain(state, key)
        assert set(m1) == set(m2) == set(atac_step.metric_names(core))
        close(m1, m2, rtol=2e-5, atol=1e-6)
        close(s1, s2, rtol=2e-5, atol=1e-6)


def test_one_step_equals_plain_formulation_float64(variant):
    core, _, _, states = variant
    to64 = lambda t: jax.tree.map(  # noqa: E731
        lambda x: x.astype(jnp.float64) if jnp.issubdtype(x.dtype, jnp.floating) else x, t)
    with jax.enable_x64(True):
        fused, plain = jitted(core._replace(ds=to64(core.ds), log_alpha0=to64(core.log_alpha0)))
        for i, state in enumerate(states):
            s64, key = to64(state), jax.random.key(21 + i)
            (s1, m1), (s2, m2) = fused(s64, key), plain(s64, key)
            assert m1["critic_loss"].dtype == jnp.float64
            close(m1, m2, rtol=1e-9, atol=1e-12)
            close(s1, s2, rtol=1e-9, atol=1e-12)


# --------------------------------------------------------------------------------------------
# A short run


def test_short_run_equals_plain_formulation():
    """50 steps × 2 seeds (6 blocks of 8, then 2) of ``make_train`` against the reference."""
    cfg = dataclasses.replace(CFG, warmstart_steps=20, num_steps=50)
    trainer = atac.make_train(dataset(), cfg)
    core = atac.build_core(dataset(), cfg, atac.dataset_rewards())
    keys = jax.random.split(jax.random.key(3), 2)
    fused = jax.jit(jax.vmap(trainer.train), compiler_options=FAST)(keys)
    plain = jax.jit(jax.vmap(lambda k: plain_run(core, trainer.init(k), cfg.num_steps)),
                    compiler_options=FAST)(keys)
    assert fused[1]["critic_loss"].shape == (2, 50)
    close(fused[1], plain[1], rtol=1e-3, atol=1e-6, per_tensor=True)
    close(fused[0].params, plain[0].params, rtol=5e-3, atol=1e-6, per_tensor=True)
    # Other blocks (25 of 2 steps, unrolled) only regroup the same steps.
    other = atac.make_train(dataset(), dataclasses.replace(cfg, block_steps=2, unroll=2))
    regrouped = jax.jit(jax.vmap(other.train), compiler_options=FAST)(keys)
    close(regrouped[1], fused[1], rtol=1e-3, atol=1e-6, per_tensor=True)
    close(regrouped[0].params, fused[0].params, rtol=5e-3, atol=1e-6, per_tensor=True)


# --------------------------------------------------------------------------------------------
# The operation count of a compiled step (offline.experiment.step_profile)


def test_step_structure_counts_the_parts_of_a_tiny_step():
    trainer = atac.make_train(dataset(), dataclasses.replace(CFG, block_steps=2))
    row = step_profile.step_structure(trainer, seeds=2, chunk=4)
    assert row["backend"] == jax.default_backend() and row["chunk"] == 4
    assert 0 < row["ops_per_step_rng_loops_as_one"] <= row["ops_per_step"]
    assert row["fusions_per_step"] <= row["ops_per_step"]
    assert sum(row["by_part"].values()) == pytest.approx(row["ops_per_step"], abs=0.1)
    for part in ("actor_forward", "critic_forward", "critic_backward", "actor_backward",
                 "critic_optimizer", "target_update"):
        assert row["by_part"].get(part, 0) > 0, (part, row["by_part"])
    assert row["static"]["while_loops"] >= 1 and np.isfinite(row["compile_s"])
    assert (row["gpu_kernels"] is None) == (jax.devices()[0].platform != "gpu")
    with pytest.raises(ValueError, match="ENTRY"):
        step_profile.parse_hlo("not hlo")

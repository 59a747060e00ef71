"""Learning from one rollout: GAE, then ``update_epochs × num_minibatches`` Adam steps on the
clipped-surrogate loss (thesis §6.2.3), each epoch a fresh shuffle (``lax.scan`` throughout).
What a policy computes from the state alone (the hand-designed RMP² tree of the residual RMP
policy: :meth:`agents.ppo.networks.PPONetworks.policy_features`) comes with the rollout's
transitions, computed once per state, and is shuffled with the batch.

The batch ``(T, N, ...)`` is laid out environment-major in ``blocks`` equal blocks of whole
environments (one per device under a mesh, so shuffling never moves data between devices);
every minibatch takes the same number of samples from each block.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax
from jax.sharding import Mesh

from agents.ppo.config import PPOConfig
from agents.ppo.hparams import resolve
from agents.ppo.losses import gae, ppo_loss
from agents.ppo.networks import PPONetworks
from agents.ppo.normalization import update_stats
from agents.ppo.rollout import episode_metrics
from agents.ppo.sharding import batch_axis_sharding
from agents.ppo.state import TrainState, Transition


def make_optimizer(config: PPOConfig) -> optax.GradientTransformation:
    """Adam at unit step size (``adam_eps``) after global-norm clipping at ``max_grad_norm``
    (none when it is None). The update scales its output by the learning rate
    (:func:`agents.ppo.hparams.resolve`): the values of ``optax.adam(learning_rate)`` bit for
    bit (a sign flip, then one product rounded once) and the same optimiser state."""
    tx = optax.adam(1.0, eps=config.adam_eps)
    if config.max_grad_norm is not None:
        tx = optax.chain(optax.clip_by_global_norm(config.max_grad_norm), tx)
    return tx


def shuffle_blocks(config: PPOConfig, mesh: Mesh | None) -> int:
    """How many blocks an epoch shuffles within (``config.shuffle_blocks``, else one per
    device of ``mesh``, else 1)."""
    return config.shuffle_blocks or (1 if mesh is None else mesh.size)


def _to_blocks(x: jax.Array, blocks: int) -> jax.Array:
    """``(T, N, ...) -> (blocks, N/blocks·T, ...)``, environment-major: each block holds whole
    environments and stays on the device that stepped them."""
    x = jnp.swapaxes(x, 0, 1)
    return x.reshape((blocks, -1, *x.shape[2:]))


def _minibatches(x: jax.Array, perm: jax.Array, n_mb: int) -> jax.Array:
    """``(blocks, block_len, ...)`` permuted per block by ``perm`` → ``(n_mb, mb_size, ...)``,
    block-major inside a minibatch."""
    blocks = x.shape[0]
    x = jax.vmap(lambda xb, pb: xb[pb])(x, perm)
    x = x.reshape((blocks, n_mb, -1, *x.shape[2:]))
    return jnp.swapaxes(x, 0, 1).reshape((n_mb, -1, *x.shape[3:]))


def make_update(nets: PPONetworks, tx: optax.GradientTransformation, config: PPOConfig,
                mesh: Mesh | None = None
                ) -> Callable[[TrainState, Transition, jax.Array], tuple[TrainState, dict]]:
    """``update(ts, transitions, key) -> (ts, metrics)``: GAE, the SGD epochs, the observation
    statistics merged with the rollout (after the update, so an iteration's rollout and update
    see the same statistics) and the iteration's metrics (means over every minibatch update
    plus :func:`agents.ppo.rollout.episode_metrics`)."""
    n_mb = config.num_minibatches
    blocks = shuffle_blocks(config, mesh)
    block_len = config.batch_size // blocks
    constrain_blocks = batch_axis_sharding(mesh, blocks)
    constrain_mb = batch_axis_sharding(mesh, config.minibatch_size)

    def loss(params, batch, stats, hp):
        features = batch.get("policy_features")
        return ppo_loss(params, batch, lambda p, o: nets.policy_apply(p, o, stats, features),
                        lambda p, o: nets.value_apply(p, o, stats), hp.clip_eps,
                        hp.vf_coef, hp.ent_coef, config.normalize_advantages)

    loss_grad = jax.value_and_grad(loss, has_aux=True)

    def epochs(params, opt_state, stats, flat, keys, hp):
        def update_minibatch(carry, mb):
            params, opt_state, sums = carry
            (_, metrics), grads = loss_grad(params, constrain_mb(mb), stats, hp)
            updates, opt_state = tx.update(grads, opt_state, params)
            updates = jax.tree.map(lambda u: hp.learning_rate * u, updates)
            sums = jax.tree.map(jnp.add, sums, metrics)
            return (optax.apply_updates(params, updates), opt_state, sums), None

        def update_epoch(carry, perm):
            mbs = constrain_mb(jax.tree.map(lambda x: _minibatches(x, perm, n_mb), flat), 1)
            return jax.lax.scan(update_minibatch, carry, mbs)[0], None

        # every epoch's shuffle drawn before the epochs: one batched sort instead of one per
        # epoch (the same permutations as drawing each inside its epoch)
        perms = jax.vmap(lambda key: jax.vmap(lambda k: jax.random.permutation(k, block_len))(
            jax.random.split(key, blocks)))(keys)
        # the minibatch metrics summed in the loop's carry, not stacked: stacking wrote each
        # one into its own buffer, a kernel per metric per minibatch step on a GPU
        mb = jax.tree.map(lambda x: jax.ShapeDtypeStruct((config.minibatch_size, *x.shape[2:]),
                                                         x.dtype), flat)
        sums = jax.tree.map(lambda m: jnp.zeros(m.shape, m.dtype),
                            jax.eval_shape(lambda p, b, s: loss(p, b, s, hp)[1],
                                           params, mb, stats))
        (params, opt_state, sums), _ = jax.lax.scan(update_epoch, (params, opt_state, sums),
                                                    perms)
        steps = config.update_epochs * n_mb
        return (params, opt_state), {k: v / steps for k, v in sums.items()}

    def update(ts, tr, key):
        stats, hp = ts.obs_stats, resolve(config, ts.hparams)
        last_value = nets.value_apply(ts.params["value"], ts.env_state.obs, stats)
        adv, ret = gae(tr.rewards, tr.values, tr.dones, tr.truncations, last_value,
                       hp.gamma, hp.gae_lambda)
        flat = {"obs": tr.obs, "actions": tr.actions, "log_probs": tr.log_probs,
                "advantages": adv, "returns": ret}
        if tr.policy_features is not None:  # the rollout's, not computed again per epoch
            flat["policy_features"] = tr.policy_features
        flat = constrain_blocks(jax.tree.map(lambda x: _to_blocks(x, blocks), flat))
        (params, opt_state), upd = epochs(ts.params, ts.opt_state, stats, flat,
                                          jax.random.split(key, config.update_epochs), hp)
        if config.normalize_observations:
            stats = update_stats(stats, tr.obs)
        metrics = dict(upd)
        metrics.update(episode_metrics(tr))
        ts = ts._replace(params=params, opt_state=opt_state, obs_stats=stats,
                         iteration=ts.iteration + 1)
        return ts, metrics

    return update


__all__ = ["make_optimizer", "make_update", "shuffle_blocks"]

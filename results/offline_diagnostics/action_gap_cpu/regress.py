"""Held-out regression of the expert's action on its observation, 3-link env3 (session 12):
N expert episodes split 90/10 by episode, a 3x256 MLP trained by MSE for 20k Adam steps on
standardised inputs, with the observation entries listed. Usage: python regress.py N"""
import sys
import warnings

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax

from offline import collect
from offline import data as odata


class MLP(nn.Module):
    @nn.compact
    def __call__(self, x):
        for _ in range(3):
            x = nn.relu(nn.Dense(256)(x))
        return nn.Dense(3)(x)


def run(train, test, layout, names, steps=20000):
    c = np.concatenate([np.arange(*layout[n]) for n in names])
    x, y = np.asarray(train.observations)[:, c], np.asarray(train.actions)
    xt, yt = np.asarray(test.observations)[:, c], np.asarray(test.actions)
    mu, sd = x.mean(0), x.std(0) + 1e-6
    x, xt = jnp.asarray((x - mu) / sd), (xt - mu) / sd
    yj = jnp.asarray(y)
    model = MLP()
    params = model.init(jax.random.PRNGKey(0), x[:1])
    opt = optax.adam(5e-4)
    opt_state = opt.init(params)

    @jax.jit
    def step(params, opt_state, key):
        i = jax.random.randint(key, (256,), 0, x.shape[0])
        grads = jax.grad(lambda p: jnp.mean(jnp.sum((model.apply(p, x[i]) - yj[i]) ** 2, -1)))(
            params)
        updates, opt_state = opt.update(grads, opt_state)
        return optax.apply_updates(params, updates), opt_state

    key = jax.random.PRNGKey(1)
    for _ in range(steps):
        key, sub = jax.random.split(key)
        params, opt_state = step(params, opt_state, sub)

    def err(a, b):
        return float(np.mean(np.sum((np.asarray(model.apply(params, a)) - b) ** 2, -1)))

    print(names, "train", round(err(x, y), 3), "held-out", round(err(xt, yt), 3), "var",
          round(float(yt.var(0).sum()), 3), flush=True)


def main() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = collect.collect_recipe("three_link/env3", "expert", int(sys.argv[1]), seed=0)
    train, test = odata.split_by_episode(ds, 0.9, jax.random.PRNGKey(0))
    layout = ds.metadata["observation_layout"]
    print(layout)
    base = ["sin_q", "cos_q", "qd", "goal_minus_x"]
    for extra in ([], ["obstacle_vectors"], ["obstacle_vectors", "obstacles"]):
        run(train, test, layout, base + extra)


if __name__ == "__main__":
    main()

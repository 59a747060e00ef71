"""Does the pessimistic critic separate goal-anchored episodes from failures (zero reward)?

Usage, from the repository root: ``python <this file> STEPS DATA.npz``, with DATA the
medium-replay collision-cut data of

    python scripts/reproduce_ch8.py --recipes medium-replay --goal-deadline 350 --scale 20 \
        --stage collect --out OUT      # OUT/data/three_link-env3_medium-replay_cut_x20_s0.npz

It trains PSPI (absolute pessimism) and ATAC (relative) with the zero reward on the ``-goal``
and ``-deadline`` versions of that data (one seed, 2 x 128 critics, NN-RESIDUAL actor, half the
steps BC warm start, scaled actor rate) and prints one JSON line per run: the min-over-critics
Q(s, a) of the data transitions, averaged per episode outcome (success: the episode reached
the goal by the deadline and was kept whole) and position (first 50, last 10 transitions).
"""

import json
import sys

sys.path.insert(0, ".")

import mjxrmp  # noqa: F401  (sets the XLA:CPU flag before JAX initialises)

# isort: split
import jax
import jax.numpy as jnp
import numpy as np

from offline import atac, collect, experiment, survival
from offline import data as odata
from offline.networks import QEnsemble

HIDDEN = (128, 128)


def main(steps: int, path: str) -> None:
    env = collect.make_env("three_link/env3")
    radius = float(env.success_radius)
    cut = odata.check_environment(odata.load(path), env, name="data")
    deadline = survival.cut_before_goal(cut, 350, radius=radius)
    # Kept whole = arrived by the deadline; the same episodes in both versions.
    whole = ~odata.episode_statistics(deadline)[0].terminated
    versions = {"goal": survival.absorbing_goal(deadline, radius=radius), "deadline": deadline}
    _, lengths = odata.episode_bounds(np.asarray(deadline.episode_ids))
    success = np.repeat(whole, lengths)
    position = np.concatenate([np.arange(n) for n in lengths])
    from_end = np.concatenate([np.arange(n)[::-1] for n in lengths])
    groups = {"all": np.ones_like(success), "first50": position < 50, "last10": from_end < 10}
    budget = experiment.Budget(steps=steps, hidden=HIDDEN, batch=256, actor="nn_residual",
                               warmstart=0.5, actor_rate="scaled")
    for name, ds in versions.items():
        zero = survival.variant(ds, "zero", "keep")
        plain = zero.replace(metadata=zero.metadata.updated(rewards_visible=True))
        for pessimism in ("absolute", "relative"):
            trainer = atac.make_train(plain, experiment.atac_config(budget, pessimism=pessimism))
            state, _ = experiment.train_chunked(trainer, experiment.seed_keys([0]), 5000)
            critic = jax.tree.map(lambda x: x[0], state.params["critic"])
            q = QEnsemble(2, hidden_sizes=HIDDEN).apply(
                critic, jnp.asarray(ds.observations, jnp.float32),
                jnp.asarray(ds.actions, jnp.float32))
            q = np.asarray(q).min(-1)
            row = {"data": name, "pessimism": pessimism, "steps": steps,
                   "success_episodes": int(whole.sum()), "episodes": int(whole.size)}
            for g, mask in groups.items():
                row[f"q_success_{g}"] = float(q[success & mask].mean())
                row[f"q_fail_{g}"] = float(q[~success & mask].mean())
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]), sys.argv[2])

"""What RP's and a constant reward look like on the dynamics data (session 13).

RP in ILfO fits g(s, s', terminal) to the expert's state transitions, all labelled 1 (eq 7.3),
then freezes it. This script fits g exactly as RP does (offline.plfo_baselines.make_train_rp's
init, REWARD_STEPS Adam steps) on the expert data of DATA_DIR and prints g's predictions on the
`mixed` dynamics data per source, against the true rewards, and on the transitions that end in
a collision. Usage: python rp_reward.py DATA_DIR EXPERT_EPISODES [REWARD_STEPS]
(data from `reproduce_ch7.py --stage collect --substeps 24 ...`).
"""
import glob
import sys

import jax
import numpy as np
from offline.mahalo import RewardNetConfig, make_reward_net
from offline.plfo_baselines import RPConfig, make_train_rp

from offline import collect, scenarios
from offline import data as odata

DATA, N_EXPERT = sys.argv[1], int(sys.argv[2])
STEPS = int(sys.argv[3]) if len(sys.argv) > 3 else 50_000


def main() -> None:
    mixed = odata.load(glob.glob(f"{DATA}/three_link-env3_mixed_*substeps_24.npz")[0])
    expert = odata.load(glob.glob(f"{DATA}/three_link-env3_expert_x{N_EXPERT}_*substeps_24.npz")[0])
    dyn, rd = scenarios.make("ILfO", mixed, expert, key=jax.random.PRNGKey(0))
    cfg = RPConfig(reward=RewardNetConfig(max_reward_label=True), reward_steps=STEPS)
    state = jax.jit(make_train_rp(dyn, cfg, reward_data=rd).init)(jax.random.PRNGKey(0), 16.0)
    g = make_reward_net(rd, cfg.reward, observation_size=dyn.observation_size,
                        remove_terminals=False, learner="RP")
    pred = np.asarray(g.predict(state.params["reward"], float32_states(dyn))).reshape(-1)
    on_expert = np.asarray(g.predict(state.params["reward"], float32_states(rd))).reshape(-1)
    true = np.asarray(mixed.rewards, np.float64)
    src = collect.source_of_episodes(mixed)
    term = np.asarray(mixed.terminals, bool)
    print(f"g fitted on {rd.size} expert transitions ({N_EXPERT} episodes), {STEPS} steps: "
          f"on them mean {on_expert.mean():.3f} min {on_expert.min():.3f}")
    for i, s in enumerate(mixed.metadata["sources"]):
        m = src == i
        print(f"  mixed source {i} ({s['behaviour']['name']}): {m.sum()} transitions, "
              f"g mean {pred[m].mean():.3f} (q10 {np.quantile(pred[m], .1):.3f}, "
              f"q90 {np.quantile(pred[m], .9):.3f}), true reward mean {true[m].mean():.3f}")
    print(f"  collision transitions (terminals): {term.sum()}, g mean {pred[term].mean():.3f}")
    print(f"  all mixed: g mean {pred.mean():.3f}, fraction above 0.9 {np.mean(pred > .9):.3f}, "
          f"corr(g, true reward) {np.corrcoef(pred, true)[0, 1]:.3f}")


def float32_states(d):
    """``d`` (dynamics or reward data) with float32 states, on the device: g's input."""
    return jax.device_put(d.replace(observations=np.asarray(d.observations, np.float32),
                                    next_observations=np.asarray(d.next_observations,
                                                                 np.float32)))


if __name__ == "__main__":
    main()

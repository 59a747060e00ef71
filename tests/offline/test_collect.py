"""Offline data collection (offline/data/collect.py), PLfO scenarios (offline/data/scenarios.py) and
the collection CLI (scripts/collect.py).

Every scripted collection here runs on 3-link env1 with the environment's 600-step horizon in
chunks of BATCH = 8 episodes, so expert, noisy and random data share one compiled program
(compiling dominates on CPU; 600 steps × 8 episodes run in well under a second). PPO data comes
from a tiny two-checkpoint run (trained once per module) and shares a second program.
"""

from __future__ import annotations

import itertools
import json
import os
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from script_main import load_script

import mjxrmp  # noqa: F401  (XLA flags first)
from agents.ppo import PPOConfig
from agents.ppo.policies import decode_observation
from agents.run import checkpoint
from agents.run.program import build, seed_keys
from agents.run.spec import RunSpec
from mjxrmp import policies as rmp_policies
from offline.data import behaviours, rollouts
from offline.data import collect as oc
from offline.data import dataset as odata
from offline.data import scenarios as sc

ENV = "three_link/env1"
BATCH = 8
# Seed whose 8 uniform-random episodes on env1 include collisions (2) and timeouts (6).
COLLIDING_SEED = 4
SPEC = RunSpec(env=ENV, policy="nn", seeds=(0,),
               ppo=PPOConfig(num_envs=4, rollout_length=8, num_minibatches=2, update_epochs=1,
                             total_iterations=2, policy_hidden_sizes=(8,),
                             value_hidden_sizes=(8,), episode_length=10),
               log_every=1, checkpoint_every=1)


def _collect(behaviour, seed=0, n=BATCH):
    return oc.collect(ENV, behaviour, n, seed=seed, batch_size=BATCH)


def _rollout(behaviour, seed=0, n=BATCH):
    return rollouts.rollout(ENV, behaviour, n, jax.random.PRNGKey(seed), batch_size=BATCH)


@pytest.fixture(scope="module")
def env():
    return rollouts.make_env(ENV)


@pytest.fixture(scope="module")
def random_traj():
    return _rollout(behaviours.uniform_random(), COLLIDING_SEED)


@pytest.fixture(scope="module")
def recipes():
    """Every recipe without a PPO run (scale 8), with the warnings each emitted."""
    out = {}
    for r in oc.RECIPES:
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            ds = oc.collect_recipe(ENV, r, BATCH, seed=1)
        out[r] = (ds, [str(x.message) for x in w if issubclass(x.category, UserWarning)])
    return out


@pytest.fixture(scope="module")
def ppo_run(tmp_path_factory):
    """A run directory laid out as ``run_training`` writes it (``run.json``, orbax checkpoints
    1 and 2 with the same meta) holding *untrained* policies: freshly initialised policy
    parameters, doubled at step 2, every other leaf of the state zero. Compiling PPO (or even
    its ``init``, which samples scenes) costs 5–25 s on a shared CPU; collection only reads
    the policy parameters of a checkpoint :func:`agents.run.loading.load_run` accepts.
    (tests/test_eval covers real runs.)"""
    out = str(tmp_path_factory.mktemp("ppo_run"))
    with open(os.path.join(out, "run.json"), "w") as f:
        json.dump(SPEC.to_json(), f)
    program = build(SPEC)
    keys = seed_keys(SPEC.seeds)
    template = jax.eval_shape(program.init, keys)
    state = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), template)
    obs = jnp.zeros((rollouts.make_env(ENV).observation_size,), jnp.float32)
    policy = program.trainer.policy.init(jax.random.PRNGKey(0), obs)
    for step in (1, 2):
        params = jax.tree.map(lambda x, s=step: (x * s)[None], policy)  # leading seed axis
        state = state._replace(params={**state.params, "policy": params})
        meta = dict(SPEC.identity(), iteration=step, history={}, run=SPEC.to_json())
        checkpoint.save(os.path.join(out, "checkpoints"), step, state, meta)
    return out


def _arrays_equal(a: odata.Dataset, b: odata.Dataset) -> bool:
    return all(np.array_equal(np.asarray(x), np.asarray(y)) and x.dtype == y.dtype
               for x, y in zip(a.arrays().values(), b.arrays().values(), strict=True))


def test_deterministic_from_seed():
    a = _collect(behaviours.uniform_random(), COLLIDING_SEED)
    b = _collect(behaviours.uniform_random(), COLLIDING_SEED)
    assert _arrays_equal(a, b) and a.metadata == b.metadata
    c = _collect(behaviours.uniform_random(), COLLIDING_SEED + 1)
    assert not np.array_equal(np.asarray(a.observations[:5]), np.asarray(c.observations[:5]))
    # Episode i depends only on (key, i): fewer episodes give a prefix, whatever the chunking.
    d = oc.collect(ENV, behaviours.uniform_random(), 3, seed=COLLIDING_SEED, batch_size=BATCH)
    n = d.size
    assert np.array_equal(np.asarray(d.actions), np.asarray(a.actions[:n]))
    assert a.metadata["behaviour"] == {"name": "random", "kind": "random"}
    assert a.metadata["reward_range"] == [-5.0, 1.0] and a.metadata["horizon"] == 600


def test_terminals_exactly_at_collisions(random_traj):
    traj, ep = random_traj, random_traj["episode"]
    ds = rollouts.to_dataset(traj)
    per, summary = odata.episode_statistics(ds)
    ended = (ep["collided"] > 0) | (ep["nonfinite"] > 0)
    assert 0 < ended.sum() < BATCH, "the seed must give both collisions and timeouts"
    np.testing.assert_array_equal(per.terminated, ended)
    np.testing.assert_array_equal(per.timed_out, ~ended)
    np.testing.assert_array_equal(per.lengths, ep["length"].astype(np.int64))
    np.testing.assert_allclose(per.returns, ep["return"], rtol=1e-5, atol=1e-4)
    assert summary["num_unfinished"] == 0
    # Per step: a terminal exactly where the environment reported a collision (valid steps).
    valid = traj["valid"]
    coll = (traj["collision"] > 0) | (traj["nonfinite"] > 0)
    assert np.array_equal((traj["dones"] > 0), coll & valid)
    term_steps = np.swapaxes(coll & valid, 0, 1)[np.swapaxes(valid, 0, 1)]
    np.testing.assert_array_equal(np.asarray(ds.terminals), term_steps)
    # Frozen steps after a collision are dropped.
    assert ds.size == int(valid.sum()) == int(ep["length"].sum())


def test_terminal_next_observation_is_the_true_last_one(env, random_traj):
    ds = rollouts.to_dataset(random_traj)
    ep = random_traj["episode"]
    obs, nxt = np.asarray(ds.observations), np.asarray(ds.next_observations)
    ends = np.nonzero(np.asarray(ds.terminals) | np.asarray(ds.timeouts))[0]
    np.testing.assert_array_equal(nxt[ends], ep["final_observation"])
    # Inside an episode s'_t = s_{t+1}; at an episode's end s' is not the next episode's s_0.
    inner = np.setdiff1d(np.arange(ds.size - 1), ends)
    np.testing.assert_array_equal(nxt[inner], obs[inner + 1])
    starts = ends[:-1] + 1
    assert not np.any(np.all(nxt[ends[:-1]] == obs[starts], axis=1))
    # The terminal next observation is in collision (decoded q and obstacles), timeouts not.
    q, _, _, obstacles = decode_observation(env, jnp.asarray(nxt[ends]))
    dist = jax.vmap(env.distances)(q, obstacles)  # (E, P, O)
    active = np.asarray(obstacles.active)[:, None, :] > 0
    min_d = np.where(active, np.asarray(dist), np.inf).min(axis=(1, 2))
    term = np.asarray(ds.terminals)[ends]
    assert (min_d[term] < 1e-4).all() and (min_d[~term] > 0).all()


def test_noisy_expert_actions_are_expert_plus_clipped_noise(env):
    lim = env.action_limit
    exp = _rollout(behaviours.expert())
    # sigma 0.5 (a recipe level) and 3.0 (mostly clipped) run in the same compiled program.
    for sigma in (0.5, 3.0):
        noisy = _rollout(behaviours.noisy_expert(sigma))
        v = noisy["valid"]
        act, raw, base = (noisy[k][v] for k in ("actions", "raw_actions", "base_actions"))
        # Recorded = what the environment applied: clip(expert + σ·ε), inside the box. Compiled
        # as the scripts compile it the two are bitwise equal; at the suite's LLVM O0
        # (conftest.py) XLA:CPU's two uses of the raw action can differ by a few float32 ulps.
        np.testing.assert_allclose(act, np.clip(raw, -lim, lim), rtol=0, atol=2e-7)
        assert np.all(np.abs(act) <= lim) and np.all(np.abs(base) <= lim)
        noise = (raw - base) / sigma  # ~ N(0, 1), i.i.d.
        assert abs(noise.mean()) < 0.05 and abs(noise.std() - 1.0) < 0.05
        clipped = np.abs(raw) > lim
        assert (clipped.mean() > 0.5) == (sigma > 1)
        assert np.all(np.abs(act[clipped]) == lim)
        # Same seed, same scenes: the first step's expert action is the expert rollout's.
        np.testing.assert_array_equal(noisy["observations"][0], exp["observations"][0])
        np.testing.assert_array_equal(noisy["base_actions"][0], exp["actions"][0])
        assert not np.allclose(noisy["actions"][0], exp["actions"][0])
    # The expert records exactly its (clipped) RMP² action; check one step against a direct
    # evaluation of the hand-designed policy on the decoded observation.
    np.testing.assert_array_equal(exp["actions"][exp["valid"]],
                                  exp["base_actions"][exp["valid"]])
    cfg = rmp_policies.default_config(env.robot_name, "hand_designed")
    q, qd, goal, obstacles = decode_observation(env, jnp.asarray(exp["observations"][0]))
    direct = jax.jit(jax.vmap(lambda *a: rmp_policies.acceleration(cfg, *a)))(
        q, qd, goal, obstacles)
    np.testing.assert_allclose(np.clip(direct, -lim, lim), exp["actions"][0], atol=1e-4)


def test_uniform_random_actions_fill_the_box(env, random_traj):
    act = random_traj["actions"][random_traj["valid"]]
    lim = env.action_limit
    assert np.all(np.abs(act) <= lim)
    assert act.min() < -0.95 * lim and act.max() > 0.95 * lim
    assert abs(act.mean()) < 0.05 and abs(act.std() - lim / np.sqrt(3)) < 0.05


def test_recipes_composition_and_fallback(recipes):
    names = {r: [s["behaviour"]["name"] for s in ds.metadata["sources"]]
             for r, (ds, _) in recipes.items()}
    assert names == {
        "random": ["random"],
        "medium": ["noisy-0.5"],
        "medium-replay": ["random", "noisy-1.0", "noisy-0.5"],
        "medium-expert": ["noisy-0.5", "expert"],
        "expert": ["expert"],
        "mixed": ["random", "noisy-1.0", "noisy-0.5", "noisy-0.1"],
    }
    for r, (ds, warned) in recipes.items():
        meta = ds.metadata
        counts = [s["episodes"] for s in meta["sources"]]
        assert counts == ([3, 3, 2] if r == "medium-replay" else [BATCH] * len(counts))
        _, summary = odata.episode_statistics(ds)
        assert summary["num_episodes"] == meta["num_episodes"] == sum(counts)
        assert (meta["recipe"], meta["scale"], meta["seed"], meta["env"]) == (r, BATCH, 1, ENV)
        # Sources occupy consecutive episode-id ranges, in table order.
        bounds = [s["episode_ids"] for s in meta["sources"]]
        assert bounds[0][0] == 0 and all(a[1] == b[0] for a, b in itertools.pairwise(bounds))
        src = oc.source_of_episodes(ds)
        assert (src >= 0).all() and np.all(np.diff(src) >= 0)
        fallback = r in ("medium", "medium-replay", "medium-expert", "mixed")
        assert (meta["fallback"] is not None) == fallback
        assert bool(warned) == fallback
        if fallback:
            assert meta["fallback"].startswith("FALLBACK") and warned == [meta["fallback"]]
        assert [s["fallback"] for s in meta["sources"]] == (
            [r in ("medium", "medium-replay")] * len(counts) if r != "medium-expert"
            else [True, False])
    # A source is the same data in every recipe that has it (same seed, role and behaviour).
    exp, med_exp = recipes["expert"][0], recipes["medium-expert"][0]
    half = oc.source_of_episodes(med_exp) == 1
    np.testing.assert_array_equal(np.asarray(exp.observations),
                                  np.asarray(med_exp.observations)[half])
    with pytest.raises(ValueError, match="valid recipes are"):
        oc.recipe_sources("expert-replay", 4)


def test_ppo_behaviours_and_recipes(ppo_run, tmp_path):
    sources, fallback = oc.recipe_sources("mixed", 4, ppo_run=ppo_run)
    assert fallback is None
    assert [(s.role, s.behaviour.name, s.episodes) for s in sources] == [
        ("random", "random", 4), ("noisy", "noisy-1.0", 4), ("noisy", "noisy-0.5", 4),
        ("noisy", "noisy-0.1", 4), ("low", "ppo-low-step1", 4),
        ("medium", "ppo-medium-step2", 4), ("medium-replay", "ppo-replay-step1", 2),
        ("medium-replay", "ppo-replay-step2", 2)]
    assert all(s.behaviour.stochastic for s in sources if s.behaviour.kind == "ppo")
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # no fallback warning with a run
        med = oc.collect_recipe(ENV, "medium", BATCH, seed=0, ppo_run=ppo_run, ppo_step=1,
                                ppo_stochastic=False)
    (src,) = med.metadata["sources"]
    assert src["behaviour"] == {"name": "ppo-medium-step1", "kind": "ppo", "run_dir": ppo_run,
                                "step": 1, "seed_index": 0, "stochastic": False}
    assert med.metadata["fallback"] is None and med.metadata["ppo_run"] == ppo_run
    # Deterministic = the Gaussian mean, clipped; stochastic samples differ; both in the box.
    det = _rollout(behaviours.ppo_policy(ppo_run, 1))
    sto = _rollout(behaviours.ppo_policy(ppo_run, 1, stochastic=True))
    v = det["valid"]
    np.testing.assert_array_equal(det["raw_actions"][v], det["base_actions"][v])
    np.testing.assert_array_equal(det["actions"][v], np.clip(det["base_actions"][v], -1, 1))
    v = sto["valid"]
    z = (sto["raw_actions"][v] - sto["base_actions"][v]) / np.exp(-1.0)  # log_std init −1
    assert abs(z.mean()) < 0.1 and abs(z.std() - 1.0) < 0.1
    assert np.abs(sto["actions"]).max() <= 1.0
    assert not np.allclose(sto["actions"][0], det["actions"][0])
    np.testing.assert_array_equal(sto["observations"][0], det["observations"][0])
    ds = rollouts.to_dataset(det)
    assert ds.observation_size == rollouts.make_env(ENV).observation_size and ds.action_size == 3
    with pytest.raises(ValueError, match="not a checkpoint"):
        oc.recipe_sources("medium", 2, ppo_run=ppo_run, ppo_step=7)


def test_plfo_scenarios(recipes, tmp_path):
    mixed, expert = recipes["mixed"][0], recipes["expert"][0]
    k = odata.episode_statistics(mixed)[1]["num_episodes"]
    e = odata.episode_statistics(expert)[1]["num_episodes"]
    key = jax.random.PRNGKey(0)
    got = {name: sc.make(name, mixed, expert, key=key) for name in sc.SCENARIOS}
    for name, (dyn, rd) in got.items():
        assert isinstance(dyn, odata.Dataset) and isinstance(rd, sc.RewardData)
        assert not hasattr(rd, "actions")
        assert dyn.metadata["plfo_role"] == "dynamics" and not dyn.metadata["rewards_visible"]
        assert rd.metadata["plfo_role"] == "reward" and rd.metadata["plfo_scenario"] == name
        with_expert = name in ("IL", "RL-expert")
        assert dyn.size == mixed.size + (expert.size if with_expert else 0)
        assert dyn.metadata["part_names"] == (["mixed", "expert"] if with_expert
                                              else ["mixed"])
        for k_env in sc.ENVIRONMENT_KEYS:  # the environment facts stay at the top level
            assert dyn.metadata[k_env] == mixed.metadata.to_dict()[k_env], k_env
        np.testing.assert_array_equal(np.asarray(dyn.actions[:mixed.size]),
                                      np.asarray(mixed.actions))
        ids = np.asarray(rd.episode_ids)
        if name == "RL-sample":
            assert rd.metadata["source"] == "mixed" and rd.metadata["reward_label"] == "true"
            labelled = np.unique(ids)
            assert len(labelled) == round(sc.RL_SAMPLE_FRACTION * k) and labelled.max() < k
            rows = np.isin(np.asarray(mixed.episode_ids), labelled)
            np.testing.assert_array_equal(np.asarray(rd.rewards), np.asarray(mixed.rewards)[rows])
            np.testing.assert_array_equal(np.asarray(rd.observations),
                                          np.asarray(mixed.observations)[rows])
        else:
            assert rd.size == expert.size and rd.metadata["source"] == "expert"
            np.testing.assert_array_equal(np.unique(ids), np.arange(k, k + e))
            np.testing.assert_array_equal(np.asarray(rd.next_observations),
                                          np.asarray(expert.next_observations))
            if name in ("ILfO", "IL"):  # expert-only reward: the maximum reward R_max = 1
                assert rd.metadata["reward_label"] == {"constant": 1.0}
                assert np.all(np.asarray(rd.rewards) == 1.0)
            else:
                np.testing.assert_array_equal(np.asarray(rd.rewards),
                                              np.asarray(expert.rewards))
        assert rd.metadata["overlap_with_dynamics"] == (name in ("IL", "RL-expert", "RL-sample"))
        if rd.metadata["overlap_with_dynamics"]:  # shared ids name the same episodes
            dyn_ids = np.asarray(dyn.episode_ids)
            for i in np.unique(ids)[:2]:
                np.testing.assert_array_equal(np.asarray(dyn.observations)[dyn_ids == i],
                                              np.asarray(rd.observations)[ids == i])
    other = expert.replace(metadata=expert.metadata.updated(action_limit=2.0))
    with pytest.raises(ValueError, match="disagree on metadata\\['action_limit'\\]"):
        sc.make("IL", mixed, other)
    # Terminals treated as timeouts, reward data through files and minibatches.
    rand = recipes["random"][0]
    dyn, rd = sc.make("RL-sample", rand, key=key, fraction=1.0, keep_terminals=False)
    assert not np.asarray(dyn.terminals).any() and not np.asarray(rd.terminals).any()
    assert np.asarray(dyn.timeouts).sum() == odata.episode_statistics(rand)[1]["num_episodes"]
    _, rd = got["ILfO"]
    path = sc.save_reward_data(rd, tmp_path / "reward.npz")
    back = sc.load_reward_data(path)
    assert back.metadata == rd.metadata
    for f in sc.REWARD_FIELDS:
        np.testing.assert_array_equal(np.asarray(getattr(back, f)), np.asarray(getattr(rd, f)))
    batch = odata.sample(rd, jax.random.PRNGKey(1), 5)
    assert isinstance(batch, sc.RewardData) and batch.observations.shape == (5, 26)
    odata.save(mixed, tmp_path / "mixed.npz")
    with pytest.raises(odata.DatasetFileError, match="not reward data"):
        sc.load_reward_data(tmp_path / "mixed.npz")
    with pytest.raises(ValueError, match="valid scenarios are"):
        sc.make("BC", mixed, expert)
    with pytest.raises(ValueError, match="needs expert data"):
        sc.make("IL", mixed)


def test_cli(tmp_path, capsys):
    """``scripts/collect.py``'s ``main`` (the command line, in this process: its rollout programs
    are the ones the module's fixtures compiled): the fallback warning, the report and the
    dataset file; no silent overwrite (exit status 2). Bad requests are refused by
    :func:`offline.data.collect.resolve_request`."""
    script = load_script("collect.py")
    out = tmp_path / "env1_medium.npz"
    script.main(["--env", ENV, "--recipe", "medium", "--episodes", str(BATCH), "--seed", "2",
                 "--out", str(out)])
    done = capsys.readouterr()
    assert "WARNING: FALLBACK" in done.err and "noisy-0.5" in done.err
    assert "ALL" in done.out and '"fallback": "FALLBACK' in done.out
    report = json.loads(done.out.strip().splitlines()[-1])
    ds = odata.load(out)
    assert ds.metadata["recipe"] == "medium" and ds.metadata["fallback"] == report["fallback"]
    assert report["episodes"] == BATCH and report["terminals"] + report["timeouts"] == BATCH
    assert oc.overall_summary(ds)["episodes"] == BATCH
    for bad, what in ((("nope", "mixed", 1), "valid names are"),
                      ((ENV, "nope", 1), "valid recipes are"),
                      ((ENV, "mixed", 0), "--episodes must be >= 1")):
        with pytest.raises(ValueError, match=what):
            oc.resolve_request(*bad)
    assert oc.resolve_request(ENV, "mixed", 1) == ENV
    with pytest.raises(SystemExit) as again:
        script.main(["--env", ENV, "--recipe", "expert", "--out", str(out)])
    assert again.value.code == 2 and "exists" in capsys.readouterr().err

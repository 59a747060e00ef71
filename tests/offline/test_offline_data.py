"""offline.data.dataset: Dataset pytree, checksummed files, rollout flattening, episode
operations."""

from __future__ import annotations

import io
import json
import os
import zipfile

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from offline.data import dataset as od

# A hand-made rollout, T = 5 steps of B = 3 environments (time-major). Reward = 10·env + t.
#   env 0: done at t=1 (collision), done at t=4 (time limit)      -> episodes [0,1], [2,3,4]
#   env 1: no done                                               -> one unfinished episode
#   env 2: done at t=0 (time limit), done at t=2 (collision)      -> [0], [1,2], unfinished [3,4]
T, B, O, A = 5, 3, 2, 1
DONES = np.zeros((T, B), np.int32)
TRUNC = np.zeros((T, B), np.int32)
DONES[1, 0] = DONES[4, 0] = 1
TRUNC[4, 0] = 1
DONES[0, 2] = DONES[2, 2] = 1
TRUNC[0, 2] = 1


def _rollout():
    t_idx, b_idx = np.meshgrid(np.arange(T), np.arange(B), indexing="ij")
    rewards = (10.0 * b_idx + t_idx).astype(np.float32)
    obs = np.stack([t_idx, b_idx], -1).astype(np.float32)  # obs = (t, env)
    nxt = obs + np.float32(0.5)
    actions = (0.1 * t_idx[..., None]).astype(np.float32)
    return obs, actions, rewards, nxt


def _toy(metadata=None):
    """8 transitions, episodes 0 (3, terminal), 1 (2, timeout), 2 (3, timeout)."""
    rng = np.random.default_rng(0)
    n = 8
    return od.create(rng.normal(size=(n, 3)).astype(np.float32),
                     rng.uniform(-1, 1, size=(n, 2)).astype(np.float32),
                     np.arange(n, dtype=np.float32),
                     rng.normal(size=(n, 3)).astype(np.float32),
                     [0, 0, 1, 0, 0, 0, 0, 0], [0, 0, 0, 0, 1, 0, 0, 1],
                     [0, 0, 0, 1, 1, 2, 2, 2], metadata)


def test_from_transitions_episode_ids_and_flags():
    obs, actions, rewards, nxt = _rollout()
    ds = od.from_transitions(obs, actions, rewards, DONES, TRUNC, next_observations=nxt,
                             metadata={"env": "toy", "seed": 3})
    assert ds.size == T * B and ds.metadata == {"env": "toy", "seed": 3}
    # environment-major order, episodes numbered env by env
    t = np.asarray(ds.observations[:, 0]).astype(int)
    env = np.asarray(ds.observations[:, 1]).astype(int)
    np.testing.assert_array_equal(env, np.repeat(np.arange(B), T))
    np.testing.assert_array_equal(t, np.tile(np.arange(T), B))
    np.testing.assert_array_equal(ds.episode_ids, [0, 0, 1, 1, 1, 2, 2, 2, 2, 2, 3, 4, 4, 5, 5])
    term = np.zeros(T * B, bool)
    term[[1, 12]] = True  # env 0 t=1, env 2 t=2
    tout = np.zeros(T * B, bool)
    tout[[4, 10]] = True  # time limits: env 0 t=4, env 2 t=0
    tout[[9, 14]] = True  # unfinished episodes cut by the rollout end (default "timeout")
    np.testing.assert_array_equal(ds.terminals, term)
    np.testing.assert_array_equal(ds.timeouts, tout)
    np.testing.assert_array_equal(ds.rewards, 10.0 * env + t)
    np.testing.assert_array_equal(ds.next_observations, ds.observations + 0.5)
    assert ds.terminals.dtype == bool and ds.episode_ids.dtype == np.int32

    # (T + 1) observations instead of next_observations; "keep" leaves the tail open
    obs_next = np.concatenate([obs, obs[-1:] + 1], axis=0)
    kept = od.from_transitions(obs_next, actions, rewards, DONES, TRUNC, unfinished="keep")
    assert not kept.timeouts[9] and not kept.timeouts[14]
    np.testing.assert_array_equal(kept.episode_ids, ds.episode_ids)
    _, summary = od.episode_statistics(kept)
    assert summary["num_unfinished"] == 2

    # "drop" removes the unfinished tails; valid masks out steps before episodes are counted
    dropped = od.from_transitions(obs, actions, rewards, DONES, TRUNC, next_observations=nxt,
                                  unfinished="drop")
    np.testing.assert_array_equal(dropped.episode_ids, [0, 0, 1, 1, 1, 2, 3, 3])
    valid = np.ones((T, B), bool)
    valid[2:, 0] = False  # env 0 frozen after its first episode
    masked = od.from_transitions(obs, actions, rewards, DONES, TRUNC, next_observations=nxt,
                                 valid=valid, unfinished="drop")
    np.testing.assert_array_equal(masked.episode_ids, [0, 0, 1, 2, 2])


def test_from_transitions_refuses_bad_inputs():
    obs, actions, rewards, nxt = _rollout()
    with pytest.raises(ValueError, match="truncations must be a subset of dones"):
        od.from_transitions(obs, actions, rewards, np.zeros((T, B)), TRUNC,
                            next_observations=nxt)
    with pytest.raises(ValueError, match=r"observations must have shape \(T \+ 1, B, O\)"):
        od.from_transitions(obs, actions, rewards, DONES, TRUNC)
    with pytest.raises(ValueError, match="rewards must have shape"):
        od.from_transitions(obs, actions, rewards[:, :2], DONES, TRUNC, next_observations=nxt)
    bad = rewards.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="rewards has 1 non-finite"):
        od.from_transitions(obs, actions, bad, DONES, TRUNC, next_observations=nxt)
    with pytest.raises(ValueError, match="unfinished must be"):
        od.from_transitions(obs, actions, rewards, DONES, TRUNC, next_observations=nxt,
                            unfinished="cut")


def test_validation_errors_name_the_field():
    ds = _toy()
    with pytest.raises(ValueError, match="inconsistent leading sizes"):
        od.validate(ds.replace(rewards=ds.rewards[:5]))
    with pytest.raises(ValueError, match="terminals must have dtype bool"):
        od.validate(ds.replace(terminals=ds.terminals.astype(np.float32)))
    with pytest.raises(ValueError, match="episode_ids must have dtype int32"):
        od.validate(ds.replace(episode_ids=ds.episode_ids.astype(np.int64)))
    with pytest.raises(ValueError, match="actions must have a floating dtype"):
        od.validate(ds.replace(actions=ds.actions.astype(np.int32)))
    with pytest.raises(ValueError, match="both a terminal and a timeout"):
        od.validate(ds.replace(timeouts=ds.terminals | ds.timeouts))
    with pytest.raises(ValueError, match="not contiguous"):
        od.validate(ds.replace(episode_ids=np.array([0, 0, 0, 1, 1, 0, 0, 0], np.int32)))
    with pytest.raises(ValueError, match=r"ends episode 0 .* continues it"):
        od.validate(ds.replace(terminals=np.eye(8, dtype=bool)[1]))
    with pytest.raises(ValueError, match="JSON-serialisable"):
        _toy(metadata={"policy": object()})


def test_bad_datasets_are_refused_with_clear_messages():
    ds = _toy()
    with pytest.raises(ValueError, match="inconsistent leading sizes"):
        od.validate(ds.replace(observations=ds.observations[:-1]))
    rewards = np.asarray(ds.rewards).copy()
    rewards[3] = np.nan
    with pytest.raises(ValueError, match=r"rewards has 1 non-finite value\(s\), the first at "
                                         r"index \(3,\)"):
        od.validate(ds.replace(rewards=rewards))
    limited = ds.replace(metadata=ds.metadata.updated(action_limit=0.5))
    big = np.asarray(ds.actions).copy()
    big[2, 0] = 0.75
    with pytest.raises(ValueError, match=r"outside the action space \[-0.5, 0.5\]"):
        od.validate(limited.replace(actions=big))

    class Env:
        observation_size, action_size, action_limit = ds.observation_size, ds.action_size, 1.0

    od.check_environment(ds, Env())
    Env.observation_size += 1
    with pytest.raises(ValueError, match=r"observation size \d+, but the environment .* "
                                         r"expects \d+"):
        od.check_environment(ds, Env())
    Env.observation_size -= 1
    Env.action_limit = float(np.abs(np.asarray(ds.actions)).max()) / 2
    with pytest.raises(ValueError, match="leave the environment's action space"):
        od.check_environment(ds, Env())


def test_save_load_bit_exact(tmp_path):
    ds = _toy(metadata={"env": "three_link/env3", "behaviour": "expert+noise0.1",
                        "recipe": {"episodes": 3, "noise": [0.1, 0.5]}})
    # mixed float dtypes survive exactly (a float64 reward column, -0.0, subnormals)
    rewards = np.array([0.0, -0.0, 1e-310, 1.0 / 3, -2.5, 7.0, 8.0, 9.0], np.float64)
    ds = ds.replace(rewards=rewards)
    path = od.save(ds, tmp_path / "sub" / "ds.npz")
    assert os.listdir(tmp_path / "sub") == ["ds.npz"]  # no temporary file left behind
    back = od.load(path)
    for name in od.FIELDS:
        a, b = getattr(ds, name), getattr(back, name)
        assert a.dtype == b.dtype and a.shape == b.shape, name
        assert a.tobytes() == b.tobytes(), name
    assert back.metadata == ds.metadata
    assert back.metadata["recipe"]["noise"] == [0.1, 0.5]
    # deterministic bytes, readable by numpy.load as well
    again = od.save(back, tmp_path / "again.npz")
    with open(path, "rb") as f1, open(again, "rb") as f2:
        assert f1.read() == f2.read()
    np.testing.assert_array_equal(np.load(path)["episode_ids"], ds.episode_ids)


def _rewrite(src, dst, *, header=None, replace=None, drop=()):
    """Copy a dataset zip, optionally with a new header dict or replaced member bytes."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for name in zin.namelist():
            if name in drop:
                continue
            blob = zin.read(name)
            if name == "header.json" and header is not None:
                blob = json.dumps(header).encode()
            if replace and name in replace:
                blob = replace[name]
            zout.writestr(name, blob)


def test_load_refuses_corrupted_files(tmp_path):
    ds = _toy(metadata={"env": "toy"})
    path = str(tmp_path / "ds.npz")
    od.save(ds, path)
    with open(path, "rb") as f:
        raw = f.read()

    # 1. a flipped byte inside the array data (caught by the zip CRC)
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo("rewards.npy")
    start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    flip = bytearray(raw)
    flip[start + info.file_size - 3] ^= 0x01  # inside the float data, after the .npy header
    bad = tmp_path / "flip.npz"
    bad.write_bytes(bytes(flip))
    with pytest.raises(od.DatasetFileError, match=r"flip\.npz.*field 'rewards' is corrupted"):
        od.load(bad)

    # 2. truncated file
    bad = tmp_path / "trunc.npz"
    bad.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(od.DatasetFileError, match=r"trunc\.npz.*not a readable zip archive"):
        od.load(bad)

    # 3. array bytes changed consistently with the zip CRC, header left alone -> SHA-256
    buf = io.BytesIO()
    np.lib.format.write_array(buf, ds.rewards + np.float32(1.0))
    bad = tmp_path / "sha.npz"
    _rewrite(path, bad, replace={"rewards.npy": buf.getvalue()})
    with pytest.raises(od.DatasetFileError, match="field 'rewards' SHA-256 checksum mismatch"):
        od.load(bad)

    # 4. tampered header: a field checksum or the metadata changed -> header checksum
    with zipfile.ZipFile(path) as zf:
        header = json.loads(zf.read("header.json"))
    for change in ({"metadata": {"env": "other"}},
                   {"fields": {**header["fields"],
                               "rewards": {**header["fields"]["rewards"], "sha256": "0" * 64}}}):
        bad = tmp_path / "hdr.npz"
        _rewrite(path, bad, header={**header, **change})
        with pytest.raises(od.DatasetFileError, match=r"hdr\.npz.*header checksum mismatch"):
            od.load(bad)

    # 5. wrong version, missing field, not a dataset
    bad = tmp_path / "ver.npz"
    _rewrite(path, bad, header={**header, "format_version": 99})
    with pytest.raises(od.DatasetFileError, match="format_version 99 is not supported"):
        od.load(bad)
    bad = tmp_path / "missing.npz"
    _rewrite(path, bad, drop=("timeouts.npy",))
    with pytest.raises(od.DatasetFileError, match="field 'timeouts' is missing"):
        od.load(bad)
    bad = tmp_path / "plain.npz"
    np.savez(bad, rewards=ds.rewards)
    with pytest.raises(od.DatasetFileError, match=r"no header\.json"):
        od.load(bad)
    with pytest.raises(FileNotFoundError, match=r"absent\.npz"):
        od.load(tmp_path / "absent.npz")


def test_sample_jittable_and_in_range():
    ds = jax.device_put(_toy(metadata={"env": "toy"}))
    sample = jax.jit(od.sample, static_argnames="batch_size")
    batch = sample(ds, jax.random.key(0), batch_size=64)
    assert isinstance(batch, od.Dataset) and batch.metadata == {"env": "toy"}
    assert batch.observations.shape == (64, 3) and batch.actions.shape == (64, 2)
    assert batch.rewards.shape == (64,) and batch.terminals.dtype == jnp.bool_
    # rewards are the row index: every draw is a valid row, rows stay aligned across fields
    idx = np.asarray(batch.rewards).astype(int)
    assert idx.min() >= 0 and idx.max() < ds.size and len(np.unique(idx)) > 4
    np.testing.assert_array_equal(batch.observations, np.asarray(ds.observations)[idx])
    np.testing.assert_array_equal(batch.episode_ids, np.asarray(ds.episode_ids)[idx])
    with pytest.raises(ValueError, match="batch_size must be a positive"):
        od.sample(ds, jax.random.key(0), 0)


def test_relabel_rewards():
    ds = _toy(metadata={"env": "toy"})
    zero = od.relabel_rewards(ds, "zero")
    assert np.all(np.asarray(zero.rewards) == 0) and zero.rewards.dtype == ds.rewards.dtype
    neg = od.relabel_rewards(zero, "negated")
    assert neg.metadata["reward_relabel"] == ["zero", "negated"]
    rnd = od.relabel_rewards(ds, "random", key=jax.random.key(1))
    r = np.asarray(rnd.rewards)
    assert r.shape == (ds.size,) and np.all((r >= 0) & (r < 1))
    custom = jax.jit(lambda d: od.relabel_rewards(d, lambda x: x.observations[:, 0]))(ds)
    np.testing.assert_allclose(custom.rewards, ds.observations[:, 0])
    with pytest.raises(ValueError, match="needs a PRNG key"):
        od.relabel_rewards(ds, "random")
    with pytest.raises(ValueError, match=r"must have shape \(8,\)"):
        od.relabel_rewards(ds, np.zeros(3))


def test_episode_statistics_and_filter():
    ds = _toy()
    per, summary = od.episode_statistics(ds)
    np.testing.assert_array_equal(per.episode_ids, [0, 1, 2])
    np.testing.assert_array_equal(per.returns, [0 + 1 + 2, 3 + 4, 5 + 6 + 7])
    np.testing.assert_array_equal(per.lengths, [3, 2, 3])
    np.testing.assert_array_equal(per.terminated, [True, False, False])
    np.testing.assert_array_equal(per.timed_out, [False, True, True])
    assert summary["num_episodes"] == 3 and summary["num_transitions"] == 8
    assert summary["return_mean"] == pytest.approx(28 / 3)
    assert summary["return_std"] == pytest.approx(np.std([3.0, 7.0, 18.0]))
    assert (summary["return_min"], summary["return_max"]) == (3.0, 18.0)
    assert (summary["num_terminals"], summary["num_timeouts"],
            summary["num_unfinished"]) == (1, 2, 0)
    safe = od.filter_episodes(ds, lambda ep: ~ep.terminated)  # drop collided episodes
    np.testing.assert_array_equal(safe.episode_ids, [1, 1, 2, 2, 2])
    np.testing.assert_array_equal(safe.rewards, [3, 4, 5, 6, 7])
    only_first = od.filter_episodes(ds, np.array([True, False, False]))
    assert only_first.size == 3 and od.episode_statistics(only_first)[1]["num_terminals"] == 1
    with pytest.raises(ValueError, match=r"shape \(num_episodes,\) = \(3,\)"):
        od.filter_episodes(ds, np.array([True, False]))


def test_split_and_concatenate():
    obs, actions, rewards, nxt = _rollout()
    ds = od.from_transitions(obs, actions, rewards, DONES, TRUNC, next_observations=nxt)
    first, second = od.split_by_episode(ds, 0.5, jax.random.key(0))
    e1, e2 = set(np.asarray(first.episode_ids)), set(np.asarray(second.episode_ids))
    assert not e1 & e2 and e1 | e2 == set(range(6)) and len(e1) == 3
    assert first.size + second.size == ds.size
    for part in (first, second):  # whole episodes: each keeps all its transitions
        for e in set(np.asarray(part.episode_ids)):
            assert (part.episode_ids == e).sum() == (ds.episode_ids == e).sum()
    all_first, none = od.split_by_episode(ds, 1.0, jax.random.key(0))
    assert all_first.size == ds.size and none.size == 0
    with pytest.raises(ValueError, match=r"fraction must lie in \[0, 1\]"):
        od.split_by_episode(ds, 1.5, jax.random.key(0))

    toy = _toy(metadata={"env": "a"})
    both = od.concatenate(toy, od.filter_episodes(toy, np.array([False, True, True])))
    np.testing.assert_array_equal(both.episode_ids, [0, 0, 0, 1, 1, 2, 2, 2, 3, 3, 4, 4, 4])
    assert both.metadata["concatenated"] == [{"env": "a"}, {"env": "a"}]
    assert od.episode_statistics(both)[1]["num_episodes"] == 5
    with pytest.raises(ValueError, match=r"datasets\[1\]\.observations has shape"):
        od.concatenate(toy, ds)

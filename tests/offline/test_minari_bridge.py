"""Minari export/import of our offline datasets (offline/data/minari.py) and
``scripts/train_offline.py --dataset minari:...`` (offline/experiment/single.py).

One small real dataset (4 noisy-expert episodes of 30 steps on 3-link env3, collected in-graph
once per module) is exported and imported; a Minari dataset written with Minari's own API
(episodes of different lengths) is imported; BC trains on the exported dataset through the
script at the smallest size.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import minari
import numpy as np
import pytest
from minari.data_collector import EpisodeBuffer

import mjxrmp  # noqa: F401  (XLA flags first)
from offline.data import behaviours
from offline.data import collect as oc
from offline.data import dataset as odata
from offline.data import minari as om
from offline.experiment import single

ROOT = Path(__file__).resolve().parents[2]
ENV = "three_link/env3"
DATASET_ID = "mjxrmp/env3-noisy-v0"


@pytest.fixture(scope="module")
def small() -> odata.Dataset:
    """4 noisy-expert episodes of 30 steps on ``ENV``, with reference returns in the metadata."""
    ds = oc.collect(ENV, behaviours.noisy_expert(0.5), 4, seed=3, horizon=30, batch_size=4)
    return ds.replace(metadata=ds.metadata.updated(
        reference={"expert_return": 10.0, "random_return": -2.0}))


@pytest.fixture(scope="module")
def exported(small, tmp_path_factory) -> Path:
    """``small`` exported as :data:`DATASET_ID` under a fresh root; returns the root."""
    root = tmp_path_factory.mktemp("minari_root")
    assert om.export_minari(small, DATASET_ID, root) == root / DATASET_ID
    return root


def _assert_identical(a: odata.Dataset, b: odata.Dataset) -> None:
    for field in odata.FIELDS:
        x, y = np.asarray(getattr(a, field)), np.asarray(getattr(b, field))
        assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), field
    assert a.metadata == b.metadata


def test_round_trip_is_exact(small, exported):
    """Export → import reproduces every array bit for bit (dtypes included) and the metadata;
    Minari itself sees one episode per ours, Box spaces (actions bounded by the action limit),
    the reference scores and our metadata as JSON text; nothing else is left in the root."""
    _assert_identical(small, om.import_minari(DATASET_ID, root=exported))
    _assert_identical(small, om.import_minari(exported / DATASET_ID))  # by folder
    mds = minari.MinariDataset(exported / DATASET_ID / "data")
    assert mds.total_episodes == len(np.unique(small.episode_ids)) == 4
    assert mds.total_steps == small.size
    assert "infos=dict" in repr(mds[0])  # Minari's own episode view works on it
    limit = small.metadata["action_limit"]
    assert mds.action_space == gym.spaces.Box(-limit, limit, (small.action_size,), np.float32)
    meta = mds.storage.metadata
    assert (meta["ref_max_score"], meta["ref_min_score"]) == (10.0, -2.0)
    assert json.loads(meta[om.METADATA_KEY]) == small.metadata.to_dict()
    assert sorted(p.name for p in (exported / "mjxrmp").iterdir()) == ["env3-noisy-v0"]
    with pytest.raises(FileExistsError, match="dataset_id 'mjxrmp/env3-noisy-v0' already"):
        om.export_minari(small, DATASET_ID, exported)


def test_round_trip_of_unchained_episodes_and_sparse_ids(small, tmp_path):
    """Episodes are cut into several Minari episodes where observations do not chain (bitwise)
    and come back whole; sparse episode ids (as filtering leaves them) and an unflagged episode
    end survive."""
    obs, nxt = np.asarray(small.observations).copy(), np.asarray(small.next_observations).copy()
    ids = np.asarray(small.episode_ids)
    same = np.flatnonzero(ids[1:] == ids[:-1])  # t with t + 1 in the same episode
    nxt[same[0]] += 1.0  # no longer leads to the next transition
    nxt[same[-1], 0], obs[same[-1] + 1, 0] = 0.0, -0.0  # equal, but not bitwise: a cut too
    ends = np.asarray(small.timeouts).copy()
    ends[-1] = False  # the last episode ends without a flag
    odd = small.replace(observations=obs, next_observations=nxt, timeouts=ends,
                        episode_ids=(np.asarray(small.episode_ids) * 7 + 3).astype(np.int32))
    odata.validate(odd)
    path = om.export_minari(odd, "odd-v1", tmp_path)
    assert minari.MinariDataset(path / "data").total_episodes == 4 + 2
    _assert_identical(odd, om.import_minari("odd-v1", tmp_path))


def _buffer(rng, length, *, terminated=False, truncated=False, discrete=False) -> EpisodeBuffer:
    """One Minari episode of ``length`` steps (3-d observations, 2-d or discrete actions)."""
    end, last = np.zeros(length, bool), np.arange(length) == length - 1
    return EpisodeBuffer(
        observations=rng.normal(size=(length + 1, 3)).astype(np.float32),
        actions=(rng.integers(0, 4, length) if discrete
                 else rng.uniform(-1, 1, (length, 2)).astype(np.float32)),
        rewards=rng.normal(size=length), terminations=end | (terminated & last),
        truncations=end | (truncated & last))


def _minari_native(monkeypatch, tmp_path, dataset_id, buffers, action_space) -> None:
    """``buffers`` written with Minari's own ``create_dataset_from_buffers`` under ``tmp_path``."""
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    with pytest.warns(UserWarning):  # Minari's advice to give an author, email, description
        minari.create_dataset_from_buffers(
            dataset_id, buffers, observation_space=gym.spaces.Box(-np.inf, np.inf, (3,)),
            action_space=action_space, data_format="hdf5")


def test_import_of_a_dataset_made_by_minari(monkeypatch, tmp_path):
    """Episodes of 3, 5 and 1 steps (terminated; truncated; both, which is a terminal) become
    9 transitions with chained observations, ids 0, 1, 2 and a metadata naming the source."""
    rng = np.random.default_rng(0)
    buffers = [_buffer(rng, 3, terminated=True), _buffer(rng, 5, truncated=True),
               _buffer(rng, 1, terminated=True, truncated=True)]
    _minari_native(monkeypatch, tmp_path, "native/mixed-v0", buffers,
                   gym.spaces.Box(-1.0, 1.0, (2,)))
    ds = om.import_minari("native/mixed-v0")  # Minari's root, from $MINARI_DATASETS_PATH
    assert ds.size == 9 and ds.episode_ids.tolist() == [0] * 3 + [1] * 5 + [2]
    assert np.flatnonzero(ds.terminals).tolist() == [2, 8]
    assert np.flatnonzero(ds.timeouts).tolist() == [7]
    starts = [0, 3, 8]
    for k, (b, s) in enumerate(zip(buffers, starts, strict=True)):
        n = len(b.rewards)
        np.testing.assert_array_equal(ds.observations[s:s + n], b.observations[:-1], err_msg=k)
        np.testing.assert_array_equal(ds.next_observations[s:s + n], b.observations[1:])
        np.testing.assert_array_equal(ds.actions[s:s + n], b.actions)
        np.testing.assert_array_equal(ds.rewards[s:s + n], b.rewards)
    assert ds.metadata == {"source": "minari", "minari_dataset_id": "native/mixed-v0",
                           "action_limit": 1.0}


def test_non_box_spaces_and_missing_datasets_are_refused(monkeypatch, tmp_path, small):
    """A discrete action space is named in the error; missing or malformed ids name the
    argument; ``--dataset minari:`` of a missing dataset is refused by the command line checks."""
    rng = np.random.default_rng(1)
    _minari_native(monkeypatch, tmp_path, "native/discrete-v0",
                   [_buffer(rng, 2, terminated=True, discrete=True)], gym.spaces.Discrete(4))
    with pytest.raises(ValueError, match=r"action_space Discrete\(4\) is not a continuous Box"):
        om.import_minari("native/discrete-v0")
    with pytest.raises(FileNotFoundError, match="dataset_id_or_path 'nope-v0': no Minari"):
        om.import_minari("nope-v0", tmp_path)
    with pytest.raises(ValueError, match="dataset_id must look like"):
        om.export_minari(small, "no spaces allowed", tmp_path)
    parser = argparse.ArgumentParser()
    for option in single.OPTIONS:
        parser.add_argument(*option.flags, **option.spec)
    args = parser.parse_args(["--learner", "BC", "--dataset", "minari:nope-v0"])
    with pytest.raises(ValueError, match="--dataset: dataset_id_or_path 'nope-v0'"):
        single.check_args(args)


def test_bc_trains_from_a_minari_dataset_through_the_script(exported, tmp_path):
    """``scripts/train_offline.py --learner BC --dataset minari:<folder>`` at the smallest size:
    it trains, evaluates on the dataset's environment (reference returns on 8 episodes, not
    256) and writes ``result.json``."""
    out = tmp_path / "run"
    done = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "train_offline.py"), "--learner", "BC",
         "--dataset", f"minari:{exported / DATASET_ID}", "--steps", "10", "--chunk", "10",
         "--hidden", "8", "--batch", "8", "--seeds", "0", "--eval-episodes", "2",
         "--reference-episodes", "8", "--out", str(out), "--no-progress"],
        capture_output=True, text=True, cwd=ROOT, env={**os.environ})
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads((out / "result.json").read_text())
    assert result["learner"] == "BC" and result["env"] == ENV and result["steps"] == 10
    assert np.isfinite(result["normalized_score"]).all()
    assert result["reference"]["episodes"] == 8
    assert f"BC on {ENV}" in done.stdout

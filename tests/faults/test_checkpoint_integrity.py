"""Fault injection into orbax checkpoints (issue 27, case 1; agents/run/checkpoint.py, loading.py,
evaluation.py): a flipped, truncated or deleted file and garbled metadata are detected by the
integrity record and the newest intact checkpoint is restored with a one-line warning naming the
file; rotation keeps the newest finite checkpoint; restoring, evaluating and exporting NaN
parameters is refused; an incompatible checkpoint names only the differing field.

Every checkpoint holds a real :class:`agents.ppo.state.TrainState` of a tiny 3-link env1 ``nn``
run (``agents.run.program.build(...).init``), saved with :func:`agents.run.checkpoint.save`.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
from pathlib import Path

import jax
import numpy as np
import orbax.checkpoint as ocp
import pytest

import mjxrmp  # noqa: F401  (XLA flags first)
from agents.ppo import PPOConfig
from agents.run import checkpoint
from agents.run.checkpoint import (
    CorruptCheckpointError,
    IncompatibleCheckpointError,
    NonFiniteCheckpointError,
)
from agents.run.eval_report import evaluate_runs
from agents.run.evaluation import resolve_steps, run_sweep
from agents.run.export import export_run
from agents.run.loading import LoadedRun, load_run
from agents.run.program import build, seed_keys
from agents.run.spec import RunSpec

SPEC = RunSpec(env="three_link/env1", policy="nn", seeds=(0,),
               ppo=PPOConfig(num_envs=4, rollout_length=8, num_minibatches=2, update_epochs=1,
                             total_iterations=4, policy_hidden_sizes=(8,),
                             value_hidden_sizes=(8,), episode_length=10),
               log_every=1, checkpoint_every=1)


@pytest.fixture(scope="module")
def real():
    """``(program, state, template)`` of SPEC: a freshly initialised, finite TrainState."""
    program = build(SPEC)
    keys = seed_keys(SPEC.seeds)
    return program, program.init(keys), jax.eval_shape(program.init, keys)


def _at(state, step: int):
    """``state`` marked as iteration ``step`` (to tell restored checkpoints apart)."""
    return state._replace(iteration=state.iteration * 0 + step)


def _nan_policy(state):
    """``state`` with NaN policy parameters (a diverged run)."""
    policy = jax.tree.map(lambda x: x * np.nan, state.params["policy"])
    return state._replace(params={**state.params, "policy": policy})


def _meta(step: int) -> dict:
    return dict(SPEC.identity(), iteration=step, history={}, run=SPEC.to_json())


def _save(directory, state, steps, keep=None, nan_steps=()):
    for s in steps:
        st = _nan_policy(_at(state, s)) if s in nan_steps else _at(state, s)
        checkpoint.save(directory, s, st, _meta(s), max_to_keep=keep)


def _data_file(directory, step: int) -> Path:
    """The largest array-data file of a step (where the parameters' bytes are)."""
    files = (Path(directory) / str(step) / "state").rglob("*")
    return max((f for f in files if f.is_file()), key=lambda f: f.stat().st_size)


def _restored_step(directory, template) -> int:
    state, meta = checkpoint.restore(directory, template)
    assert int(state.iteration[0]) == meta["step"]
    return meta["step"]


def test_steps_are_listed_as_orbax_lists_them(real, tmp_path):
    """:func:`checkpoint.all_steps` (a directory listing, no orbax) gives the steps orbax's own
    manager counts as complete: not a step still being written under its temporary name, nor
    files or other directories."""
    _, state, _ = real
    _save(tmp_path, state, [1, 3, 10])
    shutil.copytree(tmp_path / "3", tmp_path / "12.orbax-checkpoint-tmp-1764460000000000")
    (tmp_path / "7").write_text("not a step")
    (tmp_path / "tb").mkdir()
    with ocp.CheckpointManager(str(tmp_path), options=ocp.CheckpointManagerOptions(
            create=False)) as mgr:
        assert checkpoint.all_steps(tmp_path) == sorted(mgr.all_steps()) == [1, 3, 10]
    assert checkpoint.all_steps(tmp_path / "missing") == []


def test_byte_flip_falls_back_to_previous_step(real, tmp_path, capsys):
    """issue case 1: 16 bytes flipped inside the newest checkpoint's data file → the previous
    checkpoint is restored (bitwise) with a one-line warning naming the file; asking for the
    flipped step explicitly raises naming it."""
    _, state, template = real
    _save(tmp_path, state, (1, 2))
    data = _data_file(tmp_path, 2)
    blob = bytearray(data.read_bytes())
    mid = len(blob) // 2
    blob[mid:mid + 16] = bytes(b ^ 0xFF for b in blob[mid:mid + 16])
    data.write_bytes(bytes(blob))
    restored, meta = checkpoint.restore(tmp_path, template)
    assert meta["step"] == 1
    for a, b in zip(jax.tree.leaves(restored), jax.tree.leaves(_at(state, 1)), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    rel = data.relative_to(tmp_path / "2").as_posix()
    warning = capsys.readouterr().err.strip()
    assert warning == (f"warning: skipping checkpoint {tmp_path / '2'}: file {rel} does not "
                       "match its SHA-256")
    with pytest.raises(CorruptCheckpointError, match=f"{rel} does not match") as err:
        checkpoint.restore(tmp_path, template, step=2)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("fault", ["truncated", "deleted manifest", "garbled meta",
                                   "garbled record", "missing record"])
def test_unreadable_newest_falls_back(real, tmp_path, capsys, fault):
    """issue case 1: a truncated data file, a deleted ``manifest.ocdbt``, garbled checkpoint
    metadata, a garbled or missing integrity record → one warning line naming the file, the
    previous checkpoint restored; ``load_meta`` and ``latest_intact_step`` agree."""
    _, state, template = real
    _save(tmp_path, state, (1, 2))
    step = tmp_path / "2"
    if fault == "truncated":
        data = _data_file(tmp_path, 2)
        data.write_bytes(data.read_bytes()[:7])
        reason = f"file {data.relative_to(step).as_posix()} has 7 bytes"
    elif fault == "deleted manifest":
        (step / "state" / "manifest.ocdbt").unlink()
        reason = "file state/manifest.ocdbt is missing"
    elif fault == "garbled meta":
        (step / "meta" / "metadata").write_text('{"env": "three_link/env1", garbled')
        reason = "file meta/metadata has"
    elif fault == "garbled record":
        (step / checkpoint.INTEGRITY_FILE).write_text("{not json")
        reason = "integrity.json is unreadable"
    else:
        (step / checkpoint.INTEGRITY_FILE).unlink()
        reason = "integrity.json is missing"
    assert _restored_step(tmp_path, template) == 1
    assert checkpoint.load_meta(tmp_path)["step"] == 1
    assert checkpoint.latest_intact_step(tmp_path) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 3 and all(line.startswith(f"warning: skipping checkpoint {step}: "
                                                   f"{reason}") for line in lines), lines


def test_all_corrupt_is_a_clear_error(real, tmp_path):
    """Every checkpoint corrupt → one error naming the directory (no orbax traceback)."""
    _, state, template = real
    _save(tmp_path, state, (1, 2))
    for s in (1, 2):
        (tmp_path / str(s) / "state" / "manifest.ocdbt").unlink()
    with pytest.raises(CorruptCheckpointError, match=re.escape(
            f"checkpoint {tmp_path} is corrupt: none of its 2 step(s) [1, 2] is intact")):
        checkpoint.restore(tmp_path, template)
    assert checkpoint.latest_intact_step(tmp_path) is None and checkpoint.intact_steps(
        tmp_path) == []


def test_legacy_checkpoint_is_accepted_and_orbax_errors_are_one_line(real, tmp_path, capsys):
    """A checkpoint written before integrity records (orbax only, as the old ``save`` did) is
    restored with a one-line warning; its deleted ``manifest.ocdbt`` then surfaces as one line
    naming the step, not tensorstore's traceback."""
    _, state, template = real
    leaves = jax.tree.leaves(_at(state, 3))
    meta = dict(_meta(3), format_version=checkpoint.FORMAT_VERSION, step=3,
                leaves=[[list(x.shape), str(x.dtype)] for x in leaves])
    flat = {f"leaf_{i:05d}": x for i, x in enumerate(leaves) if np.size(x) > 0}
    options = ocp.CheckpointManagerOptions(create=True)
    with ocp.CheckpointManager(str(tmp_path), options=options) as mgr:
        mgr.save(3, args=ocp.args.Composite(state=ocp.args.StandardSave(flat),
                                            meta=ocp.args.JsonSave(meta)))
        mgr.wait_until_finished()
    assert _restored_step(tmp_path, template) == 3
    assert capsys.readouterr().err.strip() == (f"warning: checkpoint {tmp_path / '3'} predates "
                                               "integrity records: used unverified")
    (tmp_path / "3" / "state" / "manifest.ocdbt").unlink()
    with pytest.raises(CorruptCheckpointError, match=r"/3 is corrupt: state unreadable") as err:
        checkpoint.restore(tmp_path, template, step=3)
    assert "\n" not in str(err.value) and len(str(err.value)) < 500


def test_corrupt_step_is_replaced_on_save(real, tmp_path, capsys):
    """A resumed run that fell back past a corrupt step writes that step again: the corrupt
    one is replaced (with a warning); an intact one is never overwritten."""
    _, state, template = real
    _save(tmp_path, state, (1, 2))
    (tmp_path / "2" / "state" / "manifest.ocdbt").unlink()
    _save(tmp_path, state, (2,))
    assert "replacing corrupt checkpoint" in capsys.readouterr().err
    assert _restored_step(tmp_path, template) == 2
    with pytest.raises(ValueError, match="step 2 already exists"):
        _save(tmp_path, state, (2,))


def test_rotation_keeps_the_newest_finite_checkpoint(real, tmp_path):
    """Rotation (keep 2) never deletes the newest verified finite checkpoint, even when newer
    ones are NaN; restoring the NaN newest is refused naming the leaf and the finite step."""
    _, state, template = real
    _save(tmp_path, state, (1, 2, 3, 4, 5), keep=2, nan_steps=(3, 4, 5))
    assert checkpoint.all_steps(tmp_path) == [2, 4, 5]
    with pytest.raises(NonFiniteCheckpointError,
                       match=r"/5 holds non-finite values in params\['policy'\].*newest finite "
                             r"checkpoint is step 2"):
        checkpoint.restore(tmp_path, template)
    assert checkpoint.restore(tmp_path, template, step=2)[1]["step"] == 2
    nan_state, _ = checkpoint.restore(tmp_path, template, step=5, allow_nonfinite=True)
    assert checkpoint.first_nonfinite(nan_state).startswith("params['policy']")
    _save(tmp_path, state, (6,), keep=2)  # a finite newest: plain rotation again
    assert checkpoint.all_steps(tmp_path) == [5, 6]


def test_incompatible_checkpoint_names_only_the_differing_field(real, tmp_path):
    """issue case 3: the refusal names ``ppo.learning_rate`` and its two values, no dicts."""
    _, state, template = real
    _save(tmp_path, state, (1,))
    other = dataclasses.replace(SPEC, ppo=dataclasses.replace(SPEC.ppo, learning_rate=1e-6))
    with pytest.raises(IncompatibleCheckpointError) as err:
        checkpoint.restore(tmp_path, template, expected=other.identity())
    assert str(err.value) == ("checkpoint does not match this run: ppo.learning_rate: "
                              "checkpoint has 0.0003, this run has 1e-06")


@pytest.fixture(scope="module")
def run_dirs(real, tmp_path_factory):
    """Run directories (``run.json`` + checkpoints): ``diverged`` has a finite step 1 and a
    NaN newest step 2; ``flipped`` has intact 1, 2 and a byte-flipped newest 3."""
    _, state, _ = real
    out = {}
    for name, steps, nan in (("diverged", (1, 2), (2,)), ("flipped", (1, 2, 3), ())):
        run = tmp_path_factory.mktemp(name)
        (run / "run.json").write_text(json.dumps(SPEC.to_json()))
        _save(run / "checkpoints", state, steps, nan_steps=nan)
        out[name] = run
    data = _data_file(out["flipped"] / "checkpoints", 3)
    data.write_bytes(data.read_bytes()[::-1])
    return out


def test_load_eval_export_refuse_nan_parameters(run_dirs, tmp_path):
    """issue case 1: ``scripts/eval.py`` reported a NaN checkpoint "100 % safe" and
    ``scripts/export.py`` exported it. Loading, evaluating and exporting the NaN newest
    checkpoint now raise naming the leaf; the finite step still loads; a NaN ``LoadedRun`` is
    refused by the sweep itself."""
    run = str(run_dirs["diverged"])
    nan = r"non-finite values in params\['policy'\]"
    with pytest.raises(NonFiniteCheckpointError, match=nan + ".*step 1"):
        load_run(run)
    with pytest.raises(NonFiniteCheckpointError, match=nan):
        evaluate_runs([run], num_episodes=1, horizon=2)
    out = tmp_path / "p.jaxexport"
    with pytest.raises(NonFiniteCheckpointError, match=nan):
        export_run(out, run, platforms=("cpu",))
    assert not out.exists() and not out.with_suffix(".json").exists()
    good = load_run(run, step=1)
    assert good.step == 1
    diverged = LoadedRun(good.run_dir, good.spec, good.program, _nan_policy(good.state),
                         good.meta, 2)
    with pytest.raises(NonFiniteCheckpointError,
                       match=r"checkpoint 2 of .*non-finite values in params\['params'\]"):
        run_sweep([diverged], num_episodes=1, horizon=2)


def test_eval_and_load_skip_a_corrupt_newest(run_dirs, capsys):
    """``--steps latest``/``all`` and ``load_run()`` skip the flipped newest checkpoint with a
    warning naming it; naming it explicitly is an error."""
    run = str(run_dirs["flipped"])
    assert resolve_steps(run, ["latest"]) == [2]
    assert resolve_steps(run, ["all"]) == [1, 2]
    assert load_run(run).step == 2
    err = capsys.readouterr().err
    assert err.count(f"skipping checkpoint {run_dirs['flipped'] / 'checkpoints' / '3'}") == 3
    with pytest.raises(CorruptCheckpointError, match="/3 is corrupt: file state/"):
        load_run(run, step=3)
    copy = run_dirs["flipped"].parent / "flipped_copy"
    shutil.copytree(run, copy)
    for s in (1, 2):
        os.remove(copy / "checkpoints" / str(s) / "state" / "manifest.ocdbt")
    with pytest.raises(CorruptCheckpointError, match="none of its checkpoints is intact"):
        resolve_steps(str(copy), ["latest"])

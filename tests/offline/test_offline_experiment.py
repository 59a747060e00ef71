"""offline.experiment.run and offline.learners.registry: which learner reads which data per PLfO
scenario, the shortened ATAC schedule, chunked training; and the offline scripts' table rule and
bad-input handling (offline.experiment.ch7, ch7_table, single; the scripts as subprocesses)."""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import jax
import numpy as np
import pytest
from script_main import load_script

from offline.data import dataset as odata
from offline.data import scenarios
from offline.data.scenarios import same_dynamics
from offline.experiment import ch7, ch7_table, single
from offline.experiment import run as experiment
from offline.experiment.settings import Option, control_rate_kwargs
from offline.learners import plfo_baselines, registry
from offline.survival import ch8

ROOT = Path(__file__).resolve().parents[2]


def parse(options: Sequence[Option], check: Callable, argv: list[str]) -> argparse.Namespace:
    """The arguments a script whose parser is built from ``options`` (and ``--out``) and
    checked by ``check`` parses from ``argv``; a refused argument exits as the script does."""
    p = argparse.ArgumentParser()
    for option in options:
        p.add_argument(*option.flags, **option.spec)
    if not any(o.flags == ("--out",) for o in options):
        p.add_argument("--out", type=Path)
    args = p.parse_args(argv)
    try:
        return check(args)
    except ValueError as e:
        p.error(str(e))


def ch7_args(argv: list[str]) -> argparse.Namespace:
    """What ``scripts/reproduce_ch7.py`` parses from ``argv``."""
    return parse(ch7.OPTIONS, ch7.check_args, argv)

META = {"env": "three_link/env3", "action_limit": 1.0, "reward_range": [-1.0, 1.0]}


def _episodes(rng: np.random.Generator, n_episodes: int, length: int, reward: float,
              first_id: int = 0) -> odata.Dataset:
    n = n_episodes * length
    obs = rng.normal(size=(n, 3)).astype(np.float32)
    ids = np.repeat(np.arange(first_id, first_id + n_episodes), length)
    timeouts = np.tile(np.arange(length) == length - 1, n_episodes)
    return odata.create(obs, rng.uniform(-1, 1, (n, 2)).astype(np.float32),
                        np.full(n, reward, np.float32), obs + 0.1, np.zeros(n, bool), timeouts,
                        ids, META)


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(0)
    return _episodes(rng, 6, 5, -0.5), _episodes(rng, 2, 5, 0.7)


def test_applicability_matrix():
    for scenario in scenarios.SCENARIOS:
        for learner in registry.TABLE_LEARNERS:
            expected = not (learner in ("UDS", "ATAC") and scenario in ("ILfO", "RLfO"))
            assert experiment.applicable(learner, scenario) == expected, (learner, scenario)
    assert experiment.applicable("IQL", None) and not experiment.applicable("MAHALO", None)
    with pytest.raises(ValueError, match="valid names"):
        experiment.applicable("GAIL", "IL")
    with pytest.raises(ValueError, match="valid scenarios"):
        experiment.applicable("BC", "IRL")


def test_shortened_atac_schedule_keeps_the_published_rates_or_the_actor_budget():
    for steps in (10_000, 200_000, 1_000_000):
        cfg = registry.atac_config(registry.Budget(steps=steps))
        assert cfg.num_steps == steps and cfg.warmstart_steps == steps // 10
        assert cfg.actor_lr == 5e-7 and cfg.critic_lr == 5e-4 and cfg.batch_size == 256
        scaled = registry.atac_config(registry.Budget(steps=steps, actor_rate="scaled"))
        assert scaled.actor_lr * steps == pytest.approx(5e-7 * 1_000_000)
        assert scaled.warmstart_steps == steps // 10 and scaled.critic_lr == 5e-4
        longer = registry.atac_config(registry.Budget(steps=steps, warmstart=0.75))
        assert longer.warmstart_steps == steps * 3 // 4 and longer.actor_lr == 5e-7
    assert registry.atac_config(registry.Budget(steps=15)).warmstart_steps == 1
    assert registry.atac_config(registry.Budget(steps=70)).warmstart_steps == 7
    for bad in (1.0, -0.1, "half"):
        with pytest.raises(ValueError, match=r"Budget\.warmstart must"):
            registry.Budget(steps=100, warmstart=bad)
    with pytest.raises(ValueError, match="steps"):
        registry.Budget(steps=3)


@pytest.mark.parametrize("scenario", ["IL", "RL-expert", "RL-sample"])
def test_labelled_transitions_are_the_shared_ones_with_reward_data_rewards(data, scenario):
    mixed, expert = data
    dyn, rd = scenarios.make(scenario, mixed, expert, key=jax.random.PRNGKey(3))
    out = registry.labelled_transitions(dyn, rd)
    assert out.size == rd.size
    np.testing.assert_array_equal(out.observations, rd.observations)
    np.testing.assert_array_equal(out.next_observations, rd.next_observations)
    np.testing.assert_array_equal(out.rewards, rd.rewards)
    # the actions are the dynamics data's own for those transitions
    rows = {o.tobytes(): a for o, a in zip(np.asarray(dyn.observations),
                                          np.asarray(dyn.actions), strict=True)}
    expected = np.stack([rows[o.tobytes()] for o in np.asarray(out.observations)])
    np.testing.assert_array_equal(out.actions, expected)
    if scenario == "IL":  # expert-only reward data is labelled with the maximum reward
        assert np.all(np.asarray(out.rewards) == 1.0)


def test_build_refuses_learners_without_data(data):
    mixed, expert = data
    dyn, rd = scenarios.make("ILfO", mixed, expert)
    budget = registry.Budget(steps=20, hidden=(8,), batch=4)
    for learner in ("UDS", "ATAC"):
        with pytest.raises(ValueError, match="no data to train on"):
            experiment.build(learner, dyn, rd, budget, "ILfO")
    with pytest.raises(ValueError, match="exactly when a scenario"):
        experiment.build("BC", dyn, None, budget, "ILfO")


def test_chunked_training_equals_one_call_and_reports_every_chunk(data):
    mixed, expert = data
    dyn, rd = scenarios.make("IL", mixed, expert)
    trainer = experiment.build("BC", dyn, rd, registry.Budget(steps=20, hidden=(8,), batch=4),
                               "IL")
    keys = experiment.seed_keys([0, 1])
    seen = []
    state, hist = experiment.train_chunked(trainer, keys, 10,
                                           lambda s, m, done: seen.append(done))
    assert seen == [10, 20]
    assert all(v.shape == (2, 2) for v in hist.values())
    ref, _ = jax.jit(jax.vmap(trainer.train))(keys)
    for a, b in zip(jax.tree.leaves(state.params), jax.tree.leaves(ref.params), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)


def test_beta_grid_in_one_program_equals_runs_at_each_beta(data):
    """Seeds × β vmapped in one program: every run equals ATAC built at that β and trained
    alone with that seed; the β really changes the run."""
    mixed, _ = data
    budget = registry.Budget(steps=10, hidden=(8, 8), batch=8, actor_rate="scaled")
    run_seeds, run_betas = experiment.seed_beta_runs([0, 1], [0.5, 4.0])
    assert run_seeds == [0, 0, 1, 1] and run_betas == [0.5, 4.0, 0.5, 4.0]
    assert experiment.seed_beta_runs([3], None) == ([3], None)
    trainer = experiment.build("Oracle", mixed, None, budget)
    keys = experiment.seed_keys(run_seeds)
    state, _ = experiment.train_chunked(trainer, keys, 5,
                                        state=experiment.init_runs(trainer, keys, run_betas))
    np.testing.assert_allclose(state.beta, run_betas)
    alone = plfo_baselines.make_train_oracle(mixed, registry.atac_config(budget, beta=4.0))
    final, _ = jax.jit(alone.train)(jax.random.PRNGKey(1))
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a[3], b, rtol=1e-5, atol=1e-6),
                 state.params["critic"], final.params["critic"])
    critic = np.asarray(jax.tree.leaves(state.params["critic"])[-1])
    assert not np.allclose(critic[2], critic[3])  # same seed, other β
    with pytest.raises(ValueError, match="betas has 3 entries for 4 runs"):
        experiment.init_runs(trainer, keys, [1.0, 2.0, 3.0])


def _ch7_row(args, env: str, scenario: str, learner: str, scores: list) -> dict:
    """A results row of ``reproduce_ch7`` with the cell key ``args`` gives it."""
    return {"cell": ch7.cell_key(env, scenario, learner, args), "env": env,
            "scenario": scenario, "learner": learner, "normalized_score": scores,
            "safe_pct": [100] * len(scores)}


def test_ch7_table_bolds_entries_within_90_percent_of_the_best_non_oracle(tmp_path):
    scores = {"MAHALO": [85, 91], "BC": [50, 52], "BCO": [95, 95], "Oracle": [200, 200]}
    args = ch7_args(["--stage", "table", "--out", str(tmp_path), "--envs", "e"])
    more_seeds = ch7_args(["--out", str(tmp_path), "--envs", "e", "--seeds", "10"])
    with open(tmp_path / "results.jsonl", "w") as f:
        for learner, s in scores.items():
            f.write(json.dumps(_ch7_row(args, "e", "ILfO", learner, s)) + "\n")
        # A 10-seed run of the same learner is another cell: it does not replace the 5-seed one.
        f.write(json.dumps(_ch7_row(more_seeds, "e", "ILfO", "MAHALO", [0] * 10)) + "\n")
    summary = ch7_table.table_stage(args)
    table = (tmp_path / "table.md").read_text()
    assert "**88.0 ± 3.0**" in table and "**95.0 ± 0.0**" in table  # 88 >= 0.9 · 95
    assert "51.0 ± 1.0 |" in table and "**51.0" not in table
    assert "**200.0" not in table  # Oracle is never bold and not the reference
    assert summary == {"cells": 1, "mahalo_within_90": 1,
                       "mahalo_beats_bc_bco_ilfo": {"e": False}}
    # Above BC with BCO not run: the ILfO comparison is undecided, not passed.
    lines = (tmp_path / "results.jsonl").read_text().splitlines()
    (tmp_path / "results.jsonl").write_text("\n".join(
        line for line in lines if '"BCO"' not in line) + "\n")
    assert ch7_table.table_stage(args)["mahalo_beats_bc_bco_ilfo"] == {"e": None}


def test_ch7_and_ch8_keep_standardised_observation_runs_apart(tmp_path):
    """``--normalize-observations`` gives cells their own key (old results stay valid), and
    the ch7 table only reads rows of its own setting (refusing when there are none)."""
    base = ["--out", str(tmp_path), "--actor-rate", "scaled"]  # the settings of old results
    off, on = (ch7_args([*base, "--envs", "e", *extra])
               for extra in ([], ["--normalize-observations"]))
    assert ch7.cell_key("e", "IL", "BC", off) != ch7.cell_key(
        "e", "IL", "BC", on)
    assert json.loads(ch7.cell_key("e", "IL", "BC", on))[:-1] == json.loads(
        ch7.cell_key("e", "IL", "BC", off))
    off8, on8 = (parse(ch8.OPTIONS, ch8.check_args, base + extra)
                 for extra in ([], ["--normalize-observations"]))
    assert ch8.cell_key("mixed-cut", "ATAC", "zero", off8) != ch8.cell_key(
        "mixed-cut", "ATAC", "zero", on8)
    with open(tmp_path / "results.jsonl", "w") as f:
        f.write(json.dumps(_ch7_row(off, "e", "ILfO", "BC", [1, 2])) + "\n")
    assert ch7_table.table_stage(off)["cells"] == 1
    with pytest.raises(SystemExit, match="normalize_observations=True"):
        ch7_table.table_stage(on)


def test_ch7_control_rate_gets_its_own_data_cells_and_table(tmp_path):
    """``--substeps N``: data files, cell keys and the table of another control rate are kept
    apart from the default ones (shared helper
    :func:`offline.experiment.settings.control_rate_kwargs`, which also refuses a rate that does
    not divide the episode)."""
    base = ["--out", str(tmp_path), "--envs", "three_link/env3",
            "--actor-rate", "scaled"]  # the settings of rows without setting fields
    plain, rate = (ch7_args(base + extra) for extra in ([], ["--substeps", "24"]))
    assert control_rate_kwargs("three_link/env3", 24) == {"substeps": 24, "horizon": 75}
    assert control_rate_kwargs("three_link/env3", None) is None
    with pytest.raises(ValueError, match="substeps"):
        control_rate_kwargs("three_link/env3", 7)
    with pytest.raises(SystemExit):
        ch7_args([*base, "--substeps", "7"])
    assert ch7.data_path(tmp_path, "three_link/env3", "mixed", 2, 0, 24).name == (
        "three_link-env3_mixed_x2_s0_substeps_24.npz")
    assert ch7.data_path(tmp_path, "three_link/env3", "mixed", 2, 0).name == (
        "three_link-env3_mixed_x2_s0.npz")
    cells = [ch7.cell_key("three_link/env3", "ILfO", "BC", a) for a in (plain, rate)]
    assert cells[0] != cells[1] and json.loads(cells[1])[-2:] == ["substeps", 24]
    with open(tmp_path / "results.jsonl", "w") as f:
        f.write(json.dumps(_ch7_row(plain, "three_link/env3", "ILfO", "BC", [1, 2])) + "\n")
    assert ch7_table.table_stage(plain)["cells"] == 1
    with pytest.raises(SystemExit, match="substeps=24"):
        ch7_table.table_stage(rate)


def test_ch7_expert_set_size_gets_its_own_data_cells_and_table(tmp_path):
    """``--expert-scale N``: the expert dataset has N episodes (its own cached file), cells get
    their own key (equal to ``--scale`` is the default and keeps the keys) except in RL-sample,
    which does not read the expert set; the table reads only rows of that size (and RL-sample
    rows), and N < 1 is refused."""
    base = ["--out", str(tmp_path), "--envs", "e", "--scale", "4"]
    plain, same, small = (ch7_args(base + extra) for extra in
                          ([], ["--expert-scale", "4"], ["--expert-scale", "1"]))
    assert same.expert_scale is None
    assert ch7.cell_key("e", "ILfO", "BCO", same) == ch7.cell_key(
        "e", "ILfO", "BCO", plain) != ch7.cell_key("e", "ILfO", "BCO", small)
    assert ch7.cell_key("e", "RL-sample", "BCO", small) == ch7.cell_key(
        "e", "RL-sample", "BCO", plain)  # RL-sample does not read the expert set
    assert [ch7.recipe_scale(small, r) for r in ("mixed", "expert")] == [4, 1]
    assert [ch7.recipe_scale(plain, r) for r in ("mixed", "expert")] == [4, 4]
    with open(tmp_path / "results.jsonl", "w") as f:
        for sc, a, score in (("ILfO", plain, [1, 2]), ("ILfO", small, [5, 7]),
                             ("RL-sample", plain, [3, 3])):
            f.write(json.dumps(_ch7_row(a, "e", sc, "BC", score)) + "\n")
    assert ch7_table.table_stage(small)["cells"] == 2  # ILfO and the shared RL-sample row
    assert "6.0 ± 1.0" in (tmp_path / "table.md").read_text()
    ch7_table.table_stage(plain)
    assert "1.5 ± 0.5" in (tmp_path / "table.md").read_text()
    other = ch7_args([*base, "--expert-scale", "3"])
    assert ch7_table.table_stage(other)["cells"] == 1  # the RL-sample row only
    (tmp_path / "results.jsonl").write_text("\n".join(
        x for x in (tmp_path / "results.jsonl").read_text().splitlines() if "RL-sample" not in x))
    with pytest.raises(SystemExit, match="expert_scale=3"):
        ch7_table.table_stage(other)
    with pytest.raises(SystemExit):
        ch7_args([*base, "--expert-scale", "0"])
    with pytest.raises(SystemExit):
        ch7_args([*base, "--reference-episodes", "0"])


@pytest.fixture(scope="module")
def ch7_data(tmp_path_factory) -> Path:
    """``reproduce_ch7.py --scale 1 --stage collect``'s ``data/`` (the mixed and expert sets of
    three_link/env3), collected once for the module's train-stage runs."""
    out = tmp_path_factory.mktemp("ch7_data")
    ch7_table.run(ch7_args(["--out", str(out), "--scale", "1", "--stage", "collect"]))
    return out / "data"


def test_ch7_learning_curves_end_at_the_final_scores(tmp_path, ch7_data):
    """``reproduce_ch7.py --curve``: one evaluation per chunk in the row, the last equal to the
    row's final evaluation (same parameters, same episodes); reference returns on 8 episodes
    (``--reference-episodes``; 256 by default)."""
    shutil.copytree(ch7_data, tmp_path / "data")
    ch7_table.run(ch7_args(["--out", str(tmp_path), "--scale", "1", "--steps", "40", "--chunk",
                            "20", "--hidden", "16", "16", "--seeds", "2", "--eval-episodes",
                            "2", "--reference-episodes", "8", "--scenarios", "ILfO",
                            "--learners", "BC", "--curve"]))
    (row,) = [json.loads(x) for x in (tmp_path / "results.jsonl").read_text().splitlines()]
    assert row["curve"]["steps"] == [20, 40] and row["reference"]["episodes"] == 8
    assert np.asarray(row["curve"]["normalized_score"]).shape == (2, 2)  # steps × seeds
    for k in ("normalized_score", "safe_pct", "success_pct"):
        assert row["curve"][k][-1] == row[k], k
    assert row["eval_s"] > 0 and row["train_s"] > 0


def test_ch7_oracle_is_trained_once_per_dynamics_dataset(tmp_path, ch7_data):
    """The Oracle reads only the dynamics data: ILfO, RLfO and RL-sample share ``D_X``, so one
    run gives all three rows (the later two copies marked ``shared_from``); IL and RL-expert
    share ``D_X ∪ D_E``."""
    assert same_dynamics("RLfO") == ("ILfO", "RLfO", "RL-sample")
    assert same_dynamics("IL") == same_dynamics("RL-expert") == ("IL", "RL-expert")
    budget = ["--scale", "1", "--steps", "20", "--chunk", "20", "--hidden", "16", "16",
              "--seeds", "2", "--eval-episodes", "2", "--reference-episodes", "8", "--learners",
              "Oracle"]
    argv = ["--out", str(tmp_path), *budget, "--scenarios", "ILfO", "RLfO", "RL-sample"]
    shutil.copytree(ch7_data, tmp_path / "data")
    ch7_table.run(ch7_args(argv))
    rows = [json.loads(x) for x in (tmp_path / "results.jsonl").read_text().splitlines()]
    assert [r["scenario"] for r in rows] == ["ILfO", "RLfO", "RL-sample"]
    first, *shared = rows
    assert "shared_from" not in first and first["train_s"] > 0
    args = ch7_args(argv)
    for r in shared:
        assert r["shared_from"] == first["cell"] and r["train_s"] == 0
        assert r["cell"] == ch7.cell_key(r["env"], r["scenario"], "Oracle", args)
        assert r["normalized_score"] == first["normalized_score"]
    assert rows[1]["reward_transitions"] != rows[2]["reward_transitions"]  # expert vs sample
    ch7_table.run(ch7_args([*argv, "--stage", "train"]))  # resumable: nothing new
    assert len((tmp_path / "results.jsonl").read_text().splitlines()) == 3
    # The claim behind the copy: RL-sample's Oracle trained on its own scores the same as ILfO's.
    alone = tmp_path / "alone"
    shutil.copytree(ch7_data, alone / "data")
    ch7_table.run(ch7_args(["--out", str(alone), *budget, "--scenarios", "RL-sample",
                            "--stage", "train"]))
    (own,) = [json.loads(x) for x in (alone / "results.jsonl").read_text().splitlines()]
    assert "shared_from" not in own and own["normalized_score"] == first["normalized_score"]


def test_train_offline_refuses_bad_arguments(tmp_path, capsys):
    for argv, msg in ((["--learner", "GAIL"], "invalid choice"),
                      (["--learner", "BC", "--dataset", str(tmp_path / "nope.npz")],
                       "does not exist"),
                      (["--learner", "BC", "--steps", "0"], "positive integer"),
                      (["--learner", "BC", "--reference-episodes", "0"],
                       "--reference-episodes must be a positive integer"),
                      (["--learner", "BC", "--expert", str(tmp_path)], "only used with"),
                      (["--learner", "BC", "--betas", "1"], "Bellman weight"),
                      (["--learner", "ATAC", "--betas", "1", "-2"], "finite numbers >= 0")):
        with pytest.raises(SystemExit):
            parse(single.OPTIONS, single.check_args, argv)
        assert msg in capsys.readouterr().err


def test_scripts_refuse_bad_arguments_on_the_command_line(tmp_path, capsys):
    """The offline scripts exit with status 2 and the package's message when their arguments
    are refused (before any data is collected): ``collect.py`` run as a program, the others'
    ``main`` in this process (the same parsing and exit, no new interpreter)."""
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "collect.py"), "--recipe",
                           "nope", "--out", str(tmp_path / "x.npz")],
                          capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 2 and "valid recipes are" in done.stderr, done.stderr[-500:]
    for script, argv, msg in (
            ("reproduce_ch7.py", ["--expert-scale", "0"], "--expert-scale must be >= 1"),
            ("reproduce_ch8.py", ["--goal-deadline", "0"], "--goal-deadline must be a positive"),
            ("train_offline.py", ["--learner", "BC", "--steps", "0"], "positive integer")):
        with pytest.raises(SystemExit) as exit_:
            load_script(script).main([*argv, *(["--out", str(tmp_path)]
                                               if script.startswith("repro") else [])])
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and msg in err, (script, err[-500:])

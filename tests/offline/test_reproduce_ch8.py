"""Chapter 8 (offline/survival/sweep.py, ch8*.py; scripts/reproduce_ch8.py): rewards × seeds
vmapped in one program equal separate runs; the figures stage computes its acceptance checks from
the results (hand-made results with known answers); the full CPU smoke end to end (slow)."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from agents.run import checkpoint
from offline.data import dataset as odata
from offline.experiment import programs
from offline.experiment import run as experiment
from offline.learners import registry
from offline.survival import ch8, ch8_analysis, ch8_report, sweep
from offline.survival import rewards as survival

ROOT = Path(__file__).resolve().parents[2]

WRONG = ("zero", "random", "negated")


def parse_args(argv: list[str]) -> argparse.Namespace:
    """The arguments ``scripts/reproduce_ch8.py`` parses from ``argv`` (its parser is built from
    :data:`offline.survival.ch8.OPTIONS` and checked by :func:`offline.survival.ch8.check_args`;
    a refused argument exits as the script does)."""
    p = argparse.ArgumentParser()
    for option in ch8.OPTIONS:
        p.add_argument(*option.flags, **option.spec)
    p.add_argument("--out", type=Path)
    args = p.parse_args(argv)
    try:
        return ch8.check_args(args)
    except ValueError as e:
        p.error(str(e))


def _synthetic(n: int = 120, obs_size: int = 6, seed: int = 0) -> odata.Dataset:
    rng = np.random.default_rng(seed)
    obs = rng.normal(size=(n, obs_size)).astype(np.float32)
    return odata.create(obs, rng.uniform(-1, 1, (n, 3)).astype(np.float32),
                        rng.normal(size=n).astype(np.float32), obs + 0.1,
                        np.arange(n) % 10 == 9, np.zeros(n, bool),
                        (np.arange(n) // 10).astype(np.int32), metadata={"action_limit": 1.0})


def test_reward_rows_are_the_survival_variants():
    ds = _synthetic()
    key = sweep.reward_key(0, "x")
    base, rows = sweep.reward_rows(ds, ["original", "random", "negated"], "remove", key)
    np.testing.assert_array_equal(rows[0], ds.rewards)
    np.testing.assert_array_equal(rows[1], survival.variant(ds, "random", "remove", key).rewards)
    np.testing.assert_array_equal(rows[2], -np.asarray(ds.rewards))
    assert not np.asarray(base.terminals).any()  # terminals removed in the base dataset
    r, k = sweep.reward_seed_keys(rows[:2], [3, 4])
    np.testing.assert_array_equal(r, rows[[0, 0, 1, 1]])
    np.testing.assert_array_equal(k, experiment.seed_keys([3, 4, 3, 4]))
    with pytest.raises(ValueError, match="learner"):
        sweep.reward_batched("BC", ds, registry.Budget(steps=10))


@pytest.mark.parametrize("learner", ["ATAC", "IQL", "CQL"])
def test_reward_batched_equals_separate_runs(learner):
    """2 rewards × 2 seeds in one program; run (random reward, seed 1) equals the learner
    built on the relabelled dataset and trained alone (concrete rewards, float32)."""
    ds = _synthetic()
    # the scaled actor rate (×1e5 at 10 steps) so that ATAC's actor moves enough to tell runs apart
    budget = registry.Budget(steps=10, hidden=(8, 8), batch=16, actor_rate="scaled")
    base, rows = sweep.reward_rows(ds, ["original", "random"], "keep", sweep.reward_key(0, "x"))
    trainer = sweep.reward_batched(learner, base, budget)
    state, _ = experiment.train_chunked(trainer, sweep.reward_seed_keys(rows, [0, 1]), 5)
    batched = jax.tree.map(lambda x: x[3], sweep.run_actor_params(state))
    alone = sweep.build_plain(learner, base.replace(rewards=rows[1]), budget)
    final, _ = jax.jit(alone.train)(jax.random.PRNGKey(1))
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6),
                 batched, final.params["actor"])
    # and the runs differ from each other (the reward and the seed both matter)
    p = sweep.run_actor_params(state)
    leaf = np.asarray(jax.tree.leaves(p)[-1])
    assert not np.allclose(leaf[1], leaf[3]) and not np.allclose(leaf[2], leaf[3])


def test_reward_batched_runs_take_a_beta():
    """``--beta``: every run of a rewards × seeds program starts at the given Bellman weight
    (``experiment.init_runs`` counts the runs of ``(rewards, keys)``); a wrong count is
    refused."""
    ds = _synthetic()
    budget = registry.Budget(steps=10, hidden=(8, 8), batch=16)
    base, rows = sweep.reward_rows(ds, ["zero", "random"], "keep", sweep.reward_key(0, "x"))
    keys = sweep.reward_seed_keys(rows, [0, 1])
    trainer = sweep.reward_batched("PSPI", base, budget)
    state = experiment.init_runs(trainer, keys, [2.0] * 4)
    np.testing.assert_array_equal(state.inner.beta, np.full(4, 2.0, np.float32))
    assert not np.allclose(experiment.init_runs(trainer, keys, None).inner.beta, 2.0)
    with pytest.raises(ValueError, match="4 runs"):
        experiment.init_runs(trainer, keys, [2.0] * 3)


def test_interrupted_program_resumes_from_its_checkpoint(tmp_path):
    """A rewards × seeds program stopped after its first chunk continues from the checkpoint
    to the same final state, bit for bit, as an uninterrupted run; the checkpoint of another
    program is refused."""
    ds = _synthetic()
    budget = registry.Budget(steps=10, hidden=(8, 8), batch=16, actor_rate="scaled")
    base, rows = sweep.reward_rows(ds, ["original", "random"], "keep", sweep.reward_key(0, "x"))
    trainer = sweep.reward_batched("ATAC", base, budget)
    keys = sweep.reward_seed_keys(rows, [0, 1])
    straight = programs.train_program(trainer, keys, 5)
    ckpt = programs.program_checkpoint_dir(tmp_path, "cell A")
    assert ckpt.parent == tmp_path and programs.program_checkpoint_dir(None, "cell A") is None

    class Stop(Exception):
        pass

    def stop(state, means, done):
        raise Stop

    with pytest.raises(Stop):
        programs.train_program(trainer, keys, 5, stop, ckpt, {"program": "cell A"})
    assert checkpoint.latest_step(ckpt) == 5
    seen = []
    resumed = programs.train_program(trainer, keys, 5, lambda s, m, d: seen.append(d), ckpt,
                                  {"program": "cell A"})
    assert seen == [10]   # only the second chunk ran
    for a, b in zip(jax.tree.leaves(resumed), jax.tree.leaves(straight), strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(checkpoint.IncompatibleCheckpointError, match="program"):
        programs.train_program(trainer, keys, 5, None, ckpt, {"program": "cell B"})


# --------------------------------------------------------------------------------------------
# Figures stage on hand-made results

SCORES = {  # (dataset, learner) -> mean score per reward (original, zero, random, negated)
    ("mixed-cut", "ATAC"): (90, 80, 70, 60),
    ("mixed-cut", "PSPI"): (85, 100, 101, 100),
    ("mixed-full", "ATAC"): (90, 20, 25, 15),
    ("mixed-full", "PSPI"): (80, 30, 20, 10),
    ("mixed-cut", "IQL"): (50, 40, 40, 40),
}
BC = {"mixed-cut": 40.0, "mixed-full": 20.0, "mixed-full-filtered": 30.0}
SAFE = {("mixed-full", "BC"): 80.0, ("mixed-full", "ATAC"): 70.0, ("mixed-full", "PSPI"): 75.0,
        ("mixed-full-filtered", "ATAC"): 95.0, ("mixed-full-filtered", "PSPI"): 78.0}


def _handmade_dataset(lengths, returns_per_step) -> odata.Dataset:
    obs, rew, ids, term, tout = [], [], [], [], []
    for e, (n, r) in enumerate(zip(lengths, returns_per_step, strict=True)):
        obs.append(np.zeros((n, 26), np.float32))
        rew.append(np.full(n, r, np.float32))
        ids.append(np.full(n, e, np.int32))
        end = np.zeros(n, bool)
        end[-1] = True
        term.append(end if n < max(lengths) else np.zeros(n, bool))
        tout.append(end if n == max(lengths) else np.zeros(n, bool))
    obs = np.concatenate(obs)
    return odata.create(obs, np.zeros((len(obs), 3), np.float32), np.concatenate(rew), obs,
                        np.concatenate(term), np.concatenate(tout), np.concatenate(ids),
                        metadata={"action_limit": 1.0})


def _row(args, dataset, learner, reward, scores, safe):
    return {"cell": ch8.cell_key(dataset, learner, reward, args), "dataset": dataset,
            "learner": learner, "reward": reward, "normalized_score": list(scores),
            "safe_pct": [safe] * len(scores), "success_pct": [0.0] * len(scores)}


def _write_results(args, scores, bc, safe):
    rows = []
    for (d, lrn), means in scores.items():
        for r, m in zip(("original", *WRONG), means, strict=True):
            rows.append(_row(args, d, lrn, r, (m - 1.0, m + 1.0), safe.get((d, lrn), 100.0)))
    for d, m in bc.items():
        rows.append(_row(args, d, "BC", "none", (m, m), safe.get((d, "BC"), 100.0)))
    for d, lrn in (("mixed-full-filtered", "ATAC"), ("mixed-full-filtered", "PSPI")):
        rows.append(_row(args, d, lrn, "original", (50.0, 52.0), safe[(d, lrn)]))
    # a row of other settings (another step count) is ignored
    other = _row(args, "mixed-cut", "BC", "none", (-99.0, -99.0), 0.0)
    key = json.loads(other["cell"])
    key[4] += 1  # the step count
    other["cell"] = json.dumps(key)
    rows.append(other)
    (args.out / "results.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\n")


@pytest.fixture(scope="module")
def figures(tmp_path_factory):
    out = tmp_path_factory.mktemp("ch8")
    args = parse_args(["--out", str(out), "--recipes", "mixed", "--scale", "1",
                           "--seeds", "2", "--steps", "50", "--hidden", "16", "16"])
    for name, (lengths, per_step) in {"mixed-cut": ([5, 10, 20, 20], [0.1, 0.2, 0.5, 0.4]),
                                      "mixed-full": ([20] * 4, [0.1, 0.5, 0.3, 0.2])}.items():
        recipe, cut, _ = ch8.split_name(name)
        path = ch8.data_path(args, recipe, cut)
        path.parent.mkdir(parents=True, exist_ok=True)
        odata.save(_handmade_dataset(lengths, per_step), path)
    _write_results(args, SCORES, BC, SAFE)
    summary = ch8_report.figures_stage(args)
    return args, summary


def test_figures_files_and_fields(figures):
    args, _ = figures
    for f in ("fig8_4.png", "fig8_5.png", "fig8_6.png", "table.md", "table.csv", "safety.md",
              "safety.json", "summary.json"):
        assert (args.out / f).stat().st_size > 0, f
    on_disk = json.loads((args.out / "summary.json").read_text())
    for k in ("a", "b", "safety", "well_above_bc", "bias_estimate", "rule_a", "rule_b",
              "length_return_correlation", "cut_fraction"):
        assert k in on_disk
    assert on_disk["cut_fraction"] == {"mixed-cut": 0.5, "mixed-full": 0.0}
    assert on_disk["length_return_correlation"]["mixed-full"] is None  # all lengths equal
    assert on_disk["length_return_correlation"]["mixed-cut"] > 0.9


def test_acceptance_checks_recomputed_from_results(figures):
    args, summary = figures
    rows = [json.loads(x) for x in (args.out / "results.jsonl").read_text().splitlines()]
    cell = {(r["dataset"], r["learner"], r["reward"]): float(np.mean(r["normalized_score"]))
            for r in rows if r["cell"] == ch8.cell_key(r["dataset"], r["learner"], r["reward"],
                                                        args)}
    # (a): mean over the wrong rewards >= BC + 10
    for d in ("mixed-cut", "mixed-full"):
        for lrn in ("ATAC", "PSPI"):
            wrong = np.mean([cell[(d, lrn, r)] for r in WRONG])
            assert summary["well_above_bc"][f"{d}/{lrn}"] == bool(
                wrong >= cell[(d, "BC", "none")] + 10)
    assert summary["a"] is True and summary["bc_mean"]["mixed-cut"] == 40.0
    # (b): eq 8.3 = 100 / max(100 - min wrong, 0); PSPI reaches 100 on mixed-cut -> inf
    assert summary["bias_estimate"]["mixed-cut/PSPI"] == "inf"
    assert summary["bias_estimate"]["mixed-cut/ATAC"] == pytest.approx(100 / (100 - 60))
    assert summary["bias_estimate"]["mixed-full/ATAC"] == pytest.approx(100 / (100 - 15))
    assert summary["b"] is True
    # safety: collision % of the filtered run < BC's (20 %) and < its own unfiltered one
    safety = json.loads((args.out / "safety.json").read_text())
    assert safety["checks"] == {"ATAC": True, "PSPI": False}  # PSPI 22 % > BC 20 %
    assert summary["safety"] is False
    assert safety["rows"]["ATAC (filtered)"]["collision_pct"] == pytest.approx(5.0)


def test_acceptance_flips_with_the_data(figures, tmp_path):
    """Lowering ATAC's wrong-reward scores on the biased dataset turns (a) and (b) False."""
    args, _ = figures
    args2 = parse_args(["--out", str(tmp_path), "--recipes", "mixed", "--scale", "1",
                            "--seeds", "2", "--steps", "50", "--hidden", "16", "16"])
    (tmp_path / "data").symlink_to(args.out / "data")
    scores = dict(SCORES)
    scores[("mixed-cut", "ATAC")] = (90, 40, 45, 5)
    _write_results(args2, scores, BC, SAFE)
    summary = ch8_report.figures_stage(args2)
    assert summary["well_above_bc"]["mixed-cut/ATAC"] is False and summary["a"] is False
    assert summary["bias_larger_on_length_biased"]["mixed/ATAC"] is False  # 100/95 < 100/85
    assert summary["b"] is False


def test_no_safety_leaves_the_safety_report_out(figures, tmp_path):
    """``--no-safety``: no safety.md / safety.json and no safety verdict, even though the
    unfiltered safety dataset's cells are there (the table and figures are still written)."""
    args, _ = figures
    args2 = parse_args(["--out", str(tmp_path), "--recipes", "mixed", "--scale", "1",
                            "--seeds", "2", "--steps", "50", "--hidden", "16", "16",
                            "--no-safety"])
    (tmp_path / "data").symlink_to(args.out / "data")
    _write_results(args2, SCORES, BC, SAFE)
    summary = ch8_report.figures_stage(args2)
    assert summary["safety"] is None and summary["a"] is True
    assert (tmp_path / "table.md").exists()
    assert not (tmp_path / "safety.md").exists() and not (tmp_path / "safety.json").exists()


def test_figures_redrawn_without_the_datasets_use_the_cached_length_statistics(figures,
                                                                              tmp_path):
    """Results copied without ``data/`` (datasets are large): the length statistics come from
    ``length_bias.json``; with neither, Fig 8.5 is skipped and the rest is still written."""
    args, summary = figures
    out = tmp_path / "copy"
    out.mkdir()
    for f in ("results.jsonl", "length_bias.json"):
        (out / f).write_text((args.out / f).read_text())
    argv = ["--out", str(out), "--recipes", "mixed", "--scale", "1", "--seeds", "2", "--steps",
            "50", "--hidden", "16", "16"]
    again = ch8_report.figures_stage(parse_args(argv))
    assert again["cut_fraction"] == summary["cut_fraction"] == {"mixed-cut": 0.5,
                                                               "mixed-full": 0.0}
    assert (out / "fig8_5.png").exists()
    bare = tmp_path / "bare"
    bare.mkdir()
    (bare / "results.jsonl").write_text((args.out / "results.jsonl").read_text())
    argv[1] = str(bare)
    third = ch8_report.figures_stage(parse_args(argv))
    assert third["cut_fraction"] == {} and third["a"] == summary["a"]
    assert not (bare / "fig8_5.png").exists() and (bare / "fig8_4.png").exists()


@pytest.mark.slow
def test_cpu_smoke_end_to_end(tmp_path):
    """The script's CPU smoke, tiny, as a subprocess: every stage, every learner, 2 seeds × 50
    steps (minutes)."""
    argv = ["--out", str(tmp_path), "--scale", "1", "--steps", "50", "--hidden", "16", "16",
            "--seeds", "2", "--eval-episodes", "2", "--reference-episodes", "4", "--chunk",
            "25", "--batch", "32"]
    script = [sys.executable, str(ROOT / "scripts" / "reproduce_ch8.py")]
    subprocess.run([*script, *argv], check=True)
    rows = [json.loads(x) for x in (tmp_path / "results.jsonl").read_text().splitlines()]
    assert len(rows) == 2 * (4 * 4 + 1) + 3  # 2 datasets × (4 learners × 4 rewards + BC)
    assert {r["learner"] for r in rows if r["filtered"]} == {"ATAC", "PSPI", "BC"}
    summary = json.loads((tmp_path / "summary.json").read_text())
    cell = {(r["dataset"], r["learner"], r["reward"]): float(np.mean(r["normalized_score"]))
            for r in rows}
    wrong = np.mean([cell[("mixed-cut", "ATAC", r)] for r in WRONG])
    assert summary["well_above_bc"]["mixed-cut/ATAC"] == bool(
        wrong >= cell[("mixed-cut", "BC", "none")] + 10)
    for f in ("fig8_4.png", "fig8_5.png", "fig8_6.png", "table.md", "safety.md"):
        assert (tmp_path / f).exists()
    subprocess.run([*script, *argv, "--stage", "train"], check=True)  # resumable: nothing left
    assert len((tmp_path / "results.jsonl").read_text().splitlines()) == len(rows)


def test_goal_deadline_datasets_are_named_and_keyed(tmp_path):
    """``--goal-deadline N`` adds ``<recipe>-deadline``, ``-goal`` and ``-arrive`` (derived
    from the cut data, counted as length-biased), whose cells carry N in their key; other cells
    keep their keys."""
    base = ["--out", str(tmp_path), "--recipes", "mixed", "--scale", "1"]
    args = parse_args([*base, "--goal-deadline", "200"])
    assert args.datasets == ["mixed-cut", "mixed-full", "mixed-deadline", "mixed-goal",
                             "mixed-arrive", "mixed-full-filtered"]
    for name in ("mixed-deadline", "mixed-goal", "mixed-arrive"):
        assert ch8.split_name(name) == ("mixed", True, False)
        assert ch8.is_deadline(name)
        key = json.loads(ch8.cell_key(name, "ATAC", "zero", args))
        assert key[0] == name and key[key.index("goal_deadline") + 1] == 200
    assert not ch8.is_deadline("mixed-cut") and not ch8.is_deadline("mixed-full")
    plain = parse_args(base)
    assert ch8.cell_key("mixed-cut", "ATAC", "zero", args) == ch8.cell_key(
        "mixed-cut", "ATAC", "zero", plain)
    assert "mixed-deadline" not in plain.datasets and "mixed-goal" not in plain.datasets
    with pytest.raises(SystemExit):
        parse_args([*base, "--goal-deadline", "0"])
    # --ppo-run: the data of that run's snapshots get their own files and cell keys.
    ppo = parse_args([*base, "--ppo-run", str(tmp_path / "nn_run"), "--ppo-step", "40"])
    assert ch8.data_path(ppo, "mixed", True).name.endswith("_s0_ppo_nn_run_40.npz")
    assert ch8.data_path(plain, "mixed", True).name.endswith("_s0.npz")
    assert ch8.cell_key("mixed-cut", "ATAC", "zero", ppo) != ch8.cell_key(
        "mixed-cut", "ATAC", "zero", plain)
    with pytest.raises(SystemExit):
        parse_args([*base, "--ppo-step", "40"])
    # --substeps: another control rate, with its own data files and cell keys.
    rate = parse_args([*base, "--substeps", "24"])
    assert ch8.env_kwargs(rate) == {"substeps": 24, "horizon": 75}
    assert ch8.env_kwargs(plain) is None
    assert ch8.data_path(rate, "mixed", True).name.endswith("_s0_substeps_24.npz")
    assert ch8.cell_key("mixed-cut", "ATAC", "zero", rate) != ch8.cell_key(
        "mixed-cut", "ATAC", "zero", plain)
    with pytest.raises(SystemExit):
        parse_args([*base, "--substeps", "7"])
    # --reward-form goal: new keys for the rewards made from the true one, shared ones for
    # zero and random (the same data under either form).
    goal = parse_args([*base, "--reward-form", "goal"])
    for reward in ("original", "negated"):
        key = json.loads(ch8.cell_key("mixed-cut", "ATAC", reward, goal))
        assert key[-2:] == ["reward_form", "goal"]
        assert ch8.cell_key("mixed-cut", "ATAC", reward, plain) != json.dumps(key)
    for reward in ("zero", "random"):
        assert ch8.cell_key("mixed-cut", "ATAC", reward, goal) == ch8.cell_key(
            "mixed-cut", "ATAC", reward, plain)
    with pytest.raises(SystemExit):
        parse_args([*base, "--reward-form", "negative"])
    # --beta: ATAC and PSPI cells get their own keys; BC, IQL and CQL keep theirs.
    pess = parse_args([*base, "--beta", "1"])
    for learner in ("ATAC", "PSPI"):
        key = json.loads(ch8.cell_key("mixed-cut", learner, "zero", pess))
        assert key[-2:] == ["beta", 1.0]
    for learner, reward in (("BC", "none"), ("IQL", "zero"), ("CQL", "zero")):
        assert ch8.cell_key("mixed-cut", learner, reward, pess) == ch8.cell_key(
            "mixed-cut", learner, reward, plain)
    with pytest.raises(SystemExit):
        parse_args([*base, "--beta", "-1"])


def test_learning_curves_end_at_the_final_scores_and_the_goal_form_is_trained(tmp_path,
                                                                               monkeypatch):
    """``--curve``: one evaluation per chunk in every row, the last equal to the row's final
    evaluation (same parameters, same episodes); the figures stage draws fig8_curves.png.
    ``--reward-form goal``: the program trains on ``r − r_max`` (non-positive) and its negation
    (non-negative); the negated row records the form, the zero row does not.
    ``--substeps 24``: the data are collected and checked with 24 physics substeps per control
    step and a 75-step horizon (10 Hz, the same 7.5 s episodes)."""
    seen = []
    rows_of = sweep.reward_rows

    def recording(dataset, rewards, terminals, key):
        base, rows = rows_of(dataset, rewards, terminals, key)
        seen.append((np.asarray(dataset.rewards), dataset.metadata["reward_range"], rows))
        return base, rows

    monkeypatch.setattr(sweep, "reward_rows", recording)
    # the random recipe: one behaviour to collect (mixed has four), the same stages after it
    argv = ["--out", str(tmp_path), "--recipes", "random", "--datasets", "random-full",
            "--learners", "ATAC", "--rewards", "negated", "zero", "--no-safety", "--scale",
            "1", "--substeps", "24", "--steps", "40", "--chunk", "20", "--hidden", "16", "16",
            "--seeds", "2", "--eval-episodes", "2", "--reference-episodes", "4", "--batch",
            "32", "--curve", "--reward-form", "goal"]
    ch8_report.run(parse_args(argv))
    (shifted, (_, r_max), trained), = seen
    ds = ch8.load_dataset(parse_args(argv), "random-full")
    assert ds.metadata["horizon"] == 75 and ds.size == 75
    assert ds.metadata["env_kwargs"]["substeps"] == 24
    true = np.asarray(ds.rewards)
    np.testing.assert_allclose(shifted, true - r_max, rtol=0, atol=1e-6)
    assert (shifted <= 0).all() and (trained[0] >= 0).all() and (trained[1] == 0).all()
    np.testing.assert_array_equal(trained[0], -shifted)
    rows = [json.loads(x) for x in (tmp_path / "results.jsonl").read_text().splitlines()]
    assert sorted(r["reward"] for r in rows) == ["negated", "zero"]
    assert {r["reward"]: r["reward_form"] for r in rows} == {"negated": "goal", "zero": None}
    for r in rows:
        curve = r["curve"]
        assert curve["steps"] == [20, 40]
        assert np.asarray(curve["normalized_score"]).shape == (2, 2)  # steps × seeds
        for k in ("normalized_score", "safe_pct", "success_pct"):
            assert curve[k][-1] == r[k], k
    assert (tmp_path / "fig8_curves.png").stat().st_size > 0
    cells = ch8_analysis.load_cells(parse_args(argv))
    assert set(cells) == {("random-full", "ATAC", "negated"), ("random-full", "ATAC", "zero")}
    # the environment's form shares the zero cell but not the negated one
    env_form = ch8_analysis.load_cells(parse_args(argv[:-2]))
    assert set(env_form) == {("random-full", "ATAC", "zero")}
    c = cells[("random-full", "ATAC", "zero")]
    assert c["curve"]["mean"][-1] == pytest.approx(c["mean"])


def test_learning_curve_keeps_points_per_cell():
    """``programs.LearningCurve``: ``after`` runs the wrapped callback, then records; ``groups``
    gives per cell the steps and each metric's per-seed values per step; no points (a program
    resumed at its last chunk) give no groups."""
    results = iter([[{"normalized_score": [1.0, 2.0]}, {"normalized_score": [3.0, 4.0]}],
                    [{"normalized_score": [5.0, 6.0]}, {"normalized_score": [7.0, 8.0]}]])
    curve = programs.LearningCurve(lambda state: next(results))
    assert curve.groups() == []
    seen = []
    on_chunk = curve.after(lambda state, means, steps: seen.append(steps))
    on_chunk(None, {}, 10)
    on_chunk(None, {}, 20)
    assert seen == [10, 20] and curve.seconds >= 0
    assert curve.groups() == [
        {"steps": [10, 20], "normalized_score": [[1.0, 2.0], [5.0, 6.0]]},
        {"steps": [10, 20], "normalized_score": [[3.0, 4.0], [7.0, 8.0]]}]


def test_learning_curve_points_survive_a_resumed_program(tmp_path):
    """With a ``path`` (:func:`offline.experiment.programs.curve_path` of the program's
    checkpoint folder) the points written before an interruption are read back by the next
    process, which adds its own; :func:`offline.experiment.programs.remove_program_checkpoints`
    deletes folder and file."""
    ckpt = programs.program_checkpoint_dir(tmp_path, "cell A")
    path = programs.curve_path(ckpt)
    assert path.parent == tmp_path and programs.curve_path(None) is None
    first = programs.LearningCurve(lambda state: [{"normalized_score": [float(state)]}], path)
    first.record(1, 10)
    first.record(2, 20)
    resumed = programs.LearningCurve(lambda state: [{"normalized_score": [float(state)]}], path)
    resumed.record(3, 30)
    assert resumed.groups() == [{"steps": [10, 20, 30],
                                 "normalized_score": [[1.0], [2.0], [3.0]]}]
    assert programs.LearningCurve(lambda state: [], None).steps == []
    ckpt.mkdir()
    programs.remove_program_checkpoints(ckpt)
    assert not ckpt.exists() and not path.exists()
    programs.remove_program_checkpoints(None)

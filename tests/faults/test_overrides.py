"""Issue 27, case 4: ``--set`` overrides are parsed by the field's declared type, strictly, and
every refusal names the field and the expected type."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from typing import Literal

import pytest

from agents.ppo import PPOConfig
from agents.run.spec import RunSpec, parse_overrides, preset
from mjxrmp.config import parse_assignments, parse_field

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.mark.parametrize("item, name, value", [
    ("policy_activation=tanh", "policy_activation", "tanh"),
    ("episode_length=300", "episode_length", 300),
    ("shuffle_blocks=2", "shuffle_blocks", 2),
])
def test_typed_fields_are_accepted(item, name, value):
    """issue case 4: `--set policy_activation=tanh` (was "could not convert string to float"),
    `episode_length=300` and `shuffle_blocks=2` (were refused as non-integers) now parse to their
    declared types and build a valid configuration."""
    overrides = parse_overrides([item])
    assert overrides == {name: value} and type(overrides[name]) is type(value)
    assert getattr(preset("cpu", **overrides), name) == value


@pytest.mark.parametrize("item, match", [
    ("normalize_observations=ture",
     r"--set normalize_observations=ture: PPOConfig\.normalize_observations expects a boolean "
     r"\(true, false, 1 or 0\), got 'ture'"),
    ("num_envs=four", r"--set num_envs=four: PPOConfig\.num_envs expects an integer, got 'four'"),
    ("episode_length=3.5", r"PPOConfig\.episode_length expects an integer or none, got '3.5'"),
    ("shuffle_blocks=two", r"PPOConfig\.shuffle_blocks expects an integer or none"),
    ("max_grad_norm=off", r"PPOConfig\.max_grad_norm expects a number or none, got 'off'"),
    ("learning_rate=fast", r"PPOConfig\.learning_rate expects a number, got 'fast'"),
    ("policy_hidden_sizes=64,x", r"PPOConfig\.policy_hidden_sizes expects comma-separated "
                                 r"values, each an integer, got '64,x'"),
    ("normalize_advantages=yes", r"PPOConfig\.normalize_advantages expects a boolean"),
])
def test_malformed_values_are_refused_naming_the_field(item, match):
    """issue case 4: `--set normalize_observations=ture` (silently became False) and
    `--set num_envs=four` (failed without naming the field) are refused naming the field and the
    expected type; so is every other value that is not of the declared type."""
    with pytest.raises(ValueError, match=match):
        parse_overrides([item])


def test_valid_overrides_parse_as_before():
    """issue case 4 (no behaviour change): the overrides that parsed before give exactly the same
    values, `none` gives None, `1e-4` a float, and booleans accept true/false/1/0 in any case."""
    got = parse_overrides(["learning_rate=1e-4", "policy_hidden_sizes=64,64",
                           "max_grad_norm=none", "normalize_observations=true", "num_envs=8",
                           "value_hidden_sizes=", "gamma=1", "max_grad_norm=0.5"])
    assert got == {"learning_rate": 1e-4, "policy_hidden_sizes": (64, 64),
                   "max_grad_norm": 0.5, "normalize_observations": True, "num_envs": 8,
                   "value_hidden_sizes": (), "gamma": 1.0}
    assert type(got["gamma"]) is float and type(got["num_envs"]) is int
    assert parse_overrides(["max_grad_norm=None"]) == {"max_grad_norm": None}
    for text, value in [("TRUE", True), ("False", False), ("1", True), ("0", False)]:
        assert parse_overrides([f"normalize_advantages={text}"]) == {
            "normalize_advantages": value}
    cfg = preset("cpu", **parse_overrides(["max_grad_norm=none", "learning_rate=1e-4"]))
    assert cfg.max_grad_norm is None and cfg.learning_rate == 1e-4


def test_unknown_fields_and_missing_values_name_the_valid_ones():
    """issue case 4: a misspelt field lists the valid ones; an item without `=` says NAME=VALUE;
    a well-typed but invalid value is refused by PPOConfig naming the field."""
    with pytest.raises(ValueError, match=r"unknown PPOConfig field 'num_env'.*'num_envs'"):
        parse_overrides(["num_env=4"])
    with pytest.raises(ValueError, match="--set expects NAME=VALUE, got 'num_envs'"):
        parse_overrides(["num_envs"])
    with pytest.raises(ValueError, match=r"PPOConfig\.num_envs must be an integer >= 1, got 0"):
        preset("cpu", **parse_overrides(["num_envs=0"]))
    with pytest.raises(ValueError, match=r"PPOConfig\.policy_activation must be one of"):
        preset("cpu", **parse_overrides(["policy_activation=sigmoidish"]))


@dataclasses.dataclass(frozen=True)
class _Choices:
    """A configuration with the annotation kinds PPOConfig does not use."""

    shape: Literal["sphere", "cylinder"] = "sphere"
    pair: tuple[int, float] = (1, 2.0)


def test_literal_fixed_tuple_and_optional_annotations():
    """issue case 4 (parser by declared type): Literal choices, fixed-length tuples and optional
    tuples (RunSpec.seeds, RunSpec.keep_checkpoints) parse or are refused by name."""
    assert parse_assignments(_Choices, ["shape=cylinder", "pair=3,4.5"]) == {
        "shape": "cylinder", "pair": (3, 4.5)}
    with pytest.raises(ValueError,
                       match=r"_Choices\.shape expects one of \['sphere', 'cylinder'\]"):
        parse_field(_Choices, "shape", "cube")
    with pytest.raises(ValueError, match=r"_Choices\.pair expects 2 comma-separated values"):
        parse_field(_Choices, "pair", "3")
    assert parse_field(RunSpec, "seeds", "0,1,2") == (0, 1, 2)
    assert parse_field(RunSpec, "keep_checkpoints", "none") is None
    with pytest.raises(ValueError, match=r"RunSpec\.ppo expects a PPOConfig \(not settable"):
        parse_field(RunSpec, "ppo", "x")
    assert parse_field(PPOConfig, "policy_hidden_sizes", "") == ()


def test_train_cli_refuses_a_malformed_override_naming_the_field():
    """issue case 4 end to end: `scripts/train.py --set normalize_observations=ture` exits 2 with
    a one-line error naming the field, before anything is built."""
    proc = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "train.py"), "--set",
                           "normalize_observations=ture", "--out", os.devnull],
                          cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "JAX_PLATFORMS": "cpu"})
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "PPOConfig.normalize_observations expects a boolean" in proc.stderr, proc.stderr

"""The committed 30-shape LASA run (results/lfd_lasa/all_shapes): every demonstration start's
rollout, stored over 1.2 × the demonstration's duration, ends within 1 % of the goal, and the
per-shape records agree with the stored arrays (docs/reports/lfd_lasa.md)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from mjxrmp.data.lasa import LASA_SHAPES

RUN = Path(__file__).resolve().parents[3] / "results" / "lfd_lasa" / "all_shapes"


@pytest.fixture(scope="module")
def arrays() -> dict[str, dict[str, np.ndarray]]:
    missing = [s for s in LASA_SHAPES if not (RUN / f"{s}.npz").exists()]
    assert not missing, f"no committed rollouts for {missing}"
    return {s: dict(np.load(RUN / f"{s}.npz")) for s in LASA_SHAPES}


def test_all_210_starts_arrive_by_1_2_durations(arrays):
    arrived = 0
    for shape, z in arrays.items():
        demos, rollouts = z["demos"], z["rollouts"]
        n, t = demos.shape[:2]
        assert rollouts.shape == (n, math.ceil(1.2 * (t - 1)) + 1, 2), shape
        assert np.allclose(rollouts[:, 0], demos[:, 0]), shape
        assert float(z["dt"]) > 0.0, shape
        final = np.linalg.norm(rollouts[:, -1], axis=-1)
        arrived += int(np.sum(final < 0.01))
    assert arrived == 7 * len(LASA_SHAPES) == 210


def test_records_match_the_stored_rollouts(arrays):
    record = json.loads((RUN / "metrics.json").read_text())
    assert record["summary"]["demo_starts_arrived"] == 210
    for shape, z in arrays.items():
        t = z["demos"].shape[1]
        err = np.linalg.norm(z["rollouts"][:, :t] - z["demos"], axis=-1)
        rmse = float(np.mean(np.sqrt(np.mean(err**2, axis=1))))
        assert rmse == pytest.approx(record["shapes"][shape]["metrics"]["rmse"], rel=1e-4), shape

"""Prediction dataset from a real (short) SUMO run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sumo_ethics.predict import features as F
from sumo_ethics.predict.dataset import build_dataset, rebuild_samples, split_seeds

ROOT = Path(__file__).resolve().parents[1]
URBAN = ROOT / "scenarios" / "urban" / "urban.sumocfg"


def test_split_is_by_seed():
    s = split_seeds(list(range(1, 11)))
    assert s == {"train": [1, 2, 3, 4, 5, 6], "val": [7, 8], "test": [9, 10]}
    with pytest.raises(ValueError):
        split_seeds([1, 2])


@pytest.mark.sumo
@pytest.mark.skipif(not URBAN.exists(), reason="bundled urban scenario missing")
def test_build_dataset_from_sumo(tmp_path):
    out = build_dataset([URBAN], [1, 2, 3], tmp_path / "ds", sim_seconds=40.0, anchor_every=1.0)
    traj = pd.read_parquet(out / "trajectories.parquet")
    assert {"run_id", "seed", "scenario", "time", "agent_id", "cls", "x", "y", "yaw", "speed", "length", "width"} <= set(traj.columns)
    assert sorted(traj["seed"].unique()) == [1, 2, 3]
    # 10 Hz, and positions do not jump (lane changes take 2 s)
    one = traj[traj["run_id"] == 0].sort_values(["agent_id", "time"])
    dt = one.groupby("agent_id")["time"].diff().dropna()
    assert np.allclose(dt.median(), 0.1)
    step = np.hypot(one.groupby("agent_id")["x"].diff(), one.groupby("agent_id")["y"].diff()).dropna()
    assert step.quantile(0.999) < 5.0
    meta = json.loads((out / "split.json").read_text())
    assert meta["split"] == {"train": [1], "val": [2], "test": [3]}
    with np.load(out / "samples.npz") as z:
        assert z["tgt_hist"].shape[1:] == (F.HIST_STEPS, 2)
        assert z["fut"].shape[1:] == (F.FUT_STEPS, 2)
        assert z["nbr_ptr"][-1] == len(z["nbr_hist"])
        np.testing.assert_allclose(z["tgt_hist"][:, -1], 0.0, atol=1e-4)  # target frame
        assert set(np.unique(z["split"])) <= {0, 1, 2}
        assert len(z["nbr_yaw"]) == len(z["nbr_hist"]) and np.all(np.abs(z["nbr_yaw"]) <= np.pi + 1e-6)
        first = {k: z[k] for k in z.files}
    # samples derived again from the recorded trajectories (after a layout change) equal the first ones
    again = rebuild_samples(out, tmp_path / "ds2")
    with np.load(again / "samples.npz") as z:
        assert sorted(z.files) == sorted(first) and all(np.array_equal(z[k], first[k]) for k in z.files)
    assert json.loads((again / "split.json").read_text())["split"] == meta["split"]
    with pytest.raises(ValueError, match="out must differ"):
        rebuild_samples(out, out)

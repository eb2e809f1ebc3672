"""ADE ratios with run-bootstrap intervals (predict.evaluate.ratio_intervals), worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from sumo_ethics.predict.accuracy import ci_markdown, ratio_intervals


def gaussians(offset: np.ndarray, modes: int | None = None) -> np.ndarray:
    """(S, T, 5) (or (S, M, T, 5)) Gaussians whose mean is ``offset`` (S, T) metres east of the truth (0, 0)."""
    p = np.zeros(offset.shape + (5,))
    p[..., 0] = offset
    p[..., 2:4] = 1.0
    if modes is None:
        return p
    out = np.zeros((offset.shape[0], modes) + offset.shape[1:] + (5,))
    out[:, 0] = p
    out[:, 1:, ..., 2:4] = 1.0  # the other modes sit on the truth: only the most likely one is scored
    return out


def scene():
    """Two runs of two samples, two future points each. Run 0: the model 1 m off, constant velocity
    2 m; run 1: both 2 m off, and a third point not observed (100 m off, ignored)."""
    run = np.array([0, 0, 1, 1])
    model = np.array([[1, 1], [1, 1], [2, 2], [2, 2]], float)
    cv = np.full((4, 2), 2.0)
    valid = np.ones((4, 2), dtype=bool)
    model3, cv3 = np.concatenate([model, [[100], [100], [100], [100]]], 1), np.concatenate([cv, np.zeros((4, 1))], 1)
    fut3, valid3 = np.zeros((4, 3, 2)), np.concatenate([valid, np.zeros((4, 1), bool)], 1)
    outputs = {"constant_velocity": (gaussians(cv3), None), "constant_velocity_calibrated": (gaussians(cv3), None),
               "map_cslstm": (gaussians(model3, modes=3), np.full((4, 3), 1 / 3))}
    return outputs, fut3, valid3, run


def test_ratio_and_interval_over_runs_by_hand():
    outputs, fut, valid, run = scene()
    sel = [("all", np.ones(4, bool)), ("run 1 only", run == 1)]
    ci = ratio_intervals(outputs, fut, valid, run, sel)
    assert list(zip(ci["model"], ci["reference"])) == [("map_cslstm", "constant_velocity")] * 2  # not the calibrated CV
    row = ci.iloc[0]
    # summed errors: model 4 + 8 = 12 m over 8 points (ADE 1.5), constant velocity 8 + 8 = 16 (ADE 2.0)
    assert (row["n"], row["runs"]) == (4, 2)
    assert row["ade"] == pytest.approx(1.5) and row["ade_reference"] == pytest.approx(2.0)
    assert row["ratio"] == pytest.approx(0.75)
    # resampling two runs: (0, 0) 8 / 16 = 0.5 (p = 1/4), (0, 1) 0.75 (1/2), (1, 1) 16 / 16 = 1.0 (1/4)
    assert (row["lo"], row["hi"]) == (pytest.approx(0.5), pytest.approx(1.0))
    one = ci.iloc[1]  # one run: every resample is that run
    assert one["runs"] == 1 and one["ratio"] == one["lo"] == one["hi"] == pytest.approx(1.0)


def test_attention_against_its_cslstm_counterpart():
    outputs, fut, valid, run = scene()
    outputs = {"constant_velocity": outputs["constant_velocity"],
               "cslstm": (gaussians(np.full((4, 3), 2.0)), None), "attention": (gaussians(np.full((4, 3), 1.9)), None)}
    ci = ratio_intervals(outputs, fut, valid, run, [("all", np.ones(4, bool))]).set_index(["model", "reference"])
    assert ci.loc[("attention", "cslstm"), "ratio"] == pytest.approx(0.95)  # 5 % below CS-LSTM
    assert ci.loc[("attention", "cslstm"), "lo"] == pytest.approx(0.95)  # the same 5 % in every run
    assert ci.loc[("cslstm", "constant_velocity"), "ratio"] == pytest.approx(1.0)
    assert "| attention | cslstm | all | 4 | 2 | 1.900 | 2.000 | 0.950 | 0.950-0.950 |" in ci_markdown(ci.reset_index())


def test_the_same_seed_gives_the_same_interval():
    rng = np.random.default_rng(3)
    run = rng.integers(0, 9, 300)
    fut, valid = np.zeros((300, 4, 2)), np.ones((300, 4), bool)
    outputs = {"constant_velocity": (gaussians(rng.uniform(0, 3, (300, 4))), None),
               "map": (gaussians(rng.uniform(0, 3, (300, 4)), modes=1), np.ones((300, 1)))}
    a = ratio_intervals(outputs, fut, valid, run, [("all", np.ones(300, bool))])
    b = ratio_intervals(outputs, fut, valid, run, [("all", np.ones(300, bool))])
    assert a.equals(b) and a["lo"].iloc[0] < a["ratio"].iloc[0] < a["hi"].iloc[0]

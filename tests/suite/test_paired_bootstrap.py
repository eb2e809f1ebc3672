"""The paired bootstrap of ``suite.evaluate.table`` draws the scenarios both planners have uniformly,
however many runs are missing; the package has one bootstrap draw (``analysis.stats.resample``).

The table: 15 scenarios s00..s14. The reference ("ref") has a run for all 15, with no harm. The
planner "p" has a run for s00..s09 only: no harm on s00..s04, a total harm of 10 on s05..s09. The
paired difference (p - ref) in total harm over the 10 scenarios both have is 5 x 0 + 5 x 10 = 50.

A uniform resample of those 10 scenarios draws a harmful one with chance 1/2 each time: the summed
difference is 10 x Binomial(10, 1/2), whose 2.5th and 97.5th percentiles are 20 and 80
(P(X <= 1) = 0.011 < 0.025 < P(X <= 2) = 0.055; P(X <= 7) = 0.945 < 0.975 < P(X <= 8) = 0.989), so
the 95 % interval is [20, 80] around 50. The draw this replaces took indices over all 15 scenarios
modulo 10: s00..s04 came up twice as often as s05..s09 (chance 1/3 for a harmful one), an interval of
10 x Binomial(10, 1/3): [10, 60], which does not centre on the estimate.
"""

from __future__ import annotations

import numpy as np
from scipy import stats as st

from sumo_ethics.analysis.stats import bootstrap, bootstrap_ci, ratio_ci, resample
from sumo_ethics.suite.evaluate import METRICS, paired_risk, table

N_BOOT, SEED = 2000, 0


def _row(scenario: str, planner: str, total: float, risk: float | None = None) -> dict:
    r = {"scenario": scenario, "planner": planner, "completed": True, "total": total, "ego": 0.0,
         "third_party": total, "vru": 0.0}
    if risk is not None:
        r["risk_total_mean"] = risk
    return r


def _rows() -> list[dict]:
    rows = [_row(f"s{i:02d}", "ref", 0.0) for i in range(15)]
    rows += [_row(f"s{i:02d}", "p", 10.0 if i >= 5 else 0.0) for i in range(10)]
    return rows


def test_by_hand_the_interval_is_binomial():
    assert (st.binom.ppf(0.025, 10, 0.5), st.binom.ppf(0.975, 10, 0.5)) == (2, 8)
    assert (st.binom.ppf(0.025, 10, 1 / 3), st.binom.ppf(0.975, 10, 1 / 3)) == (1, 6)  # the old draw's


def test_paired_interval_resamples_the_scenarios_both_have_uniformly():
    t1, paired = table(_rows(), ["ref", "p"], reference="ref", n_boot=N_BOOT, seed=SEED)
    tot = next(r for r in paired if r["metric"] == "total")
    assert tot["scenarios"] == 10 and tot["difference"] == 50.0
    assert (tot["lo"], tot["hi"]) == (20.0, 80.0)  # 10 x the 2.5th / 97.5th percentile of Binomial(10, 1/2)
    # the same interval computed independently: a hand-written uniform resample with the same seed logic
    d = np.array([0.0] * 5 + [10.0] * 5)
    sums = d[np.random.default_rng(SEED).integers(0, 10, size=(N_BOOT, 10))].sum(axis=1)
    assert (tot["lo"], tot["hi"]) == tuple(np.percentile(sums, [2.5, 97.5]))
    # and scipy's percentile bootstrap of the summed differences (its own draws: close, not equal)
    ci = st.bootstrap((d,), np.sum, n_resamples=N_BOOT, method="percentile", random_state=SEED).confidence_interval
    assert abs(ci.low - tot["lo"]) <= 10 and abs(ci.high - tot["hi"]) <= 10
    # the draw this replaced: indices over all 15 scenarios modulo 10 (s00..s04 twice as likely)
    old = d[np.random.default_rng(SEED).integers(0, 15, size=(N_BOOT, 15))[:, :10] % 10].sum(axis=1)
    assert tuple(np.percentile(old, [2.5, 97.5])) == (10.0, 60.0)


def test_planner_rows_resample_their_own_runs():
    t1, _ = table(_rows(), ["ref", "p"], reference="ref", n_boot=N_BOOT, seed=SEED)
    p = next(r for r in t1 if r["planner"] == "p")
    assert p["runs"] == 10 and p["total"] == 50.0 and (p["total_lo"], p["total_hi"]) == (20.0, 80.0)
    assert p["completed"] == p["completed_lo"] == p["completed_hi"] == 100.0
    ref = next(r for r in t1 if r["planner"] == "ref")
    assert ref["runs"] == 15 and ref["total"] == ref["total_lo"] == ref["total_hi"] == 0.0


def test_no_missing_run_gives_every_planner_and_pair_the_same_resamples():
    rows = [_row(f"s{i:02d}", p, float(i) * (p == "p")) for i in range(10) for p in ("ref", "p")]
    t1, paired = table(rows, ["ref", "p"], reference="ref", n_boot=N_BOOT, seed=SEED)
    p = next(r for r in t1 if r["planner"] == "p")
    tot = next(r for r in paired if r["metric"] == "total")
    assert (p["total_lo"], p["total_hi"]) == (tot["lo"], tot["hi"])  # ref has no harm: the same sums
    assert len(paired) == len(METRICS)


def test_a_planner_without_runs():
    rows = [_row(f"s{i:02d}", "ref", 1.0) for i in range(4)]
    t1, paired = table(rows, ["ref", "p"], reference="ref", n_boot=50)
    p = next(r for r in t1 if r["planner"] == "p")
    assert p["runs"] == 0 and np.isnan(p["completed"]) and p["total"] == 0.0 and np.isnan(p["total_lo"])
    assert all(r["scenarios"] == 0 and r["lo"] == r["hi"] == 0.0 for r in paired)


def test_paired_risk_resamples_uniformly_too():
    rows = [_row(f"s{i:02d}", "ref", 0.0, risk=0.0) for i in range(15)]
    rows += [_row(f"s{i:02d}", "p", 0.0, risk=1.0 if i >= 5 else 0.0) for i in range(10)]
    r = next(x for x in paired_risk(rows, ["ref", "p"], "ref", n_boot=N_BOOT, seed=SEED)
             if x["metric"] == "risk_total_mean")
    assert r["scenarios"] == 10 and r["difference"] == 0.5
    assert (r["lo"], r["hi"]) == (0.2, 0.8)  # Binomial(10, 1/2) / 10


def test_one_bootstrap_draw():
    idx = resample(7, 30, 3)
    assert idx.shape == (30, 7) and idx.min() >= 0 and idx.max() <= 6
    assert np.array_equal(idx, np.random.default_rng(3).integers(0, 7, size=(30, 7)))
    x = np.arange(7.0)
    assert np.array_equal(bootstrap(x, lambda r: r.mean(axis=1), 30, 3), x[idx].mean(axis=1))
    # the sweep tables' intervals are that draw
    means = x[resample(7, 2000, 0)].mean(axis=1)
    assert bootstrap_ci(x) == tuple(float(v) for v in np.quantile(means, [0.025000000000000022, 0.975]))
    num, den = np.array([1.0, 2.0, 3.0]), np.array([2.0, 2.0, 2.0])
    i = resample(3, 2000, 0)
    r = num[i].sum(axis=1) / den[i].sum(axis=1)
    assert ratio_ci(num, den) == (float(np.quantile(r, 0.025000000000000022)), float(np.quantile(r, 0.975)))

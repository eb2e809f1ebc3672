"""Tables of a sweep: completion rate and harm per class per parameter value, bootstrap 95% CIs;
and the package's one bootstrap draw (:func:`resample`, :func:`bootstrap`), which ``suite/evaluate``
uses too.

The CI is a seeded percentile bootstrap over runs (runs are the independent samples: seeds
of the same grid point). A group of one run has a zero-width interval.
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np
import pandas as pd

from sumo_ethics.errors import ConfigError

#: harm classes as booked per run: (runs column, label)
HARM_CLASSES = (("harm_ego", "ego"), ("harm_third_party", "third party"), ("harm_vru", "VRU"),
                ("harm_total", "total"))
#: most bootstrap resamples (each is an index array the size of the group)
MAX_BOOT = 100_000
HARM_UNIT = "harm [-] (P(MAIS 3+), summed over the run's ego collisions)"


def resample(n: int, n_boot: int = 2000, seed: int | np.random.Generator = 0) -> np.ndarray:
    """(n_boot, n) int indices into n samples, every one drawn uniformly from 0..n-1 with replacement
    (``np.random.default_rng(seed).integers(0, n, (n_boot, n))``): the draw of every bootstrap of
    the package. n >= 1. ``seed`` may be a Generator: several bootstraps then draw from one stream."""
    return np.random.default_rng(seed).integers(0, n, size=(n_boot, n))


def bootstrap(samples: np.ndarray, stat: Callable[[np.ndarray], np.ndarray], n_boot: int = 2000,
              seed: int | np.random.Generator = 0) -> np.ndarray:
    """``stat`` of ``n_boot`` uniform resamples (:func:`resample`) of ``samples`` (n, ...): rows are
    resampled whole (the two values of a pair, a numerator with its denominator). ``stat`` maps the
    resamples (n_boot, n, ...) to (n_boot, ...); returns that."""
    x = np.asarray(samples)
    return stat(x[resample(len(x), n_boot, seed)])


def bootstrap_ci(values: Sequence[float] | np.ndarray | pd.Series, n_boot: int = 2000, seed: int = 0,
                 level: float = 0.95) -> tuple[float, float]:
    """Percentile bootstrap CI of the mean of ``values`` (NaN, NaN for no values)."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return math.nan, math.nan
    if x.size == 1 or np.all(x == x[0]):
        return float(x[0]), float(x[0])
    means = bootstrap(x, lambda r: r.mean(axis=1), n_boot, seed)
    a = (1.0 - level) / 2.0
    lo, hi = np.quantile(means, [a, 1.0 - a])
    return float(lo), float(hi)


def check_groups(runs: pd.DataFrame, by: Sequence[str]) -> list[str]:
    by = list(by)
    missing = [b for b in by if b not in runs.columns]
    if missing:
        raise ConfigError(f"unknown --by column(s): {', '.join(missing)}; known: {', '.join(runs.columns)}")
    return by


def summary_table(runs: pd.DataFrame, by: Sequence[str], n_boot: int = 2000, seed: int = 0) -> pd.DataFrame:
    """One row per group: n_runs, completion and collision rates, harm per class (mean, sum, 95% CI)."""
    by = check_groups(runs, by)
    rows = []
    groups = runs.groupby(by, sort=True, dropna=False) if by else [((), runs)]
    for key, g in groups:
        key = key if isinstance(key, tuple) else (key,)
        row = dict(zip(by, key))
        row["n_runs"] = len(g)
        row["n_errors"] = int((g["status"] == "error").sum())
        for name, rate in (("completion_rate", g["completed"].astype(float)),
                           ("collision_rate", (g["collisions_ego"] > 0).astype(float))):
            lo, hi = bootstrap_ci(rate, n_boot, seed)
            row.update({name: float(rate.mean()), f"{name}_ci_lo": lo, f"{name}_ci_hi": hi})
        for col, _ in HARM_CLASSES:
            lo, hi = bootstrap_ci(g[col], n_boot, seed)
            row.update({f"{col}_mean": float(g[col].mean()), f"{col}_sum": float(g[col].sum()),
                        f"{col}_ci_lo": lo, f"{col}_ci_hi": hi})
        rows.append(row)
    return pd.DataFrame(rows)


def ratio_ci(num: np.ndarray, den: np.ndarray, n_boot: int = 2000, seed: int = 0,
             level: float = 0.95) -> tuple[float, float]:
    """Percentile bootstrap CI of sum(num) / sum(den), resampling the runs (pairs) with replacement."""
    num, den = np.asarray(num, dtype=float), np.asarray(den, dtype=float)
    if len(num) == 0:
        return float("nan"), float("nan")
    with np.errstate(divide="ignore", invalid="ignore"):
        r = bootstrap(np.stack([num, den]).T, lambda b: (np.ascontiguousarray(b[..., 0]).sum(axis=1)
                                                          / np.ascontiguousarray(b[..., 1]).sum(axis=1)), n_boot, seed)
    r = r[np.isfinite(r)]
    if len(r) == 0:
        return float("nan"), float("nan")
    a = (1.0 - level) / 2.0
    return float(np.quantile(r, a)), float(np.quantile(r, 1.0 - a))


def rate_ci(num: np.ndarray, den: np.ndarray, scale: float = 1.0, n_boot: int = 2000,
            seed: int = 0) -> tuple[float, float, float]:
    """(rate, CI low, CI high) of ``scale`` x sum(num) / sum(den) over runs (NaN rate for no
    denominator), the CI from :func:`ratio_ci`."""
    total = float(np.sum(den))
    rate = scale * float(np.sum(num)) / total if total > 0 else float("nan")
    lo, hi = ratio_ci(num, den, n_boot, seed)
    return rate, scale * lo, scale * hi


#: conflict classes of the runs table: (name, column or None for total - vru)
CONFLICT_CLASSES = (("all", "conflicts_total"), ("vehicle", None), ("vru", "conflicts_vru"))


def conflict_table(runs: pd.DataFrame, by: Sequence[str], n_boot: int = 2000, seed: int = 0) -> pd.DataFrame:
    """Conflicts (near misses, ``conflicts.parquet``) per class and group: per 100 ego-km and per
    ego-hour, each the group's sum of conflicts over its sum of distance / driving time, with a
    bootstrap CI over runs. Runs without conflict counts (measured off) are left out; no row
    for a group without any."""
    by = check_groups(runs, by)
    if "conflicts_total" not in runs.columns:
        return pd.DataFrame()
    have = runs[runs["conflicts_total"].notna()]
    rows = []
    for key, g in (have.groupby(by, sort=True, dropna=False) if by else [((), have)]):
        key = key if isinstance(key, tuple) else (key,)
        km = g["distance"].to_numpy(float) / 1000.0
        hours = g["drive_time"].to_numpy(float) / 3600.0 if "drive_time" in g else np.full(len(g), np.nan)
        row = dict(zip(by, key))
        row.update(n_runs=len(g), ego_km=float(km.sum()), ego_hours=float(np.nansum(hours)))
        for name, col in CONFLICT_CLASSES:
            n = (g["conflicts_total"] - g["conflicts_vru"]).to_numpy(float) if col is None else g[col].to_numpy(float)
            row[f"conflicts_{name}"] = float(n.sum())
            for unit, den, scale in (("per_100km", km, 100.0), ("per_hour", hours, 1.0)):
                rate, lo, hi = rate_ci(n, den, scale, n_boot, seed)
                row.update({f"{name}_{unit}": rate, f"{name}_{unit}_ci_lo": lo, f"{name}_{unit}_ci_hi": hi})
        rows.append(row)
    return pd.DataFrame(rows)


#: traffic outcomes of fleet runs: (name, runs column); harm per 10^6 vehicle-km of all trips,
#: mean time loss per trip [s]
TRAFFIC_HARM = (("egos", "harm_all_egos"), ("other_vehicles", "harm_all_other_vehicles"), ("vru", "harm_all_vru"),
                ("total", "harm_all_total"))
TRAFFIC_LOSS = (("egos", "time_loss_egos"), ("other_vehicles", "time_loss_other_vehicles"),
                ("persons", "time_loss_persons"))


def traffic_table(runs: pd.DataFrame, by: Sequence[str], n_boot: int = 2000, seed: int = 0) -> pd.DataFrame:
    """Fleet runs' traffic outcomes per group: everyone's harm by party per 10^6 vehicle-km (the
    group's summed harm over its summed vehicle-km of all trips), the egos' conflicts per 100
    ego-km, the conflicts among the road users that are not egos (``conflicts_others``, runs with
    ``[conflicts] everyone``) per 100 vehicle-km of all trips, all of them and those with a VRU, and
    every conflict of those runs (the egos' and the others') per 100 vehicle-km (NaN for a group
    without such runs), mean time loss per trip by party (mean over runs), each with a bootstrap
    95 % CI over runs. Empty without fleet runs."""
    by = check_groups(runs, by)
    if "vehicle_km" not in runs.columns or not runs["vehicle_km"].notna().any():
        return pd.DataFrame()
    have = runs[runs["vehicle_km"].notna()]
    rows = []
    for key, g in (have.groupby(by, sort=True, dropna=False) if by else [((), have)]):
        key = key if isinstance(key, tuple) else (key,)
        km = g["vehicle_km"].to_numpy(float)
        row = dict(zip(by, key))
        row.update(n_runs=len(g), egos=float(g["fleet_egos"].mean()), vehicle_km=float(km.sum()),
                   ego_km=float(g["distance"].sum() / 1000.0))
        for name, col in TRAFFIC_HARM:
            rate, lo, hi = rate_ci(g[col].to_numpy(float), km, 1e6, n_boot, seed)
            row.update({f"harm_{name}_per_Mvkm": rate, f"harm_{name}_per_Mvkm_ci_lo": lo,
                        f"harm_{name}_per_Mvkm_ci_hi": hi})
        if "conflicts_total" in g and g["conflicts_total"].notna().any():
            c = g[g["conflicts_total"].notna()]
            rate, lo, hi = rate_ci(c["conflicts_total"].to_numpy(float), c["distance"].to_numpy(float) / 1000.0, 100.0,
                                   n_boot, seed)
        else:
            rate = lo = hi = float("nan")
        row.update(conflicts_per_100km=rate, conflicts_per_100km_ci_lo=lo, conflicts_per_100km_ci_hi=hi)
        o = g[g["conflicts_others"].notna()] if "conflicts_others" in g else g.iloc[:0]
        vkm = o["vehicle_km"].to_numpy(float)
        for name, n in (("others", o.get("conflicts_others")), ("others_vru", o.get("conflicts_others_vru")),
                        ("everyone", o.get("conflicts_others", 0.0) + o.get("conflicts_total", np.nan))):
            rate, lo, hi = rate_ci(np.asarray(n, float), vkm, 100.0, n_boot, seed) if len(o) else (np.nan,) * 3
            row.update({f"conflicts_{name}_per_100vkm": rate, f"conflicts_{name}_per_100vkm_ci_lo": lo,
                        f"conflicts_{name}_per_100vkm_ci_hi": hi})
        for name, col in TRAFFIC_LOSS:
            lo, hi = bootstrap_ci(g[col], n_boot, seed)
            row.update({f"time_loss_{name}": float(g[col].mean()), f"time_loss_{name}_ci_lo": lo,
                        f"time_loss_{name}_ci_hi": hi})
        rows.append(row)
    return pd.DataFrame(rows)


def status_table(runs: pd.DataFrame, by: Sequence[str]) -> pd.DataFrame:
    """Run counts per group and status (completed, collision, timeout, error)."""
    by = check_groups(runs, by)
    t = runs.groupby(by + ["status"], dropna=False).size().unstack("status", fill_value=0)
    for s in ("completed", "collision", "timeout", "error"):
        if s not in t.columns:
            t[s] = 0
    return t[["completed", "collision", "timeout", "error"]].reset_index()


def ego_collision_harm(collisions: pd.DataFrame) -> pd.DataFrame:
    """Long table of harm per ego collision and class: columns run_id, omega_u, ..., class, harm.

    Per ego collision: the ego's harm (class "ego"), and the other party's harm booked as
    "third party" (cars, trucks, buses) or "VRU" (pedestrians, cyclists, motorcyclists).
    """
    if collisions.empty or "involves_ego" not in collisions.columns:
        return pd.DataFrame(columns=["run_id", "class", "harm", "class_b"])
    c = collisions[collisions["involves_ego"].astype(bool)]
    base = [col for col in c.columns if col in ("run_id", "scenario", "omega_u", "seed", "event", "class_b",
                                                  "delta_v")]
    ego = c[base].assign(**{"class": "ego", "harm": c["harm_ego"]})
    vru = c["harm_vru"] > 0
    third = c.loc[~vru, base].assign(**{"class": "third party", "harm": c.loc[~vru, "harm_third_party"]})
    vr = c.loc[vru, base].assign(**{"class": "VRU", "harm": c.loc[vru, "harm_vru"]})
    return pd.concat([ego, third, vr], ignore_index=True)


def collision_table(collisions: pd.DataFrame) -> pd.DataFrame:
    """Per class of the other party: the ego's booked collisions (n_collisions; confirmed by the
    geometry, by SUMO or both) with their mean delta-v and harm per class, and n_unconfirmed: SUMO's
    reports whose boxes do not overlap at the recorded poses (``detector`` "sumo_unconfirmed"),
    listed in collisions.parquet and booked as no harm, so left out of the means."""
    cols = ["class_b", "n_collisions", "n_unconfirmed", "delta_v_mean_m_s", "harm_ego_mean", "harm_third_party_mean",
            "harm_vru_mean"]
    if collisions.empty:
        return pd.DataFrame(columns=cols)
    c = collisions[collisions["involves_ego"].astype(bool)]
    if c.empty:
        return pd.DataFrame(columns=cols)
    unconfirmed = (c["detector"] == "sumo_unconfirmed") if "detector" in c else pd.Series(False, index=c.index)
    booked = c[~unconfirmed]
    t = booked.groupby("class_b").agg(n_collisions=("event", "size"), delta_v_mean_m_s=("delta_v", "mean"),
                                      harm_ego_mean=("harm_ego", "mean"),
                                      harm_third_party_mean=("harm_third_party", "mean"),
                                      harm_vru_mean=("harm_vru", "mean"))
    t = t.reindex(sorted(set(c["class_b"])))
    t["n_collisions"] = t["n_collisions"].fillna(0).astype(int)
    t["n_unconfirmed"] = c[unconfirmed].groupby("class_b").size().reindex(t.index).fillna(0).astype(int)
    return t.rename_axis("class_b").reset_index()[cols]


def to_markdown(df: pd.DataFrame, digits: int = 4) -> str:
    """A GitHub Markdown table (no extra dependency)."""
    def cell(v) -> str:
        if isinstance(v, (float, np.floating)):
            return "" if math.isnan(v) else f"{v:.{digits}g}"
        return str(v)

    head = "| " + " | ".join(map(str, df.columns)) + " |"
    sep = "| " + " | ".join("---" for _ in df.columns) + " |"
    body = ["| " + " | ".join(cell(v) for v in row) + " |" for row in df.itertuples(index=False)]
    return "\n".join([head, sep, *body]) + "\n"

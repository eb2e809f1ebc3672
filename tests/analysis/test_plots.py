"""The figures of ``analyze`` are readable: no series hidden, CIs told apart, the same w_u axis in
every sweep, the trade-off plot split by every --by key (synthetic sweep, no SUMO)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sumo_ethics.analysis import load, plots
from sumo_ethics.analysis.stats import summary_table

from test_analysis import fake_sweep  # noqa: F401 - fixture


@pytest.fixture
def figures(monkeypatch):
    """Keep every figure the plot functions make instead of saving it."""
    kept = []
    monkeypatch.setattr(plots, "_save", lambda fig, folder, name: kept.append(fig) or
                        [Path(folder) / f"{name}.png", Path(folder) / f"{name}.svg"])
    return kept


def _summary(omega_u, weights=("ethical", "ego")) -> pd.DataFrame:
    """Two weight presets with IDENTICAL rates at every w_u (the case that hid one series)."""
    rows = []
    for w in omega_u:
        for p in weights:
            row = {"omega_u": float(w), "weights": p, "n_runs": 10}
            for col, v in (("completion_rate", 0.8), ("collision_rate", 0.2), ("harm_ego", 0.1),
                           ("harm_third_party", 0.2), ("harm_vru", 0.05)):
                name = col if col.endswith("rate") else f"{col}_mean"
                row |= {name: v, f"{col}_ci_lo": v - 0.1, f"{col}_ci_hi": v + 0.1}
            rows.append(row)
    return pd.DataFrame(rows)


def test_equal_series_stay_visible_side_by_side(figures, tmp_path):
    plots.completion_vs_parameter(_summary([0, 10, 1000]), ["omega_u", "weights"], tmp_path)
    ax = figures[0].axes[0]
    lines = [c.lines[0] for c in ax.containers]  # each series' line (its CI bars are c.lines[1:])
    assert len(lines) == 4  # completed and ego collision, for each preset
    # the same data point (w_u = 10, rate 0.8) is drawn at different places on the screen
    screen_x = {round(float(ln.get_transform().transform((10.0, 0.8))[0]), 1) for ln in lines}
    assert len(screen_x) == 4
    assert len({ln.get_marker() for ln in lines}) == 4  # and with four different markers


@pytest.mark.parametrize("values", [[0, 0.5, 1], [0, 10, 1000], [0.5, 100]])
def test_w_u_axis_is_the_same_in_every_sweep(figures, tmp_path, values):
    plots.completion_vs_parameter(_summary(values), ["omega_u", "weights"], tmp_path)
    plots.harm_vs_parameter(_summary(values), ["omega_u"], tmp_path)
    for fig in figures:
        ax = fig.axes[0]
        assert ax.get_xscale() == "symlog" and ax.xaxis.get_transform().linthresh == 1.0
        assert [t.get_text() for t in ax.get_xticklabels()] == [f"{v:g}" for v in values]


def test_tradeoff_honours_every_by_key(fake_sweep, figures, tmp_path):  # noqa: F811
    runs = load(fake_sweep, steps=False).runs
    plots.tradeoff(runs, tmp_path, ["omega_u", "weights"])
    ax = figures[0].axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert {"w_u = 0", "w_u = 0.5", "w_u = 1", "weights=ego", "weights=ethical"} <= set(labels)
    for ticks, (lo, hi) in ((ax.get_xticks(), ax.get_xlim()), (ax.get_yticks(), ax.get_ylim())):
        assert sum(lo <= t <= hi for t in ticks) <= 6  # few labels: they do not run together
    markers = {c.get_paths()[0].vertices.shape for c in ax.collections}
    assert len(markers) >= 2  # one marker per weights preset


def test_report_uses_the_by_keys_for_the_tradeoff(fake_sweep, figures, tmp_path, monkeypatch):  # noqa: F811
    from sumo_ethics.analysis.report import make_report

    seen = {}
    real = plots.tradeoff
    monkeypatch.setattr(plots, "tradeoff", lambda runs, folder, by: seen.setdefault("by", list(by)) and
                        real(runs, folder, by))
    make_report(fake_sweep, ["omega_u", "weights"], tmp_path / "rep", n_boot=50)
    assert seen["by"] == ["omega_u", "weights"]
    assert np.isfinite(summary_table(load(fake_sweep, steps=False).runs, ["omega_u"]).harm_total_mean).all()

"""Fig. 3 on its quick preset: the paper's claims about risk-sensitive deployment, the exact
max-min (A3) against the paper's simplification (A4), the files, and bad settings."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from corrections_sim.figures import deployment, presets

EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments"


@pytest.fixture(scope="module")
def fig3():
    settings = deployment.load_settings("fig3", quick=True)
    with ThreadPoolExecutor(max_workers=1) as executor:
        return settings, deployment.run(settings, executor)


def _row(result, panel: str, rule: str, trajectory: str) -> dict:
    return next(
        r
        for r in result.trajectories
        if (r["panel"], r["rule"], r["trajectory"]) == (panel, rule, trajectory)
    )


def _phi(row: dict) -> np.ndarray:
    return np.array([row["phi_laptop"], row["phi_table"]])


def test_with_little_uncertainty_the_three_trajectories_nearly_coincide(fig3):
    """Paper (fig. 3, left): "if the robot has little uncertainty, risk-sensitive planning
    is almost the same as risk-neutral planning". Measured: feature counts within 0.09 of
    the neutral ones with P = 0.01 I, against differences of 0.5–4.4 with P = I."""
    _, result = fig3
    for panel, bound in (("little", 0.15), ("both", None)):
        neutral = _phi(_row(result, panel, "A4", "neutral"))
        spread = max(
            np.max(np.abs(_phi(_row(result, panel, "A4", a)) - neutral))
            for a in ("averse", "seeking")
        )
        if bound is None:
            assert spread > 1.0
        else:
            assert spread < bound


@pytest.mark.parametrize("panel", ["both", "table"])
def test_averse_collects_fewer_features_and_seeking_more_than_neutral(fig3, panel):
    """Paper (fig. 3, middle): with large uncertainty the robot "attempts to decrease feature
    counts (risk-averse) or increase feature counts (risk-seeking)". With Φ ≥ 0, (A4) lowers
    or raises one weight; the total interaction Σ_i Φ_i orders averse < neutral < seeking."""
    _, result = fig3
    total = {a: _phi(_row(result, panel, "A4", a)).sum() for a in ("averse", "neutral", "seeking")}
    assert total["averse"] < total["neutral"] - 0.5
    assert total["seeking"] > total["neutral"] + 0.5


def test_confident_about_the_laptop_the_difference_concerns_the_table(fig3):
    """Paper (fig. 3, right): confident about the laptop, "uncertain as to whether it should
    avoid crossing the table". Measured: both (A4) choices move only the table weight, and
    the table count changes 9 to 13 times more than the laptop count."""
    settings, result = fig3
    neutral = _phi(_row(result, "table", "A4", "neutral"))
    for attitude in ("averse", "seeking"):
        row = _row(result, "table", "A4", attitude)
        assert row["gamma_laptop"] == settings.theta[0]
        assert row["gamma_table"] != settings.theta[1]
        change = np.abs(_phi(row) - neutral)
        assert change[1] > 5 * change[0]


def test_a3_is_never_worse_than_a4_in_the_worst_case_and_bounded_by_the_values(fig3):
    _, result = fig3
    tol = 1e-6
    for r in result.comparison:
        assert r["status"] == "ok"
        assert r["a3_worst_case"] >= r["a4_worst_case"] - tol
        assert r["a3_worst_case"] >= r["a4_refined_worst_case"] - tol
        assert r["a3_worst_case"] <= r["min_value_refined"] + tol
    for panel in ("little", "both", "table"):
        a3 = _row(result, panel, "A3", "averse")["worst_case"]
        for rule in ("A4", "A4r"):
            assert a3 >= _row(result, panel, rule, "averse")["worst_case"] - tol


def test_a3_gains_only_where_its_worst_case_is_shared_by_two_preferences(fig3):
    """Measured in the quick environments: with P = I, (A3) gains 0.02 and 0.30 over the
    refined (A4) where two preferences bind; with P = diag(0.01, 1) it equals (A4)."""
    _, result = fig3
    for r in result.comparison:
        kink = ";" in r["a3_worst_gammas"]
        if r["gain_refined"] > 1e-4:
            assert kink, r
    both = [r for r in result.comparison if r["panel"] == "both"]
    assert max(r["gain_refined"] for r in both) > 0.1
    table = [r for r in result.comparison if r["panel"] == "table"]
    assert max(abs(r["gain_refined"]) for r in table) < 1e-6


def test_fig3_writes_its_data_and_figure(fig3, tmp_path):
    settings, result = fig3
    written = deployment.write(settings, result, tmp_path)
    names = [p.name for p in written]
    assert names == [
        "trajectories.csv",
        "gammas.csv",
        "comparison.csv",
        "paths.csv",
        "fig3.png",
        "fig3.pdf",
    ]
    header = (tmp_path / "trajectories.csv").read_text().splitlines()[0].split(",")
    assert header[:4] == ["panel", "rule", "trajectory", "gamma_index"]
    assert {"phi_laptop", "phi_table", "worst_case", "reward_theta_hat"} <= set(header)
    # 3 panels x (3 A4 + 3 refined A4 + 1 A3) trajectories
    assert len((tmp_path / "trajectories.csv").read_text().splitlines()) == 1 + 3 * 7
    assert (tmp_path / "fig3.png").stat().st_size > 50_000
    assert len(result.timings) == len(settings.panels)
    assert all(t["a3_solve_time"] > 0 for t in result.timings)


def test_bad_fig3_settings_are_refused_by_field(tmp_path, monkeypatch):
    monkeypatch.setattr(presets, "EXPERIMENTS_DIR", tmp_path)
    original = (EXPERIMENTS / "fig3.toml").read_text()
    for old, new, message in (
        (
            "cov = [[0.01, 0.0], [0.0, 1.0]]",
            "cov = [[0.01, 0.0], [0.0, -1.0]]",
            r"panels\[2\]\.cov: must be positive definite",
        ),
        ("theta = [-1.0, 0.0]", "theta = [-1.0]", "theta: expected 2 values, got 1"),
        ("comparison_environments = 4", "comparison_environments = 49", "comparison_env"),
        ('name = "both"', 'name = "little"', "panels: names must be distinct"),
    ):
        (tmp_path / "fig3.toml").write_text(original.replace(old, new))
        with pytest.raises(ValueError, match=message):
            deployment.load_settings("fig3", quick=True)
    with pytest.raises(ValueError, match="seed: fig3 draws no random numbers"):
        deployment.load_settings("fig3", quick=True, overrides={"seed": 1})

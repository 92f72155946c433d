"""The report command: tables computed from a figure's summary, one-line errors otherwise."""

from __future__ import annotations

import json

from corrections_sim.cli import main as cli
from corrections_sim.figures import report

SUMMARY = {
    "final": {
        "PP": {
            "runs": 3,
            **{k: {"mean": 1.0, "sem": 0.1, "auc_mean": 9.0} for k in report.METRIC_NAMES},
        },
        "AL": {
            "runs": 1,
            **{k: {"mean": 2.0, "sem": None, "auc_mean": 8.0} for k in report.METRIC_NAMES},
        },
    },
    "calibration": {
        "AL": {
            "runs": 1,
            "mean_nees": [2.0, 3.5],
            "band": [0.05, 7.38],
            "inside_band": 1.0,
            "coverage_1sigma_mean": 0.0,
            "coverage_2sigma_mean": 1.0,
        }
    },
    "paired": [
        {
            "a": "PP",
            "b": "KF",
            "metric": "regret",
            "final": {"mean": 0.5, "ci95": [0.1, 0.9]},
            "auc": {"mean": -1.0, "ci95": [-2.0, 0.0]},
        }
    ],
}


def test_tables_quote_the_summary(tmp_path, capsys):
    (tmp_path / "summary.json").write_text(json.dumps(SUMMARY))
    assert cli.main(["report", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "| PP (N = 3) | AL (N = 1) |" in out
    assert "1.000 ± 0.100; 9.0" in out and "2.000 (N = 1); 8.0" in out
    assert "| AL (1) | 2 3.5 | [0.05, 7.38] | 100% | 0.00 / 1.00 |" in out
    assert "| PP − KF | regret | +0.500 [+0.100, +0.900] | -1.000 [-2.000, +0.000] |" in out


def test_bad_folders_are_one_line(tmp_path, capsys):
    assert cli.main(["report", str(tmp_path / "none")]) == 2
    (tmp_path / "summary.json").write_text("{}")
    assert cli.main(["report", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 2 and "no summary.json" in err and "not a learning" in err

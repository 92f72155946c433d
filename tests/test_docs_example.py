"""The docs' "Use it from Python" block (docs/python.md) runs as printed, and says what it
claims."""

from __future__ import annotations

import re
from pathlib import Path

PAGE = Path(__file__).resolve().parents[1] / "docs" / "python.md"


def test_the_python_example_runs(capsys):
    blocks = re.findall(r"```python\n(.*?)```", PAGE.read_text(), flags=re.S)
    assert len(blocks) == 1, "one python block on the page"
    exec(compile(blocks[0], "docs/python.md", "exec"), {})
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 3
    regrets = [float(re.search(r"regret ([\d.]+)", line).group(1)) for line in lines]
    assert regrets[-1] < regrets[0]


def test_the_readme_study_file_is_a_valid_study():
    """The README's ten-line study file parses as it says (its user and KF-C's model)."""
    import tomllib

    from corrections_sim.study import schema

    readme = PAGE.parents[1] / "README.md"
    blocks = re.findall(r"```toml\n(.*?)```", readme.read_text(), flags=re.S)
    assert len(blocks) == 1
    values = tomllib.loads(blocks[0])
    quick_values = values.pop("quick")
    settings = schema.parse_study(values).study
    assert settings.user.step == 0.5 and settings.learners["KF-C"].model.step == 0.5
    assert list(settings.learners) == ["KF", "KF-C"]
    quick = schema.parse_study({**values, **quick_values}).study
    assert quick.runs == 2

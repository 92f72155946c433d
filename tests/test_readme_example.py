"""The README's "Use it from Python" block runs as printed, and says what it claims."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_the_python_example_runs(capsys):
    text = README.read_text()
    section = text.split("## Use it from Python", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 1, "one python block in the section"
    exec(compile(blocks[0], "README.md (Use it from Python)", "exec"), {})
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 3
    regrets = [float(re.search(r"regret ([\d.]+)", line).group(1)) for line in lines]
    assert regrets[-1] < regrets[0]

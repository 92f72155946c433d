"""The house's rules that import-linter does not check: no module passes 600 lines unless the
map of the code (docs/architecture.md, "Modules over 600 lines") lists it with its reason, and
a listed one still does (so the list cannot go stale)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LIMIT = 600


def _lines(path: Path) -> int:
    return len(path.read_text().splitlines())


def test_modules_over_600_lines_are_the_listed_ones():
    page = (ROOT / "docs" / "architecture.md").read_text()
    section = page.split("**Modules over 600 lines.**", 1)[1].split("**", 1)[0]
    listed = set(re.findall(r"^\| `([\w/]+\.py)` \|", section, re.M))
    assert listed, "docs/architecture.md lists no module: this test would check nothing"
    sources = [
        p
        for folder in ("corrections_sim", "benchmarks", "scripted_people")
        for p in (ROOT / folder).rglob("*.py")
    ]
    long = {
        p.relative_to(ROOT / "corrections_sim").as_posix()
        if p.is_relative_to(ROOT / "corrections_sim")
        else p.relative_to(ROOT).as_posix(): _lines(p)
        for p in sources
        if _lines(p) > LIMIT
    }
    assert set(long) == listed, (
        f"over {LIMIT} lines but not listed: {sorted(set(long) - set(listed))}; "
        f"listed but no longer over: {sorted(set(listed) - set(long))}"
    )


def test_a_learner_is_updated_only_through_the_one_correction_step():
    """Every place a person corrects the robot (the study loop, a session, replay, the
    reference, the physical figure, the benchmarks) builds a learner's context and updates it
    through ``learning/correction.py``: nowhere else in the package or the benchmarks builds a
    ``LearnerContext`` or calls a learner's ``update`` (a family's own learners call their
    parents' and their maths')."""
    pattern = re.compile(r"LearnerContext\(|\b(agent|learner|engine|model)\.update\(")
    found = []
    for folder in ("corrections_sim", "benchmarks", "scripted_people"):
        for path in (ROOT / folder).rglob("*.py"):
            relative = path.relative_to(ROOT).as_posix()
            if relative.startswith("corrections_sim/learning/"):
                continue  # the protocol, the correction step and the families themselves
            text = path.read_text()
            found += [f"{relative}: {m.group(0)}" for m in pattern.finditer(text)]
    assert not found, found
    step = (ROOT / "corrections_sim" / "learning" / "correction.py").read_text()
    assert "LearnerContext(" in step and "agent.update(" in step


def test_every_default_learner_and_every_likelihood_is_registered():
    """The learners each command runs when none is named (one place, ``defaults.py``) are
    registered ones, and every learner's likelihood names a registered grid model (the exact
    reference looks it up, no string branches)."""
    from corrections_sim.defaults import DEFAULTS
    from corrections_sim.learning.base import LEARNERS, make_learner
    from corrections_sim.learning.exact.grid import GRID_MODELS

    named = {name for names in DEFAULTS.values() for name in names}
    assert named and named <= set(LEARNERS), named - set(LEARNERS)
    kinds = {make_learner(n).likelihood().kind for n in LEARNERS if make_learner(n).likelihood()}
    assert kinds == set(GRID_MODELS), (kinds, set(GRID_MODELS))

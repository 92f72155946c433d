"""The README and the docs cannot go stale: every number they quote from a committed result is
the file's, the README quotes no result by hand, and every pointer into the README or the docs
from the code, the presets and the examples leads somewhere."""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np
import pytest

from corrections_sim.figures import quotes

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]

#: The README's numbers that are not results: names, versions and counts of the text itself.
NOT_RESULTS = {
    "CoRL 2018": "the paper's venue",
    "7-DoF": "the Panda's joints",
    "Python 3.11": "what a fresh machine has",
    "fig. 4": "a figure's name",
    "figs. 1–3, 5 and 6": "figures' names",
}


def _prose(text: str) -> str:
    """``text`` without code blocks, inline code, quotes, link targets and HTML comments."""
    text = re.sub(r"```.*?```", "", text, flags=re.DOTALL)
    text = quotes.PATTERN.sub("", text)
    text = re.sub(r"`[^`]*`", "", text)
    text = re.sub(r"\]\([^)]*\)", "]", text)
    return re.sub(r"<!--.*?-->", "", text, flags=re.DOTALL)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_quoted_number_is_its_files(page):
    stale = quotes.stale(page.read_text(), ROOT)
    assert not stale, "; ".join(
        f"{name}: the page says {said!r}, the file {now!r}" for name, said, now in stale
    )


def test_the_readme_quotes_its_headline_table_and_time():
    text = README.read_text()
    assert {"headline", "minutes fig4"} <= {m[1] for m in quotes.PATTERN.finditer(text)}


def test_the_readme_has_no_number_outside_a_quote():
    """A result typed by hand goes stale: every digit in the README's prose is a quote or one
    of the names in NOT_RESULTS."""
    prose = _prose(README.read_text())
    for allowed in NOT_RESULTS:
        prose = prose.replace(allowed, "")
    assert re.findall(r"[^\s]*\d[^\s]*", prose) == []


def test_the_readme_is_two_screens():
    assert len(README.read_text().splitlines()) <= 110


def test_a_stale_quote_is_found_and_filled(tmp_path, monkeypatch, capsys):
    """``run quotes`` finds a hand-edited number (exit 1, the quote named) and --fill puts the
    file's back, nothing else; run where there is no results/, it refuses in one line."""
    from corrections_sim.cli import main as cli

    monkeypatch.chdir(ROOT)  # where results/ is
    page = tmp_path / "page.md"
    right = quotes.fill("took <!-- quote minutes fig4 -->0<!-- /quote --> minutes", ROOT)
    page.write_text(right.replace("-->" + quotes.minutes(ROOT, "fig4"), "-->999"))
    assert cli.main(["quotes", str(page)]) == 1
    out, err = capsys.readouterr()
    assert "quote minutes fig4: the page says '999'" in out and "1 quoted numbers differ" in err
    assert cli.main(["quotes", str(page), "--fill"]) == 0
    assert page.read_text() == right
    assert cli.main(["quotes", str(page)]) == 0
    monkeypatch.chdir(tmp_path)  # no results/ here: one line, exit 2
    capsys.readouterr()
    assert cli.main(["quotes"]) == 2
    assert "results/" in capsys.readouterr().err


@pytest.mark.parametrize(
    "quote, named",
    [
        ("nothing fig4", "no such quote"),
        ("value fig9 final", "fig9"),
        ("value fig4 final.XX.estimate_error.mean", "XX"),
        ("learners-table fig4 PP,XX", "no learner XX"),
        ("paired-table fig4 PP/XX", "no paired comparison PP/XX"),
    ],
)
def test_a_bad_quote_is_one_line_and_changes_nothing(tmp_path, monkeypatch, capsys, quote, named):
    from corrections_sim.cli import main as cli

    monkeypatch.chdir(ROOT)
    page = tmp_path / "page.md"
    text = f"<!-- quote minutes fig4 -->0<!-- /quote --> <!-- quote {quote} -->1<!-- /quote -->"
    page.write_text(text)
    assert cli.main(["quotes", str(page), "--fill"]) == 2
    err = capsys.readouterr().err
    assert named in err and quote in err and len(err.strip().splitlines()) == 1
    assert page.read_text() == text


def test_a_value_quote_formats_the_files_number():
    summary = quotes._summary(ROOT, "fig4")
    said = quotes.value(ROOT, "fig4", "final.KF-C.estimate_error.mean", ".3f")
    assert said == f"{summary['final']['KF-C']['estimate_error']['mean']:.3f}"
    assert quotes.value(ROOT, "fig4", "calibration.KF.mean_nees.-1", ".3g") == format(
        summary["calibration"]["KF"]["mean_nees"][-1], ".3g"
    )


def test_a_pooled_pair_is_the_mean_of_each_study_s_paired_difference(tmp_path):
    """Two studies of the same person (one of them in two folders): the paired difference at
    the last correction in each, their mean, and 1.96 · √(Σ SE²) / m either side."""

    def study(folder, rows):
        (tmp_path / "results" / folder).mkdir(parents=True)
        with open(tmp_path / "results" / folder / "curves.csv", "w", newline="") as f:
            out = csv.writer(f)
            out.writerow(["user", "learner", "run", "iteration", "estimate_error"])
            for learner, values in rows.items():
                for run, value in enumerate(values):
                    out.writerow(["p q", learner, run, 0, 9.0])  # not the last correction
                    out.writerow(["p q", learner, run, 2, value])

    study("one", {"A": [1.0, 2.0, 4.0], "B": [0.0, 0.0, 0.0]})  # differences 1, 2, 4
    study("two", {"A": [1.0, 1.0]})
    study("two_more", {"B": [2.0, 4.0]})  # differences −1, −3
    said = quotes.pooled_pair(tmp_path, "one,two+two_more", "A/B", "p_q", "estimate_error", "3")
    mean = (7 / 3 + -2.0) / 2
    se2 = np.var([1, 2, 4], ddof=1) / 3 + np.var([-1, -3], ddof=1) / 2
    low, high = mean - 1.96 * np.sqrt(se2) / 2, mean + 1.96 * np.sqrt(se2) / 2
    assert said == f"{mean:+.3f} [{low:.3f}, {high:.3f}]".replace("-", "−")
    study("uneven", {"A": [1.0, 2.0], "B": [1.0]})
    with pytest.raises(KeyError, match="do not share"):
        quotes.pooled_pair(tmp_path, "one,uneven", "A/B", "p_q", "estimate_error")
    with pytest.raises(KeyError, match="no B"):
        quotes.pooled_pair(tmp_path, "one,two", "A/B", "p_q", "estimate_error")


def test_a_mean_with_its_interval_from_a_study_of_one_person(tmp_path):
    """``mean-ci``: the mean at each run's last correction and 1.96 SEM either side, from a
    study's curves without a ``user`` column (``-``); a paired difference there too."""
    (tmp_path / "results" / "one").mkdir(parents=True)
    with open(tmp_path / "results" / "one" / "curves.csv", "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["learner", "run", "iteration", "nees"])
        for run, (a, b) in enumerate([(1.0, 0.5), (2.0, 1.0), (4.0, 1.5)]):
            out.writerows([["A", run, 0, 9.0], ["A", run, 3, a], ["B", run, 3, b]])
    said = quotes.mean_ci(tmp_path, "one", "A", "-", "nees", "2")
    half = 1.96 * np.sqrt(np.var([1, 2, 4], ddof=1) / 3)
    assert said == f"{7 / 3:.2f} [{7 / 3 - half:.2f}, {7 / 3 + half:.2f}]".replace("-", "−")
    paired = quotes.pooled_pair(tmp_path, "one", "A/B", "-", "nees", "2")
    assert paired.startswith("+1.33 [")
    with pytest.raises(KeyError, match="no C"):
        quotes.mean_ci(tmp_path, "one", "C", "-", "nees", "2")


def _anchors(page: Path) -> set[str]:
    """The heading anchors MkDocs makes (toc's slugify: lowercase, words joined by '-')."""
    found = set()
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.DOTALL)
    for line in text.splitlines():
        if line.startswith("#"):
            title = line.lstrip("#").strip().lower()
            slug = re.sub(r"[^\w\s-]", "", title)
            found.add(re.sub(r"[-\s]+", "-", slug).strip("-"))
    return found


SOURCES = [
    path
    for folder in ("corrections_sim", "experiments", "examples", "benchmarks", "tests")
    for path in sorted((ROOT / folder).rglob("*"))
    if path.suffix in {".py", ".toml"}
]


@pytest.mark.parametrize("source", SOURCES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_pointer_into_the_readme_or_the_docs_leads_somewhere(source):
    """A comment, help line or preset that names a README section or a docs page: the README
    has that section (the README names sections by their title in quotes), the page exists,
    and so does its anchor."""
    text = source.read_text()
    readme = _anchors(README)
    for m in re.finditer(r'README,? "([^"]+)"', text):
        title = re.sub(r"[-\s]+", "-", re.sub(r"[^\w\s-]", "", m[1].lower())).strip("-")
        assert title in readme, f"{source.name}: README has no section {m[1]!r}"
    for m in re.finditer(r"docs/([\w-]+\.md)(#[\w-]+)?", text):
        page = ROOT / "docs" / m[1]
        assert page.is_file(), f"{source.name}: no docs/{m[1]}"
        if m[2]:
            assert m[2][1:] in _anchors(page), f"{source.name}: docs/{m[1]} has no {m[2]}"


def test_help_lines_name_registered_learners_and_the_true_defaults():
    """A list of learners in any command's --help names registered learners only, and
    replay's stated default is the one it uses."""
    from corrections_sim.cli.commands import commands
    from corrections_sim.cli.options import catalogue
    from corrections_sim.learning.base import LEARNERS
    from corrections_sim.session.replay import DEFAULT_LEARNERS

    assert ",".join(DEFAULT_LEARNERS) in commands()["replay"].option_help["learners"]
    own = [text for command in commands().values() for text in command.option_help.values()]
    texts = [*own, *(a.help or "" for a in catalogue()._actions)]
    lists = re.findall(r"\b[A-Z]+(?:-[A-Z]+)?(?:,[A-Z]+(?:-[A-Z]+)?)+\b", " ".join(texts))
    assert lists, "the help names no list of learners: this test would check nothing"
    named = {name for found in lists for name in found.split(",")}
    assert named <= set(LEARNERS), named - set(LEARNERS)

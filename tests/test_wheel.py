"""The package as a user installs it (issue 13): a wheel, in a fresh virtual environment,
run from a folder that is not the clone, reads its presets from the package and makes a
figure. Also the files a user of the project looks for: LICENSE and CITATION.cff.

The wheel is built once per session (≈ 5 s). The fresh environment gets the wheel only; the
dependencies (mujoco, casadi, ...) come from the test's own environment through a ``.pth``
line, which is enough to prove that nothing is read from the clone, and saves installing
them again. The compiled planner is reused from the usual cache.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = (
    "pyproject.toml",
    "README.md",
    "LICENSE",
    "CITATION.cff",
    "corrections_sim",
    "experiments",
)


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel, built from a copy of the sources (the clone gets no build/ folder)."""
    work = tmp_path_factory.mktemp("wheel")
    (work / "src").mkdir()
    for name in SOURCES:
        source = ROOT / name
        if source.is_dir():
            ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
            shutil.copytree(source, work / "src" / name, ignore=ignore)
        else:
            shutil.copy2(source, work / "src" / name)
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "-q",
            "--no-deps",
            "-w",
            str(work / "dist"),
            str(work / "src"),
        ],
        check=True,
        capture_output=True,
    )
    (built,) = (work / "dist").glob("corrections_sim-*.whl")
    return built


@pytest.fixture(scope="module")
def python(wheel) -> Path:
    """The interpreter of a fresh virtual environment with the wheel installed."""
    venv = wheel.parent.parent / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    site = Path(sysconfig.get_path("purelib", vars={"base": str(venv), "platbase": str(venv)}))
    # The dependencies, not the package: a .pth line adds their folder without running its
    # .pth files, of which all but the clone's editable install are copied (pinocchio's
    # cmeel.pth among them); "00-" sorts this one first.
    dependencies = Path(sysconfig.get_path("purelib"))
    (site / "00-dependencies.pth").write_text(f"{dependencies}\n")
    for pth in dependencies.glob("*.pth"):
        if not pth.name.startswith("__editable__"):
            shutil.copy2(pth, site / pth.name)
    python = venv / "bin" / "python"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "--python",
            str(python),
            "install",
            "-q",
            "--no-deps",
            "--no-index",
            str(wheel),
        ],
        check=True,
        capture_output=True,
    )
    return python


def test_the_wheel_holds_every_module_every_preset_and_the_license(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    package = ROOT / "corrections_sim"
    modules = {
        f"corrections_sim/{p.relative_to(package).as_posix()}" for p in package.rglob("*.py")
    }
    presets = {
        f"corrections_sim/experiments/{p.name}" for p in (ROOT / "experiments").glob("*.toml")
    }
    assert modules <= names, sorted(modules - names)
    assert presets <= names and len(presets) >= 5, sorted(presets - names)
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names), sorted(names)


def test_an_installed_wheel_runs_a_figure_from_another_folder(python, tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env.setdefault("MUJOCO_GL", "egl")

    def run(*argv: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [str(python), *argv], cwd=tmp_path, env=env, capture_output=True, text=True
        )

    check = run(
        "-c",
        "import corrections_sim, json\n"
        "from corrections_sim.figures import deployment, learning_study, selection\n"
        "for module in (selection, deployment, learning_study):\n"
        "    for figure in module.FIGURES:\n"
        "        for quick in (False, True):\n"
        "            module.load_settings(figure, quick=quick)\n"
        "print(corrections_sim.__file__)\n",
    )
    assert check.returncode == 0, check.stderr
    assert Path(check.stdout.strip()).is_relative_to(python.parent.parent), check.stdout
    figure = run(
        "-m",
        "corrections_sim.run",
        "fig4",
        "--quick",
        "--runs",
        "1",
        "--iterations",
        "1",
        "--workers",
        "1",
    )
    assert figure.returncode == 0, figure.stderr
    summary = json.loads((tmp_path / "results" / "quick" / "fig4" / "summary.json").read_text())
    assert summary["git"] is None  # not a clone
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert summary["versions"]["corrections_sim"] == project["version"]


def test_license_and_citation_match_the_project():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "MIT"
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
    citation = (ROOT / "CITATION.cff").read_text()
    assert f"version: {project['version']}" in citation
    assert "license: MIT" in citation
    assert "Including Uncertainty when Learning from Human Corrections" in citation

"""Where a figure's files came from: the command, the code, the machine's packages, the time.

Recorded in every figure's ``summary.json`` so a folder of results can be traced back and
regenerated. Nothing here computes results: it is the command line's edge (see ``run.py``).
"""

from __future__ import annotations

import datetime
import math
import shlex
import subprocess
from collections.abc import Sequence
from dataclasses import asdict, is_dataclass
from importlib.metadata import version
from pathlib import Path

#: The packages whose versions can change a figure's numbers.
PACKAGES = ("corrections_sim", "mujoco", "casadi", "pin", "numpy")


def versions() -> dict[str, str]:
    """Installed versions of :data:`PACKAGES`."""
    return {n: version(n) for n in PACKAGES}


def git_commit(folder: Path | None = None) -> dict | None:
    """The commit (and whether tracked files differ from it) of the clone holding
    ``folder`` (default: this package's folder); None for an installed wheel or without git."""
    root = (folder or Path(__file__).resolve().parent).parent
    if not (root / ".git").exists():
        return None
    try:
        commit = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=5,
            check=True,
        ).stdout.strip()
        status = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=5,
            check=True,
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    return {"commit": commit, "modified": bool(status.strip())}


def machine() -> dict[str, str]:
    """What the floating point of a computation depends on beyond the code: the processor, the
    system and the numerical packages. Two computations with the same code and the same
    ``machine()`` give the same bits; across processors BLAS kernels, libm and so the
    solvers' iterations may round differently."""
    import platform

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": cpu, "system": platform.platform(), **versions()}


def plain(value):
    """``value`` as JSON data: dataclasses as dicts, tuples as lists, NaN and ±inf as None
    (strict JSON has no NaN), numpy scalars and arrays as Python numbers and lists."""
    if is_dataclass(value) and not isinstance(value, type):
        value = asdict(value)
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    if hasattr(value, "tolist"):  # numpy arrays and scalars
        return plain(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def record(argv: Sequence[str]) -> dict:
    """The provenance fields of a summary: command line, timestamp (UTC), package versions
    and the git commit when run from a clone."""
    return {
        "command": shlex.join(["python", "-m", "corrections_sim.run", *argv]),
        "timestamp": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "versions": versions(),
        "git": git_commit(),
    }


#: Modules that cannot change a learning run's numbers (files, plots, CLI, other figures).
EDGE_MODULES = (
    "run.py",
    "provenance.py",
    "study/store.py",
    "scene/render.py",
    "scene/models.py",
)
#: Packages that cannot change a learning run's numbers (command line, files and plots), and
#: of ``figures/`` the modules a learning run executes (the others make files or figs. 1–3).
EDGE_PACKAGES = ("cli/", "figures/", "session/", "userstudy/", "pages/")
FIGURE_MODULES = ("figures/learning_study.py",)


def code_fingerprint() -> str:
    """Hash of the sources a learning run executes and of the solver versions: part of the run
    cache's key, so runs made by other code never mix with these."""
    import hashlib

    digest = hashlib.sha256()
    root = Path(__file__).resolve().parent
    for path in sorted(root.rglob("*.py")):
        name = path.relative_to(root).as_posix()
        edge = name.startswith(EDGE_PACKAGES) and name not in FIGURE_MODULES
        if name in EDGE_MODULES or edge:
            continue
        if name.startswith("experiments/"):  # the presets, in a wheel; settings are in the key
            continue
        digest.update(name.encode())
        digest.update(path.read_bytes())
    for name, value in sorted(versions().items()):
        digest.update(f"{name}={value}".encode())
    # The fitted densities a learner reads when a study names no fit file (see
    # learning.relevance.judge.DEFAULT_FIT): data, but they change what a run computes.
    from importlib import resources

    fit = resources.files("corrections_sim.experiments").joinpath("relevance_fit.json")
    if fit.is_file():
        digest.update(fit.read_bytes())
    return digest.hexdigest()[:16]

"""A simulated cohort: a pilot of N simulated participants through a protocol, and the power
analysis of many simulated studies.

Every simulated participant goes through the protocol's state machine
(:func:`~corrections_sim.userstudy.participant.simulate_participant`) into a study log, as a
person at the page would; participant i's θ*, noise and answers are functions of (the
protocol's seed, i), so a pool split over workers (each into its own shard log) gives the
same participants as one process.

**Power.** A pool of P simulated participants is cut, for each study size N, into ⌊P/N⌋
disjoint studies of consecutive indices (so each study sees the Latin square's rows equally
when N is a multiple of its size); each study is analysed as ``run analyze`` analyses a log
(:func:`corrections_sim.userstudy.statistics.mixed_model` on its trials), and the power at N is
the share of studies whose condition effect has p < 0.05. The population's difference is the
mean paired difference over the whole pool (its standard error is reported); the coverage at
N is the share of studies whose 95% interval holds it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from corrections_sim.figures.presets import EXPERIMENTS_DIR
from corrections_sim.session.log import StudyLog
from corrections_sim.study import files, legacy, schema
from corrections_sim.study.settings import FigureSettings
from corrections_sim.userstudy import statistics
from corrections_sim.userstudy.participant import (
    StudyRun,
    check_conditions,
    simulate_participant,
)
from corrections_sim.userstudy.protocol import Protocol, load_protocol


def study_source(protocol: Protocol, base: Path | None) -> Path:
    """The study file a protocol's ``study`` names: a preset's name, or a path relative to
    the protocol file."""
    name = protocol.study
    preset = EXPERIMENTS_DIR / f"{name}.toml"
    if "/" not in name and not name.endswith(".toml") and preset.is_file():
        return preset
    path = Path(name) if base is None or Path(name).is_absolute() else base / name
    if not path.is_file():
        raise ValueError(f"study = {name!r}: neither a preset (fig4, …) nor a study file")
    return path


def settings_for(protocol: Protocol, base: Path | None = None) -> dict[str, FigureSettings]:
    """Each condition's (and the practice's) study settings: the protocol's study file with
    the condition's ``set`` keys; one-line errors name the condition's key."""
    source = study_source(protocol, base)
    values = files.read(source, quick=False, keys=(*schema.STUDY_KEYS, *legacy.LEGACY_KEYS))
    values = schema.apply_overrides(values, {})
    out = {}
    conditions = [*protocol.conditions, *([protocol.practice] if protocol.practice else [])]
    for i, condition in enumerate(conditions):
        where = "practice" if condition is protocol.practice else f"conditions[{i}]"
        mine = json.loads(json.dumps(values))
        try:
            for path, value in condition.set:
                files.set_path(mine, path, value)
            out[condition.name] = schema.parse_study(
                mine, name=source.stem, base=source.resolve().parent
            )
        except ValueError as exc:
            raise ValueError(f"{where}.set: {exc}") from None
    return out


def load(protocol_path) -> tuple[Protocol, dict[str, FigureSettings]]:
    """The protocol at ``protocol_path`` and its conditions' study settings, checked as a
    study run checks them, with nothing written."""
    protocol_path = Path(protocol_path)
    protocol = load_protocol(protocol_path)
    settings = settings_for(protocol, protocol_path.resolve().parent)
    check_conditions(protocol, settings)
    return protocol, settings


def open_run(protocol_path, db, loaded: tuple | None = None) -> StudyRun:
    """The protocol at ``protocol_path`` with the study log ``db`` (made if new);
    ``loaded``: what :func:`load` gave for it, where the caller checked it first."""
    if loaded is None:
        protocol_path = Path(protocol_path)
        protocol = load_protocol(protocol_path)
        settings = settings_for(protocol, protocol_path.resolve().parent)
    else:
        protocol, settings = loaded
    log = StudyLog(db)
    try:
        return StudyRun(protocol, log, settings)
    except BaseException:
        log.close()
        raise


def code_of(index: int) -> str:
    return f"sim{index:05d}"


def simulate_cohort(run: StudyRun, indices: Sequence[int], progress=None) -> int:
    """Simulated participants ``indices`` through the protocol into the run's log (those
    already finished are skipped, one stopped midway resumes); how many were simulated."""
    if run.protocol.simulation is None:
        raise ValueError("simulation: the protocol states no simulated population to draw from")
    done = 0
    for i, index in enumerate(indices):
        code = code_of(index)
        row = run.log.participant(code)
        if row is not None and row["index"] != index:
            raise ValueError(f"participant {code}: index {row['index']} in the log, not {index}")
        person = simulate_participant(run, code, index)
        done += person.where().step.kind == "end"
        if progress is not None:
            progress(i + 1, len(indices))
    return done


def simulate_shard(protocol_path: str, db: str, first: int, count: int) -> str:
    """A worker's share of a pool: participants first … first + count − 1 into ``db``."""
    run = open_run(protocol_path, db)
    try:
        simulate_cohort(run, range(first, first + count))
    finally:
        run.log.close()
    return db


#: Participants per shard log of a pool (the layout does not depend on the workers).
SHARD = 100


def shards(folder: Path, participants: int) -> list[tuple[Path, int, int]]:
    """(log, first index, count) of each shard of a pool of ``participants``."""
    return [
        (Path(folder) / f"shard-{first:05d}.sqlite", first, min(SHARD, participants - first))
        for first in range(0, participants, SHARD)
    ]


def pool_trials(dbs: Sequence[Path], outcome: str = "final_error") -> list[dict]:
    """The finished trials of every participant in the shard logs (tidy rows; no regret)."""
    from corrections_sim.userstudy.report import tidy

    rows = []
    for db in dbs:
        with StudyLog(db) as log:
            rows += tidy(log, regret=outcome == "mean_regret")["trials"]
    return rows


def power_table(
    trials: list[dict],
    conditions: Sequence[str],
    sizes: Sequence[int],
    outcome: str = "final_error",
    alpha: float = 0.05,
) -> dict:
    """The power and coverage at each study size (see the module) from a pool's trials."""
    if len(conditions) < 2:
        raise ValueError("power: the protocol needs two conditions or more to compare")
    by_index: dict[int, list[dict]] = {}
    for t in trials:
        by_index.setdefault(int(t["index"]), []).append(t)
    indices = sorted(by_index)
    pool = statistics.paired(trials, outcome, conditions)[0]
    truth = pool["mean"]
    out = {
        "outcome": outcome,
        "effect": f"{conditions[1]} - {conditions[0]}",
        "pool": len(indices),
        "difference": truth,
        "difference_se": pool["sd"] / math.sqrt(pool["n"]) if pool["n"] > 1 else math.nan,
        "d_z": pool["d_z"],
        "sizes": [],
    }
    for n in sizes:
        studies = len(indices) // n
        significant, covered, covered_z, estimates = [], [], [], []
        for s in range(studies):
            rows = [t for i in indices[s * n : (s + 1) * n] for t in by_index[i]]
            fit = statistics.mixed_model(rows, outcome, conditions)
            effect = fit["effects"][0]
            significant.append(effect["p"] < alpha)
            covered.append(effect["lo"] <= truth <= effect["hi"])
            covered_z.append(effect["z_lo"] <= truth <= effect["z_hi"])
            estimates.append(effect["estimate"])
        power = statistics.power_summary(significant)
        coverage = statistics.power_summary(covered)
        out["sizes"].append(
            {
                "participants": n,
                "studies": studies,
                "power": power["power"],
                "power_lo": power["lo"],
                "power_hi": power["hi"],
                "coverage": coverage["power"],
                "coverage_lo": coverage["lo"],
                "coverage_hi": coverage["hi"],
                "coverage_z": float(np.mean(covered_z)) if covered_z else math.nan,
                "mean_estimate": float(np.mean(estimates)) if estimates else math.nan,
            }
        )
    measured = [s for s in out["sizes"] if s["studies"] > 0]
    out["n_for_80"] = statistics.needed(
        [s["participants"] for s in measured], [s["power"] for s in measured]
    )
    return out


def power_markdown(table: Mapping, protocol: Protocol) -> str:
    """The power analysis as Markdown (says its participants are simulated)."""
    sim = protocol.simulation
    lines = [
        f"# Power analysis: {protocol.description}",
        "",
        "> **Simulated participants** (θ* ~ N(" + f"{list(sim.mean)}, diag({list(sim.sd)})²)"
        f", user {json.dumps(sim.user)}); every number below is from simulated studies.",
        "",
        f"Outcome `{table['outcome']}`, effect {table['effect']}. Pool of {table['pool']} "
        f"simulated participants; the population's difference (pool mean of the paired "
        f"differences) {table['difference']:.4f} ± {table['difference_se']:.4f} (SE), "
        f"standardized d_z = {table['d_z']:.3f}.",
        "",
        "| N | studies | power (p < 0.05) | 95% CI | t-interval coverage | 95% CI | "
        "z-interval coverage |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in table["sizes"]:
        lines.append(
            f"| {s['participants']} | {s['studies']} | {s['power']:.3f} | "
            f"[{s['power_lo']:.3f}, {s['power_hi']:.3f}] | {s['coverage']:.3f} | "
            f"[{s['coverage_lo']:.3f}, {s['coverage_hi']:.3f}] | {s['coverage_z']:.3f} |"
        )
    n80 = table["n_for_80"]
    lines += [
        "",
        "N for 80% power: "
        + (
            f"{n80:.1f} (interpolated between the sizes measured)"
            if n80 is not None
            else "not reached at the sizes measured"
        ),
        "",
    ]
    return "\n".join(lines)

"""The command line of a user study run from a protocol (docs/user-study.md):

    python -m corrections_sim.run serve-study experiments/protocol.toml --enroll P01,P02
    python -m corrections_sim.run study-status --db results/study/study.sqlite
    python -m corrections_sim.run analyze results/study/study.sqlite
    python -m corrections_sim.run pilot experiments/protocol.toml --participants 12
    python -m corrections_sim.run power experiments/protocol.toml --pool 2400

The edges only: reading options, opening the log and the server, workers, printing; the
study itself is :mod:`corrections_sim.userstudy.participant`, its analysis
:mod:`corrections_sim.userstudy.report` and :mod:`corrections_sim.userstudy.cohort`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from corrections_sim.cli.errors import UsageError

#: Where a study's log goes without --db, and a pilot's and a power analysis' folders.
STUDY_DB = Path("results") / "study" / "study.sqlite"
#: Study sizes a power analysis measures by default (multiples of 2 and 4 conditions' squares).
POWER_SIZES = (4, 8, 12, 16, 24, 32, 48)
#: Simulated participants a power analysis draws by default (200 studies of 12).
POWER_POOL = 2400
#: Seconds the study server checks for the end between (Ctrl-C stops it at once).
POLL = 0.5


def _protocol_path(args: argparse.Namespace) -> Path:
    if not args.study_file:
        raise UsageError(f"{args.figure}: give the protocol file, e.g. experiments/protocol.toml")
    path = Path(args.study_file)
    if not path.is_file():
        raise UsageError(f"{path}: no such protocol file")
    return path


def _open(args: argparse.Namespace, db: Path):
    from corrections_sim.session.log import LogError
    from corrections_sim.userstudy.cohort import open_run

    try:
        return open_run(_protocol_path(args), db)
    except (LogError, ValueError, OSError) as exc:
        raise UsageError(str(exc).splitlines()[0]) from None


def _codes(text: str | None) -> list[str]:
    from corrections_sim.session.log import check_participant

    codes = [c.strip() for c in (text or "").split(",") if c.strip()]
    try:
        return [check_participant(c) for c in codes]
    except ValueError as exc:
        raise UsageError(f"--enroll: {exc}") from None


def run_serve_study(args: argparse.Namespace) -> list[Path]:
    """Serve a protocol to several participants at once until Ctrl-C."""
    from corrections_sim.pages.server import AddressError, open_server, stop
    from corrections_sim.pages.study import StudyServer
    from corrections_sim.session.log import StudyError

    db = Path(args.db) if args.db else STUDY_DB
    codes = _codes(args.enroll)
    host = args.host or "127.0.0.1"
    run = _open(args, db)
    for code in codes:  # before the server: a used code writes nothing and serves nothing
        if run.log.participant(code) is not None:
            run.log.close()
            raise UsageError(
                f"--enroll {code}: already used in {db} (a returning participant resumes "
                "through their link; give a new code, or a new link from the experimenter's page)"
            )
    try:
        server = open_server(host, args.port or 8080)
    except AddressError as exc:
        run.log.close()
        raise UsageError(str(exc)) from None
    if host not in ("127.0.0.1", "localhost", "::1"):
        print(
            f"warning: serving on {host}: anyone who can reach it may open the page; each "
            "participant gets only their own link's page, the experimenter's needs its secret",
            file=sys.stderr,
        )
    try:
        study = StudyServer(server, run, host=host, speed=args.speed or 1.0)
        for code in codes:
            try:
                link = study.enroll(code)
            except StudyError as exc:
                raise UsageError(str(exc)) from None
            print(f"participant {code}: {link}", file=sys.stderr, flush=True)
        print(
            f"study {run.protocol.description or ''} ({db}): experimenter's page "
            f"{study.experimenter_link()} ; Ctrl-C stops the server (every step is logged)",
            file=sys.stderr,
            flush=True,
        )
        while True:
            time.sleep(POLL)
    finally:
        stop(server)
        run.log.close()


def run_study_status(args: argparse.Namespace) -> list[Path]:
    """Who is where in a study log (it may be served meanwhile)."""
    from corrections_sim.session.log import LogError, StudyLog
    from corrections_sim.userstudy.report import protocol_of

    db = Path(args.db) if args.db else STUDY_DB
    if not db.is_file():
        raise UsageError(f"--db {db}: no such study log")
    try:
        with StudyLog(db) as log:
            protocol = protocol_of(log)
            for person in log.participants():
                steps = protocol.steps(int(person["index"]))
                done = {r["position"] for r in log.steps(person["code"]) if r["finished"]}
                position = next((i for i in range(len(steps)) if i not in done), len(steps) - 1)
                state = " (withdrawn)" if person["withdrawn"] else ""
                kind = " simulated" if person["simulated"] else ""
                print(
                    f"{person['code']}{kind}: step {position + 1}/{len(steps)} "
                    f"{steps[position].key}{state}"
                )
    except (LogError, ValueError) as exc:
        raise UsageError(str(exc).splitlines()[0]) from None
    return []


def run_analyze(args: argparse.Namespace) -> list[Path]:
    """Tidy CSVs, the mixed model, paired comparisons, plots and a report of a study log."""
    from corrections_sim.session.log import LogError
    from corrections_sim.userstudy.report import analyze

    if not args.study_file:
        raise UsageError("analyze: give the study log, e.g. analyze results/study/study.sqlite")
    db = Path(args.study_file)
    out = Path(args.out) if args.out else db.parent / "analysis"
    try:
        return analyze(db, out)
    except (LogError, ValueError) as exc:
        raise UsageError(str(exc).splitlines()[0]) from None


def run_pilot(args: argparse.Namespace) -> list[Path]:
    """N simulated participants through the protocol into a log, then its analysis."""
    from corrections_sim.userstudy.cohort import simulate_cohort
    from corrections_sim.userstudy.report import analyze

    out = Path(args.out) if args.out else Path("results") / "pilot"
    db = Path(args.db) if args.db else out / "study.sqlite"
    count = args.participants or 12
    run = _open(args, db)
    try:
        if run.protocol.simulation is None:
            raise UsageError(f"{args.study_file}: no [simulation] table (the population)")
        started = time.perf_counter()

        def progress(done: int, total: int) -> None:
            print(f"pilot: {done}/{total} simulated participants", file=sys.stderr, flush=True)

        simulate_cohort(run, range(count), progress)
        print(f"pilot: {time.perf_counter() - started:.0f} s", file=sys.stderr)
    except ValueError as exc:
        raise UsageError(str(exc).splitlines()[0]) from None
    finally:
        run.log.close()
    return [db, *analyze(db, out / "analysis")]


def run_power(args: argparse.Namespace) -> list[Path]:
    """A pool of simulated participants (sharded over workers), cut into studies of each
    size; the power and the CIs' coverage at each."""
    from corrections_sim.cli.executors import process_pool
    from corrections_sim.userstudy.cohort import (
        load,
        pool_trials,
        power_markdown,
        power_table,
        shards,
        simulate_shard,
    )
    from corrections_sim.userstudy.protocol import OUTCOMES

    protocol_path = _protocol_path(args)
    out = Path(args.out) if args.out else Path("results") / "power"
    pool = args.pool or POWER_POOL
    sizes = tuple(args.sizes or POWER_SIZES)
    if any(n < 2 for n in sizes) or max(sizes) > pool:
        raise UsageError(f"--sizes: each in [2, --pool {pool}], got {list(sizes)}")
    try:
        protocol, _ = load(protocol_path)  # checked before any worker starts
    except ValueError as exc:
        raise UsageError(str(exc).splitlines()[0]) from None
    if protocol.simulation is None:
        raise UsageError(f"{protocol_path}: no [simulation] table (the population)")
    outcome = args.outcome or protocol.primary
    if outcome not in OUTCOMES:
        raise UsageError(f"--outcome {outcome}: expected one of {', '.join(OUTCOMES)}")
    folder = out / ".pool"
    parts = shards(folder, pool)
    started = time.perf_counter()
    with process_pool(args.workers or 2) as executor:
        futures = [
            executor.submit(simulate_shard, str(protocol_path), str(db), first, count)
            for db, first, count in parts
        ]
        for i, future in enumerate(futures):
            future.result()
            print(f"power: shard {i + 1}/{len(parts)}", file=sys.stderr, flush=True)
    simulated = time.perf_counter() - started
    trials = pool_trials([db for db, _, _ in parts], outcome)
    table = power_table(trials, list(protocol.names), sizes, outcome)
    # This command's share (a pool simulated before is only checked again).
    table["seconds_simulating_in_this_run"] = simulated
    out.mkdir(parents=True, exist_ok=True)
    (out / "power.json").write_text(json.dumps(table, indent=1, default=float) + "\n")
    (out / "power.md").write_text(power_markdown(table, protocol))
    png = out / "power.png"
    _plot_power(table, png, protocol.description)
    return [out / "power.json", out / "power.md", png]


def _plot_power(table: dict, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sizes = [s["participants"] for s in table["sizes"]]
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.4))
    power = [s["power"] for s in table["sizes"]]
    lo = [s["power"] - s["power_lo"] for s in table["sizes"]]
    hi = [s["power_hi"] - s["power"] for s in table["sizes"]]
    a.errorbar(sizes, power, yerr=[lo, hi], fmt="o-", capsize=4)
    a.axhline(0.8, color="0.5", ls="--", lw=1)
    if table["n_for_80"] is not None:
        a.axvline(table["n_for_80"], color="C3", ls=":", lw=1)
    a.set(xlabel="participants N", ylabel="power (p < 0.05)", ylim=(0, 1.02))
    a.set_title(f"power, d_z = {table['d_z']:.2f}")
    cov = [s["coverage"] for s in table["sizes"]]
    clo = [s["coverage"] - s["coverage_lo"] for s in table["sizes"]]
    chi = [s["coverage_hi"] - s["coverage"] for s in table["sizes"]]
    b.errorbar(sizes, cov, yerr=[clo, chi], fmt="o-", capsize=4, label="t (analyze)")
    b.plot(sizes, [s["coverage_z"] for s in table["sizes"]], "s--", label="Wald z")
    b.axhline(0.95, color="0.5", ls="--", lw=1)
    b.axhspan(0.93, 0.97, color="C2", alpha=0.12)
    low = min([*cov, *(s["coverage_z"] for s in table["sizes"]), 0.9])
    b.set(xlabel="participants N", ylabel="95% CI coverage", ylim=(max(0.0, low - 0.03), 1.0))
    b.legend(fontsize=8)
    fig.suptitle(f"{title} (simulated participants, {table['outcome']})", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

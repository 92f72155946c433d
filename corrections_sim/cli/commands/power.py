"""``power``: the power to detect a protocol's condition effect, from a pool of simulated
participants cut into studies of each size.

    python -m corrections_sim.run power experiments/protocol.toml --pool 2400
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from corrections_sim.cli.command import Command
from corrections_sim.cli.errors import UsageError
from corrections_sim.cli.study_files import protocol_path

#: Study sizes a power analysis measures by default (multiples of 2 and 4 conditions' squares).
POWER_SIZES = (4, 8, 12, 16, 24, 32, 48)
#: Simulated participants a power analysis draws by default (200 studies of 12).
POWER_POOL = 2400


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

    protocol_file = protocol_path(args)
    out = Path(args.out) if args.out else Path("results") / "power"
    pool = args.pool or POWER_POOL
    sizes = tuple(args.sizes or POWER_SIZES)
    if any(n < 2 for n in sizes) or max(sizes) > pool:
        raise UsageError(f"--sizes: each in [2, --pool {pool}], got {list(sizes)}")
    try:
        protocol, _ = load(protocol_file)  # checked before any worker starts
    except ValueError as exc:
        raise UsageError(str(exc).splitlines()[0]) from None
    if protocol.simulation is None:
        raise UsageError(f"{protocol_file}: no [simulation] table (the population)")
    outcome = args.outcome or protocol.primary
    if outcome not in OUTCOMES:
        raise UsageError(f"--outcome {outcome}: expected one of {', '.join(OUTCOMES)}")
    folder = out / ".pool"
    parts = shards(folder, pool)
    started = time.perf_counter()
    with process_pool(args.workers or 2) as executor:
        futures = [
            executor.submit(simulate_shard, str(protocol_file), str(db), first, count)
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
    # Low enough for every interval's lower end too (one cut off hid how little was known).
    low = min(
        [
            *cov,
            *(s["coverage_z"] for s in table["sizes"]),
            *(s["coverage_lo"] for s in table["sizes"]),
            0.9,
        ]
    )
    b.set(xlabel="participants N", ylabel="95% CI coverage", ylim=(max(0.0, low - 0.03), 1.0))
    b.legend(fontsize=8)
    fig.suptitle(f"{title} (simulated participants, {table['outcome']})", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


COMMAND = Command(
    name="power",
    run=run_power,
    help="the power to detect a protocol's condition effect, from simulated studies",
    options=("study_file", "out", "pool", "sizes", "outcome", "workers"),
    file="PROTOCOL",
    option_help={
        "study_file": "the protocol (TOML) with its [simulation] population",
        "out": "the power analysis' folder (default results/power; the pool's logs in "
        "OUT/.pool, resumable)",
        "workers": "worker processes simulating the pool (default 2)",
    },
    nothing_kept=lambda args: (
        "power stopped; the pool's participants simulated so far are kept in OUT/.pool "
        "(run it again to go on from them)"
    ),
)

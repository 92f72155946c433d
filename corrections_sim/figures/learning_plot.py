"""The plots of a learning study: :func:`plot_learning_curves`, the curves of a few learners
(figs. 4 and 5, ``run study``), and :func:`plot_every_learner`, every registered learner in
panels by family (``run learners``). Plots only: the numbers come in as arrays.

The recommended robot (:data:`corrections_sim.defaults.RECOMMENDED`) is drawn thicker and on
top wherever it appears, and its legend entry says it is the one we recommend.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from corrections_sim.defaults import RECOMMENDED

#: The panels of a learning figure: (key in the curves, title, y label).
PANELS = (
    ("estimate_error", "Estimate error ‖θ̂ − θ*‖₁", "error (L1, weight units)"),
    ("regret", "Regret (full objective), Σ over {n} envs", "regret (reward units)"),
    ("regret_paper", "Regret θ*·Φ only (paper's), Σ over {n} envs", "regret (reward units)"),
)
CALIBRATION_TITLE = "Calibration: mean NEES (θ̂−θ*)ᵀP⁻¹(θ̂−θ*)"
#: What the calibration panel's reader needs in words, under its title.
CALIBRATION_WORDS = (
    "in the grey band: calibrated\nabove it: over-confident; below it: under-confident"
)

#: Panels of ``run learners``: the learners' families, by the package they live in (an active
#: learner is in "Active learning" whatever its package; a plug-in in "Plug-ins").
FAMILIES = {
    "perceptron": "Perceptrons and BP",
    "boltzmann": "Perceptrons and BP",
    "kalman": "Kalman filters",
    "particles": "Particles and relevance",
    "relevance": "Particles and relevance",
    "exact": "Exact posteriors",
}
FAMILY_ORDER = (
    "Perceptrons and BP",
    "Kalman filters",
    "Active learning",
    "Particles and relevance",
    "Exact posteriors",
    "Plug-ins",
)


def family(name: str) -> str:
    """The panel of ``run learners`` a registered learner is drawn in."""
    from corrections_sim.learning.base import LEARNERS

    cls = LEARNERS[name]
    if cls.active:
        return "Active learning"
    parts = cls.__module__.split(".")
    if parts[:2] != ["corrections_sim", "learning"] or len(parts) < 3:
        return "Plug-ins"
    return FAMILIES.get(parts[2], "Plug-ins")


def _label(name: str, runs: int, *, short: bool = False) -> str:
    """A learner's legend entry: its label (``short``: its registered name) and runs."""
    from corrections_sim.figures.style import learner_label

    label = f"{name if short else learner_label(name)}, N = {runs}"
    if name == RECOMMENDED:
        return f"{label} (recommended)" if short else f"{label} — the robot we recommend"
    return label


def _draw(ax, name: str, values: np.ndarray, *, label: str | None, band: bool = True) -> None:
    """One learner's mean curve (± SEM over runs, if more than one) in its style; the
    recommended robot thicker and on top."""
    from corrections_sim.figures.style import learner_style
    from corrections_sim.metrics import mean_sem

    colour, style = learner_style(name)
    mean, sem = mean_sem(values)
    t = np.arange(mean.size)
    ours = name == RECOMMENDED
    ax.plot(
        t, mean, color=colour, ls=style, lw=3.2 if ours else 2, zorder=5 if ours else 3, label=label
    )
    if band and values.shape[0] > 1:
        ax.fill_between(t, mean - sem, mean + sem, color=colour, alpha=0.2, lw=0, zorder=2)


def _calibration(ax, curves: Mapping, bands: Mapping, learners: Sequence[str]) -> None:
    """Mean NEES of ``learners`` with a covariance on a log scale, the 95% band of a
    calibrated mean for each number of runs shaded, and what the band means in words."""
    from corrections_sim.figures.style import learner_style

    shown = set()
    for name, band in sorted(bands.items(), key=lambda kv: kv[1][1] - kv[1][0]):
        if name not in learners or tuple(band) in shown:
            continue
        n = curves[name]["nees"].shape[0]
        single = n == 1
        ax.axhspan(
            *band,
            facecolor="none" if single else "0.85",
            hatch="///" if single else None,
            edgecolor="0.7",
            lw=0,
            label=f"95% band of a calibrated mean of {n} run{'s' if n > 1 else ''}",
        )
        shown.add(tuple(band))
    for name in learners:
        if name not in bands:
            continue
        colour, style = learner_style(name)
        mean = np.nanmean(curves[name]["nees"], axis=0)
        ours = name == RECOMMENDED
        ax.plot(
            np.arange(mean.size),
            mean,
            color=colour,
            ls=style,
            lw=3.2 if ours else 2,
            zorder=5 if ours else 3,
        )
    if shown:
        ax.set_yscale("log")
    without = [n for n in learners if n not in bands]
    first, rest = CALIBRATION_WORDS.split("\n", 1)
    if without:
        first += f" ({', '.join(without)}: no covariance)"
    ax.set_title(f"{CALIBRATION_TITLE}\n{first}\n{rest}", fontsize=9)
    ax.set_ylabel("mean NEES (log scale)")


def _order(names: Sequence[str]) -> list[str]:
    """The recommended robot last, so that it is drawn on top and closes the legend."""
    return [n for n in names if n != RECOMMENDED] + [n for n in names if n == RECOMMENDED]


def plot_learning_curves(
    curves: dict[str, dict[str, np.ndarray]],
    title: str,
    paths,
    bands: dict[str, tuple[float, float]] | None = None,
    n_environments: int = 48,
) -> None:
    """Estimate error, regret (full and the paper's) and calibration against iteration.

    Bands are ± SEM over runs (none for a single run). The calibration panel shows the mean
    NEES of every learner with a covariance on a log scale, with the 95% χ² band of a
    calibrated mean for that learner's number of runs shaded (light grey: the most runs;
    hatched: a single run), and says in words what is good.

    Args:
        curves: learner -> {"estimate_error", "regret", "regret_paper", "nees"}: each
            (runs, T+1).
        paths: files to write (PNG, PDF, …).
        bands: learner -> (low, high) band of its mean NEES; learners without one have no
            covariance and are left out of the calibration panel.
    """
    from corrections_sim.figures.style import plt, save_and_close

    bands = bands or {}
    names = _order(list(curves))
    # The learners' legend gets a row of its own under the panels: inside a panel, many
    # learners covered the curves they name.
    ncol = min(len(names), 3) if len(names) <= 6 else min(len(names), 5)
    legend_rows = -(-len(names) // ncol) if names else 0
    fig = plt.figure(figsize=(17, 4.6 + 0.26 * legend_rows))
    grid = fig.add_gridspec(2, 4, height_ratios=(4.6, max(0.26 * legend_rows, 0.01)))
    axes = [fig.add_subplot(grid[0, j]) for j in range(4)]
    box = fig.add_subplot(grid[1, :])
    box.set_axis_off()
    for ax, (key, label, ylabel) in zip(axes, PANELS, strict=False):
        for name in names:
            values = curves[name][key]
            _draw(ax, name, values, label=_label(name, values.shape[0]))
        ax.set_title(label.format(n=n_environments), fontsize=10)
        ax.set_ylabel(ylabel)
    _calibration(axes[3], curves, bands, names)
    for ax in axes:
        ax.set_xlabel("iteration (corrections)")
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.grid(alpha=0.3)
    if names:
        handles, labels = axes[0].get_legend_handles_labels()
        more = axes[3].get_legend_handles_labels()  # the calibration panel's bands
        box.legend(
            handles + more[0],
            labels + more[1],
            loc="center",
            ncol=ncol,
            fontsize=9 if len(names) <= 6 else 8,
            frameon=False,
        )
    fig.suptitle(title + "; bands: ± SEM over runs", fontsize=11)
    save_and_close(fig, paths, dpi=150)


def plot_every_learner(
    curves: dict[str, dict[str, np.ndarray]],
    title: str,
    paths,
    bands: dict[str, tuple[float, float]] | None = None,
    n_environments: int = 48,
) -> None:
    """Every learner of ``curves`` in panels by family (columns, :func:`family`): estimate
    error, regret (full objective) and calibration (rows), each family's learners in their
    own styles and the recommended robot in every column for comparison; a legend under each
    column.

    Args: as :func:`plot_learning_curves`'s.
    """
    from corrections_sim.figures.style import plt, save_and_close

    bands = bands or {}
    groups: dict[str, list[str]] = {}
    for name in curves:
        groups.setdefault(family(name), []).append(name)
    columns = [f for f in FAMILY_ORDER if f in groups]
    ours = RECOMMENDED in curves
    most = max(
        (len(groups[f]) + (ours and RECOMMENDED not in groups[f]) for f in columns), default=1
    )
    fig = plt.figure(figsize=(4.2 * max(len(columns), 1), 11.2 + 0.24 * most))
    grid = fig.add_gridspec(
        4, max(len(columns), 1), height_ratios=(3.4, 3.4, 3.4, 0.24 * most + 0.1)
    )
    rows = (PANELS[0], PANELS[1], ("nees", CALIBRATION_TITLE, "mean NEES"))
    shared = [None, None, None]
    bands_shown: tuple[list, list] = ([], [])
    legends = []
    for j, column in enumerate(columns):
        names = groups[column]
        drawn = _order(names + ([RECOMMENDED] if ours and RECOMMENDED not in names else []))
        handles = None
        for i, (key, label, ylabel) in enumerate(rows):
            ax = fig.add_subplot(grid[i, j], sharey=shared[i])
            shared[i] = shared[i] or ax
            if key == "nees":
                _calibration(ax, curves, bands, drawn)
                without = [n for n in drawn if n not in bands]
                more = f"\nno covariance: {', '.join(without)}" if without else ""
                ax.set_title(f"Calibration: mean NEES{more}", fontsize=10)
                for handle, text in zip(*ax.get_legend_handles_labels(), strict=True):
                    if text not in bands_shown[1]:  # each number of runs' band, once
                        bands_shown[0].append(handle)
                        bands_shown[1].append(text)
            else:
                for name in drawn:
                    values = curves[name][key]
                    _draw(ax, name, values, label=_label(name, values.shape[0], short=True))
                ax.set_title(label.format(n=n_environments), fontsize=10)
            if i == 0:
                ax.set_title(f"{column}\n{ax.get_title()}", fontsize=11)
                handles = ax.get_legend_handles_labels()
            ax.set_ylabel(ylabel if j == 0 else "")
            ax.set_xlabel("iteration (corrections)")
            ax.xaxis.get_major_locator().set_params(integer=True)
            ax.grid(alpha=0.3)
        box = fig.add_subplot(grid[3, j])
        box.set_axis_off()
        legends.append((box, handles))
    for j, (box, handles) in enumerate(legends):
        if handles is None:
            continue
        if j == 0:  # the calibrated bands, under the first column's learners
            handles = (handles[0] + bands_shown[0], handles[1] + bands_shown[1])
        box.legend(*handles, loc="upper center", ncol=1, fontsize=8, frameon=False)
    fig.suptitle(
        f"{title}; bands: ± SEM over runs\ncalibration (log scale): "
        + CALIBRATION_WORDS.replace("\n", "; "),
        fontsize=12,
    )
    save_and_close(fig, paths, dpi=110)

"""Figures with matplotlib (headless, Agg). Only the edges of the program import this."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402


def save_atomically(fig: plt.Figure, path: Path, **kwargs) -> Path:
    """Save ``fig`` to ``path`` through a temporary file, so a crash leaves no half file."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    fig.savefig(tmp, **kwargs)
    os.replace(tmp, path)
    return path


def save_scene_figure(
    path: Path,
    image: np.ndarray,
    title: str,
    legend: Sequence[tuple[tuple[float, float, float, float], str]],
) -> Path:
    """A render (H, W, 3) with a title and a legend of coloured paths, as a PNG."""
    h, w = image.shape[:2]
    fig, ax = plt.subplots(figsize=(w / 100, h / 100 + 0.9), dpi=100)
    ax.imshow(image)
    ax.set_axis_off()
    ax.set_title(title, fontsize=11)
    handles = [Line2D([0], [0], color=rgba[:3], lw=3, label=label) for rgba, label in legend]
    ax.legend(
        handles=handles, loc="lower center", bbox_to_anchor=(0.5, -0.1), fontsize=9, frameon=False
    )
    fig.tight_layout()
    try:
        return save_atomically(fig, path, dpi=100)
    finally:
        plt.close(fig)


LEARNER_STYLE = {
    "PP": ("#7f7f7f", "Preference Perceptron (PP)"),
    "KF": ("#1f77b4", "Kalman filter (KF)"),
    "EKF": ("#2ca02c", "Extended Kalman filter (EKF)"),
    "AL": ("#d62728", "Active learning (AL)"),
}


def mean_sem(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard error over axis 0 (runs); SEM is 0 for a single run."""
    mean = np.nanmean(values, axis=0)
    if values.shape[0] < 2:
        return mean, np.zeros_like(mean)
    n = np.sum(np.isfinite(values), axis=0)
    return mean, np.nanstd(values, axis=0, ddof=1) / np.sqrt(np.maximum(n, 1))


def plot_learning_curves(curves: dict[str, dict[str, np.ndarray]], title: str, paths) -> None:
    """Estimate error and regret against iteration, mean ± SEM as shaded bands.

    Args:
        curves: learner -> {"estimate_error": (runs, T+1), "regret": (runs, T+1),
            "regret_paper": (runs, T+1)}.
        paths: files to write (PNG, PDF, …).
    """
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    panels = (
        ("estimate_error", "Estimate error ‖θ̂ − θ*‖₁"),
        ("regret", "Regret (full objective), Σ over 48 envs"),
        ("regret_paper", "Regret θ*·Φ only (paper), Σ over 48 envs"),
    )
    for ax, (key, label) in zip(axes, panels, strict=True):
        for learner, data in curves.items():
            color, name = LEARNER_STYLE[learner]
            values = data[key]
            mean, sem = mean_sem(values)
            t = np.arange(mean.size)
            n = values.shape[0]
            ax.plot(t, mean, color=color, lw=2, label=f"{name}, N = {n}")
            ax.fill_between(t, mean - sem, mean + sem, color=color, alpha=0.25, lw=0)
        ax.set_xlabel("iteration (corrections)")
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    try:
        for path in paths:
            save_atomically(fig, path, dpi=150)
    finally:
        plt.close(fig)

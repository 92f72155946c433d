"""Tidy CSV files of figs. 1–3: floats written exactly (``repr``), atomically.

Same records, same bytes: nothing here depends on time, the machine or the worker count.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from corrections_sim.scene.robot import cup_pose


def write_csv(path: Path, rows: Sequence[dict]) -> Path:
    """Write ``rows`` (dicts with the same keys, in order) to ``path`` through a temp file.

    Floats are written with ``repr`` (round-trip exact; NaN as ``nan``).

    Raises:
        ValueError: no rows, or rows with different keys.
    """
    if not rows:
        raise ValueError(f"{Path(path).name}: no rows to write")
    fields = list(rows[0])
    for i, row in enumerate(rows):
        if list(row) != fields:
            raise ValueError(f"{Path(path).name}: row {i} has keys {list(row)}, not {fields}")
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields, lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _cell(v) for k, v in row.items()})
    os.replace(tmp, path)
    return path


def write_records(path: Path, rows: Sequence[dict]) -> Path:
    """Write the tidy records of a learning study (figs. 4–6, study files) to ``path``.

    The committed curves were written this way (``csv`` module defaults: CRLF line ends;
    floats with ``repr``, None as an empty cell), so the same records give the same bytes.
    """
    # Columns in order of first appearance: a learner that records more (noise_ij of one that
    # learns N) adds columns, empty for the others.
    fieldnames = list(dict.fromkeys(key for row in rows for key in row))
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fieldnames)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in row.items()})
    return Path(path)


def _cell(value):
    if isinstance(value, float | np.floating):
        return repr(float(value))
    if isinstance(value, np.integer):
        return int(value)
    return value


def trajectory_rows(waypoints: np.ndarray, /, **columns) -> list[dict]:
    """One row per waypoint of a trajectory (T, 7): the given columns, the waypoint index,
    the joint angles q_0 … q_6 (rad) and the cup centre (m)."""
    rows = []
    for i, q in enumerate(np.asarray(waypoints, float)):
        cup = cup_pose(q)[1]
        rows.append(
            {
                **columns,
                "waypoint": i,
                **{f"q_{j}": float(v) for j, v in enumerate(q)},
                "cup_x": float(cup[0]),
                "cup_y": float(cup[1]),
                "cup_z": float(cup[2]),
            }
        )
    return rows


def path_rows(paths, features: Sequence[str]) -> list[dict]:
    """Waypoint rows of figs. 1–2's drawn paths (see ``selection.DrawnPath``)."""
    rows = []
    for p in paths:
        columns = {"label": p.label, "map": p.map}
        columns.update({f"theta_{n}": float(v) for n, v in zip(features, p.theta, strict=True)})
        columns.update({f"phi_{n}": float(v) for n, v in zip(features, p.features, strict=True)})
        rows += trajectory_rows(p.trajectory, **columns)
    return rows

r"""Figs. 1 and 2: where the robot learns most — heat maps of the predicted ‖Pᵗ⁺¹‖_F, eq. (A1).

For a grid of environments E (the laptop moved, or the cup's start moved, in the figure's
fixed scene) the UKF predicts the covariance after one correction in E, before the human
acts (:func:`corrections_sim.learning.ukf_predicted_covariance`): h(θ) = Φ(ξ*(θ, E), E) is
evaluated at the 2k + 1 sigma points of N(θ̂, P + M), and

    Pᵗ⁺¹(E) = P⁻ − K S Kᵀ,   ‖Pᵗ⁺¹(E)‖_F ≤ ‖P + M‖_F   ("no information" when h is flat).

The robot's current trajectory in E is ξ*(θ̂, E), the UKF's first sigma point. A grid cell
whose start the arm cannot reach (no IK), whose start collides, or whose 2k + 1 plans do not
all converge is kept in the data with its status and a NaN value, and drawn as missing.

* Fig. 1 (one feature, the laptop): one map over laptop positions (the table follows the
  laptop only as far as it must to hold it), one over cup start positions with the laptop
  fixed; the scene rendered with the paths of three candidate preferences.
* Fig. 2 (laptop and table): maps over start positions for two covariances P (equal, and
  more uncertain about the table); the scene rendered with the paths from each map's best
  start.

Settings are data (``experiments/fig1.toml``, ``fig2.toml``, each a ``paper`` and a
``quick`` preset). :func:`run` spreads the grid over any ``concurrent.futures`` executor;
the records do not depend on the executor or the number of workers.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from corrections_sim.figures import presets
from corrections_sim.figures.presets import PresetFigure, Scene
from corrections_sim.figures.registry import register
from corrections_sim.learning import (
    Belief,
    KalmanNoise,
    SigmaPoints,
    frobenius,
    ukf_predicted_covariance,
)
from corrections_sim.planning.planner import PlannerConfig, PlanningError, shared_planner
from corrections_sim.scene.environments import CUP_WORKSPACE, Environment, laptop_range
from corrections_sim.scene.world import check_configuration
from corrections_sim.study import checks, files
from corrections_sim.study.loop import PlanBook

FIGURES = ("fig1", "fig2")
VARY = ("laptop", "start")
#: Status of a grid cell; anything but "ok" has a NaN value.
STATUSES = ("ok", "unreachable", "start_collides", "plan_failed")
#: Views of the scene render (``render.TOP_CAMERA``, ``render.SIDE_CAMERA``).
CAMERAS = ("top", "side")
_MAX_CELLS_PER_AXIS = 80


@dataclass(frozen=True)
class Grid:
    """A rectangular grid of points in the horizontal plane, cell centres on the bounds.

    Attributes:
        vary: what moves: "laptop" (its centre; yaw and the rest of the scene fixed) or
            "start" (the cup's start position at height ``z``).
        x: (lo, hi) of world x, m.
        y: (lo, hi) of world y, m.
        nx: number of points along x (>= 2).
        ny: number of points along y (>= 2).
        z: cup height of a start grid, m (None for a laptop grid).
    """

    vary: str
    x: tuple[float, float]
    y: tuple[float, float]
    nx: int
    ny: int
    z: float | None = None

    @property
    def xs(self) -> np.ndarray:
        return np.linspace(*self.x, self.nx)

    @property
    def ys(self) -> np.ndarray:
        return np.linspace(*self.y, self.ny)


@dataclass(frozen=True)
class HeatMap:
    """One heat map: a grid and the covariance Pᵗ the prediction starts from.

    Attributes:
        name: short label (CSV ``map`` column, file-safe).
        title: panel title.
        grid: the environments.
        cov: Pᵗ, k × k, symmetric positive definite.
    """

    name: str
    title: str
    grid: Grid
    cov: tuple[tuple[float, ...], ...]


@dataclass(frozen=True)
class SelectionSettings:
    """Resolved settings of fig. 1 or fig. 2.

    Attributes:
        figure: "fig1" or "fig2".
        features: the planner's features (k of them).
        theta: θ̂, the robot's current estimate (k,).
        scene: the fixed scene every grid varies one thing of.
        maps: the heat maps, in panel order.
        candidates: preferences whose optimal paths in the fixed scene the scene render
            shows (fig. 1); if empty, the render shows the path from each start map's best
            start (fig. 2).
        process_noise: M = process_noise · I.
        observation_noise: N = observation_noise · I.
        sigma_alpha, sigma_beta, sigma_kappa: the UKF's sigma points.
        n_starts: the planner's initial guesses per solve.
        camera: view of the scene render, one of :data:`CAMERAS` ("top": where the cup
            passes in the plane; "side": how high it passes over the table).
    """

    figure: str
    features: tuple[str, ...]
    theta: tuple[float, ...]
    scene: Scene
    maps: tuple[HeatMap, ...]
    candidates: tuple[tuple[float, ...], ...]
    process_noise: float = 1e-4
    observation_noise: float = 0.25
    sigma_alpha: float = 1.0
    sigma_beta: float = 2.0
    sigma_kappa: float = 0.0
    n_starts: int = 1
    camera: str = "top"

    @property
    def k(self) -> int:
        return len(self.features)

    def planner_config(self) -> PlannerConfig:
        return PlannerConfig(features=self.features, n_starts=self.n_starts)

    def noise(self) -> KalmanNoise:
        return KalmanNoise.isotropic(self.k, self.process_noise, self.observation_noise)

    def sigma(self) -> SigmaPoints:
        return SigmaPoints(alpha=self.sigma_alpha, beta=self.sigma_beta, kappa=self.sigma_kappa)

    def belief(self, index: int) -> Belief:
        """N(θ̂, Pᵗ) of map ``index``."""
        return Belief(theta=np.array(self.theta), cov=np.array(self.maps[index].cov))

    def no_information(self, index: int) -> float:
        """‖Pᵗ + M‖_F: the prediction of map ``index`` where a correction teaches nothing."""
        return frobenius(np.array(self.maps[index].cov) + self.noise().process)


def _grid(prefix: str, values: dict, laptop_yaw: float) -> Grid:
    vary = checks.take(values, "vary", prefix)
    if vary not in VARY:
        raise ValueError(f"{prefix}vary = {vary!r}: choose one of {', '.join(VARY)}")
    if vary == "laptop":
        (x_lo, x_hi), (y_lo, y_hi) = laptop_range(laptop_yaw)
        z = None
    else:
        (x_lo, x_hi), (y_lo, y_hi), (z_lo, z_hi) = CUP_WORKSPACE
        z = checks.number(f"{prefix}z", checks.take(values, "z", prefix), low=z_lo, high=z_hi)
    grid = Grid(
        vary=vary,
        x=checks.bounds(f"{prefix}x", checks.take(values, "x", prefix), x_lo, x_hi),
        y=checks.bounds(f"{prefix}y", checks.take(values, "y", prefix), y_lo, y_hi),
        nx=checks.integer(
            f"{prefix}nx", checks.take(values, "nx", prefix), low=2, high=_MAX_CELLS_PER_AXIS
        ),
        ny=checks.integer(
            f"{prefix}ny", checks.take(values, "ny", prefix), low=2, high=_MAX_CELLS_PER_AXIS
        ),
        z=z,
    )
    return grid


def load_settings(figure: str, *, quick: bool, overrides: dict | None = None) -> SelectionSettings:
    """Settings of ``figure`` from ``experiments/<figure>.toml``, checked field by field.

    Args:
        figure: "fig1" or "fig2".
        quick: the CI-sized preset instead of the paper-scale one.
        overrides: top-level fields to replace (None values are ignored). The figures draw
            no random numbers, so there is no ``seed``.

    Raises:
        ValueError: unknown figure, missing or unknown key, or a bad value; the one-line
            message names the field (e.g. ``maps[1].cov``, ``maps[0].x``).
    """
    values, features, theta = files.load_values(
        presets.EXPERIMENTS_DIR, figure, FIGURES, quick, overrides, "maps"
    )
    k = len(features)
    scene = Scene.parse(values)
    maps = []
    raw_maps = checks.take(values, "maps")
    if not isinstance(raw_maps, list) or not raw_maps:
        raise ValueError("maps: expected at least one [[maps]] table")
    for i, raw in enumerate(raw_maps):
        prefix = f"maps[{i}]."
        raw = dict(raw)
        name = str(checks.take(raw, "name", prefix))
        if not name.isidentifier():
            raise ValueError(f"{prefix}name = {name!r}: expected a short identifier")
        title = str(checks.take(raw, "title", prefix))
        cov = checks.covariance(f"{prefix}cov", checks.take(raw, "cov", prefix), k)
        grid = _grid(prefix, raw, scene.laptop[2])
        checks.reject_unknown(raw, f"maps[{i}]")
        maps.append(HeatMap(name=name, title=title, grid=grid, cov=cov))
    if len({m.name for m in maps}) != len(maps):
        raise ValueError(f"maps: names must be distinct, got {[m.name for m in maps]}")
    candidates = tuple(
        checks.vector(f"candidates[{i}]", c, k) for i, c in enumerate(values.pop("candidates", []))
    )
    optional = {}
    for name, low in (("process_noise", 0.0), ("observation_noise", 1e-12)):
        if name in values:
            optional[name] = checks.number(name, values.pop(name), low=low)
    for name in ("sigma_alpha", "sigma_beta", "sigma_kappa"):
        if name in values:
            optional[name] = checks.number(name, values.pop(name))
    if "n_starts" in values:
        optional["n_starts"] = checks.integer("n_starts", values.pop("n_starts"), low=1, high=3)
    if "camera" in values:
        camera = values.pop("camera")
        if camera not in CAMERAS:
            raise ValueError(f"camera = {camera!r}: choose one of {', '.join(CAMERAS)}")
        optional["camera"] = camera
    checks.reject_unknown(values)
    settings = SelectionSettings(
        figure=figure,
        features=features,
        theta=theta,
        scene=scene,
        maps=tuple(maps),
        candidates=candidates,
        **optional,
    )
    settings.sigma()  # SigmaPoints checks its own parameters, by name
    return settings


# --- computation -----------------------------------------------------------------------------


def cell_environment(settings: SelectionSettings, index: int, x: float, y: float) -> Environment:
    """The environment of grid point (x, y) of map ``index``.

    Raises:
        ValueError: the start is unreachable (a start grid's IK failed).
    """
    grid = settings.maps[index].grid
    name = f"{settings.maps[index].name}-{x:.3f}-{y:.3f}"
    if grid.vary == "laptop":
        laptop = (float(x), float(y), settings.scene.laptop[2])
        return settings.scene.environment(laptop=laptop, name=name)
    return settings.scene.environment(start=(float(x), float(y), grid.z), name=name)


def _cell(settings: SelectionSettings, index: int, ix: int, iy: int) -> dict:
    """Predicted ‖Pᵗ⁺¹‖_F of one grid point, with the features of ξ*(θ̂, E)."""
    hmap = settings.maps[index]
    x, y = float(hmap.grid.xs[ix]), float(hmap.grid.ys[iy])
    k = settings.k
    row = {"map": hmap.name, "ix": ix, "iy": iy, "x": x, "y": y, "status": "ok"}
    nan = float("nan")
    values = {"frobenius": nan}
    values.update({f"cov_{i}{j}": nan for i in range(k) for j in range(i, k)})
    values.update({f"phi_{name}": nan for name in settings.features})
    try:
        env = cell_environment(settings, index, x, y)
    except ValueError:
        row["status"] = "unreachable"
        return {**row, **values}
    if not check_configuration(env.q_start, env).collision_free:
        row["status"] = "start_collides"
        return {**row, **values}
    book = PlanBook(shared_planner(settings.planner_config()))
    belief = settings.belief(index)
    try:
        cov = ukf_predicted_covariance(
            belief, book.observe(env), settings.noise(), settings.sigma()
        )
        phi = book.plan(belief.theta, env).features
    except PlanningError:
        row["status"] = "plan_failed"
        return {**row, **values}
    values["frobenius"] = frobenius(cov)
    values.update({f"cov_{i}{j}": float(cov[i, j]) for i in range(k) for j in range(i, k)})
    values.update({f"phi_{n}": float(v) for n, v in zip(settings.features, phi, strict=True)})
    return {**row, **values}


def grid_column(settings: SelectionSettings, index: int, ix: int) -> list[dict]:
    """All cells of map ``index`` at x index ``ix`` (one task for a worker process)."""
    return [_cell(settings, index, ix, iy) for iy in range(settings.maps[index].grid.ny)]


@dataclass(frozen=True, eq=False)
class DrawnPath:
    """A trajectory the figure draws.

    Attributes:
        label: what it is ("candidate", "current", "best start").
        map: the map it belongs to ("" for the scene render's candidates).
        theta: the preference it is optimal for (k,).
        environment: where it was planned.
        trajectory: waypoints (T, 7).
        features: Φ(ξ, E) (k,).
    """

    label: str
    map: str
    theta: tuple[float, ...]
    environment: Environment
    trajectory: np.ndarray
    features: np.ndarray


def plan_path(
    settings: SelectionSettings, label: str, map_name: str, theta, env: Environment
) -> DrawnPath | None:
    """ξ*(θ, E) as a :class:`DrawnPath`, or None if the planner fails (a worker task)."""
    try:
        plan = shared_planner(settings.planner_config()).solve(np.array(theta), env)
    except PlanningError:
        return None
    return DrawnPath(label, map_name, tuple(theta), env, plan.trajectory, plan.features)


@dataclass(frozen=True, eq=False)
class SelectionResult:
    """Everything fig. 1 or 2 shows.

    Attributes:
        cells: one record per grid point of every map, sorted by (map order, ix, iy): map,
            ix, iy, x, y, status, frobenius (NaN unless status is "ok"), the upper triangle
            of Pᵗ⁺¹ (cov_ij), and the features of ξ*(θ̂, E) (phi_<name>).
        maps: one record per map: name, the entries of Pᵗ, no_information = ‖Pᵗ + M‖_F,
            counts of each status, and the best cell (argmin of frobenius; NaN if none).
        paths: the trajectories drawn (see :class:`DrawnPath`); a failed plan is left out.
    """

    cells: tuple[dict, ...]
    maps: tuple[dict, ...]
    paths: tuple[DrawnPath, ...]


def best_cell(cells: list[dict]) -> dict | None:
    """The cell with the smallest predicted ‖Pᵗ⁺¹‖_F (first in grid order on ties)."""
    ok = [c for c in cells if c["status"] == "ok"]
    return min(ok, key=lambda c: c["frobenius"]) if ok else None


def _map_record(settings: SelectionSettings, index: int, cells: list[dict]) -> dict:
    hmap = settings.maps[index]
    k = settings.k
    rec: dict = {"map": hmap.name, "vary": hmap.grid.vary}
    rec.update({f"P_{i}{j}": hmap.cov[i][j] for i in range(k) for j in range(i, k)})
    rec["no_information"] = settings.no_information(index)
    for status in STATUSES:
        rec[f"cells_{status}"] = sum(c["status"] == status for c in cells)
    best = best_cell(cells)
    rec["best_x"] = best["x"] if best else float("nan")
    rec["best_y"] = best["y"] if best else float("nan")
    rec["best_frobenius"] = best["frobenius"] if best else float("nan")
    for name in settings.features:
        rec[f"best_phi_{name}"] = best[f"phi_{name}"] if best else float("nan")
    return rec


def run(
    settings: SelectionSettings,
    executor: Executor,
    progress: Callable[[int, int], None] | None = None,
) -> SelectionResult:
    """Every heat map of the figure, then the paths it draws, on ``executor``.

    Args:
        settings: from :func:`load_settings`.
        executor: any ``concurrent.futures`` executor (tasks are module-level functions of
            picklable arguments: one grid column each, then one path each).
        progress: called with (tasks done, tasks in all) as tasks finish, in order.

    Returns:
        The records; identical for any executor and number of workers.
    """
    columns = [(m, ix) for m, hmap in enumerate(settings.maps) for ix in range(hmap.grid.nx)]
    jobs = {}  # (kind, key) -> future, in submission order
    for m, ix in columns:
        jobs[("column", (m, ix))] = executor.submit(grid_column, settings, m, ix)
    scene_env = settings.scene.environment(name="scene")
    for i, theta in enumerate(settings.candidates):
        key = ("path", ("candidate", "", i))
        jobs[key] = executor.submit(plan_path, settings, "candidate", "", theta, scene_env)
    total = len(jobs) + sum(1 for m in settings.maps)
    done = 0

    def tick() -> None:
        nonlocal done
        done += 1
        if progress:
            progress(done, total)

    by_map: dict[int, list[dict]] = {m: [] for m in range(len(settings.maps))}
    paths: list[DrawnPath] = []
    for (kind, key), fut in jobs.items():
        result = fut.result()
        if kind == "column":
            by_map[key[0]].extend(result)
        elif result is not None:
            paths.append(result)
        tick()
    # Each map's overlay: the current trajectory in the fixed scene (a laptop map) or from
    # the best start (a start map).
    overlays = []
    for m, hmap in enumerate(settings.maps):
        best = best_cell(by_map[m])
        if hmap.grid.vary == "laptop":
            env, label = scene_env, "current"
        elif best is not None:
            env, label = cell_environment(settings, m, best["x"], best["y"]), "best start"
        else:
            overlays.append(None)
            continue
        overlays.append(executor.submit(plan_path, settings, label, hmap.name, settings.theta, env))
    for fut in overlays:
        if fut is not None and (path := fut.result()) is not None:
            paths.append(path)
        tick()
    cells = tuple(c for m in range(len(settings.maps)) for c in by_map[m])
    maps = tuple(_map_record(settings, m, by_map[m]) for m in range(len(settings.maps)))
    return SelectionResult(cells=cells, maps=maps, paths=tuple(paths))


# --- output ----------------------------------------------------------------------------------


def write(settings: SelectionSettings, result: SelectionResult, folder: Path) -> list[Path]:
    """Write the figure and its data into ``folder``.

    Files: ``cells.csv`` (one row per grid point), ``maps.csv`` (one row per heat map),
    ``paths.csv`` (waypoints of the drawn trajectories), ``<figure>.png`` and ``.pdf``
    (scene render and heat maps).

    Returns:
        The paths written, in that order.
    """
    from corrections_sim.figures.output import path_rows, write_csv
    from corrections_sim.figures.selection_plot import plot_selection_figure
    from corrections_sim.scene import render

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = [
        write_csv(folder / "cells.csv", list(result.cells)),
        write_csv(folder / "maps.csv", list(result.maps)),
        write_csv(folder / "paths.csv", path_rows(result.paths, settings.features)),
    ]
    scene_paths = [p for p in result.paths if p.label == "candidate"]
    if not scene_paths:
        scene_paths = [p for p in result.paths if p.label == "best start"]
    colors = _path_colors(len(scene_paths))
    env = scene_paths[0].environment if scene_paths else settings.scene.environment()
    image = render.render_scene(
        env,
        [(render.cup_path(p.trajectory), c) for p, c in zip(scene_paths, colors, strict=True)],
        width=800,
        height=600,
        camera=render.TOP_CAMERA if settings.camera == "top" else render.SIDE_CAMERA,
    )
    legend = []
    titles = {m.name: m.title for m in settings.maps}
    for p, c in zip(scene_paths, colors, strict=True):
        counts = ", ".join(
            f"{n} {v:.2f}" for n, v in zip(settings.features, p.features, strict=True)
        )
        what = f"θ = {_fmt(p.theta)}" if p.label == "candidate" else titles.get(p.map, p.map)
        legend.append((c, f"{what}: Φ = ({counts})"))
    maps = []
    for m, hmap in enumerate(settings.maps):
        cells = [c for c in result.cells if c["map"] == hmap.name]
        overlay = next((p for p in result.paths if p.map == hmap.name), None)
        maps.append(
            {
                "title": hmap.title,
                "grid": hmap.grid,
                "values": _values(hmap.grid, cells, "frobenius"),
                "status": _values(hmap.grid, cells, "status"),
                "no_information": settings.no_information(m),
                "overlay": None if overlay is None else _xy(overlay.trajectory),
                "overlay_label": (
                    "current path ξ*(θ̂)"
                    if hmap.grid.vary == "laptop"
                    else "ξ*(θ̂) from the best start"
                ),
                "laptop": None if hmap.grid.vary == "laptop" else settings.scene.laptop,
                "table": settings.scene.table,
                "start": settings.scene.start if hmap.grid.vary == "laptop" else None,
                "goal": settings.scene.goal,
                "cov": hmap.cov,
            }
        )
    title = _title(settings)
    targets = [folder / f"{settings.figure}.png", folder / f"{settings.figure}.pdf"]
    legend_title = (
        None
        if scene_paths and scene_paths[0].label == "candidate"
        else "ξ*(θ̂) from the most informative start of the map"
    )
    plot_selection_figure(image, legend, maps, title, targets, legend_title)
    return written + targets


def _values(grid: Grid, cells: list[dict], key: str) -> np.ndarray:
    """A (nx, ny) array of one column of the cells."""
    dtype = float if key != "status" else object
    out = np.empty((grid.nx, grid.ny), dtype=dtype)
    for c in cells:
        out[c["ix"], c["iy"]] = c[key]
    return out


def _xy(trajectory: np.ndarray) -> np.ndarray:
    from corrections_sim.scene.render import cup_path

    return cup_path(trajectory)[:, :2]


_PALETTE = (
    (0.15, 0.45, 0.95, 1.0),
    (0.95, 0.55, 0.1, 1.0),
    (0.85, 0.2, 0.6, 1.0),
    (0.2, 0.75, 0.35, 1.0),
)


def _path_colors(n: int) -> list[tuple[float, float, float, float]]:
    return [_PALETTE[i % len(_PALETTE)] for i in range(n)]


def _fmt(values) -> str:
    return "(" + ", ".join(f"{v:g}" for v in values) + ")"


def _title(settings: SelectionSettings) -> str:
    names = ", ".join(settings.features)
    return (
        f"{settings.figure}: where would one correction teach the robot most?  Features ({names}),"
        f" the robot's estimate θ̂ = {_fmt(settings.theta)}; lighter = learns more"
    )


register(
    PresetFigure("fig1", "where to learn, one feature: heat maps of eq. (A1)", __name__, ("maps",))
)
register(
    PresetFigure("fig2", "where to learn, two features: the best start moves", __name__, ("maps",))
)

"""Settings files as values: a TOML file with its ``[quick]`` table applied (:func:`read`), a
``--set`` value and its key path (:func:`parse_value`, :func:`set_path`), and figs. 1–3's
files read and checked (:func:`load_values`)."""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from corrections_sim.planning.features import check_feature_names
from corrections_sim.study.checks import take, vector


def read(path, *, quick: bool, keys=None) -> dict:
    """The values of a settings file, with its ``[quick]`` table applied when ``quick``.

    Args:
        keys: the top-level keys the file may hold, if the caller checks them here (a key
            of ``[quick]`` is checked whether or not ``quick`` is given).

    Raises:
        ValueError: unreadable file, a TOML syntax error (the message has its line), an
            unknown key (named, ``quick.runz``).
    """
    path = path if hasattr(path, "read_text") else Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(
            f"cannot read the file ({getattr(exc, 'strerror', None) or exc})"
        ) from None
    try:
        values = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        hint = ""
        if "Cannot declare ('learners'" in str(exc):
            hint = (
                "; a list `learners = [...]` and a table `[learners.NAME]` cannot both be "
                "given: name every learner as a table (`[learners.KF]`, an empty one takes "
                "the defaults)"
            )
        raise ValueError(f"invalid TOML: {exc}{hint}") from None
    overrides = values.pop("quick", {})
    if not isinstance(overrides, dict):
        raise ValueError("quick: expected a table of keys to override with --quick")
    if keys is not None:
        for prefix, table in (("", values), ("quick.", overrides)):
            unknown = [k for k in table if k not in keys]
            if unknown:
                raise ValueError(
                    f"{prefix}{unknown[0]}: unknown key (the file takes {', '.join(keys)})"
                )
    if quick:
        values.update(overrides)
    return values


def parse_value(text: str) -> Any:
    """A command-line value as TOML (``0.5``, ``[1, -1]``, ``true``, ``{ name = "x" }``), or
    the text itself when it is not TOML (``deform``)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def set_path(values: dict, path: str, value: Any) -> None:
    """Set ``values[a][b]… = value`` for ``path`` "a.b…" (``--set``); a name where a table is
    needed becomes ``{name = …}`` (``user``), a list of learners a table of them.

    Raises:
        ValueError: an empty path, or one through a value that is not a table.
    """
    parts = path.split(".")
    if not all(parts):
        raise ValueError(f"--set {path}: expected KEY.PATH=VALUE, e.g. user.step=0.5")
    node = values
    for depth, key in enumerate(parts[:-1]):
        where = ".".join(parts[: depth + 1])
        child = node.get(key)
        if child is None:
            child = {"name": "biased"} if where == "user" else {}
        elif (
            isinstance(child, str)
            and where in ("user",)
            or (isinstance(child, str) and depth > 0 and parts[0] == "learners")
        ):
            child = {"name": child}
        elif isinstance(child, list) and where == "learners":
            child = {name: {} for name in child}
        elif not isinstance(child, dict):
            raise ValueError(f"--set {path}: {where} is {child!r}, not a table")
        if where.startswith("learners.") and depth == 1 and key not in node:
            raise ValueError(
                f"--set {path}: {key} is not one of the study's learners ({', '.join(node)})"
            )
        node[key] = child
        node = child
    node[parts[-1]] = value


def as_table(value, where: str) -> dict:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ValueError(f"{where} = {value!r}: expected a table")
    return dict(value)


def load_values(
    directory,
    figure: str,
    figures: tuple[str, ...],
    quick: bool,
    overrides: dict | None,
    table: str,
) -> tuple[dict, tuple[str, ...], tuple[float, ...]]:
    """A figure's preset with overrides applied, and its checked features and θ̂.

    Args:
        figure: the figure asked for, one of ``figures``.
        quick: the quick preset instead of the paper-scale one.
        overrides: top-level fields to replace (None values are ignored); ``table`` (the
            list of maps or panels) and ``seed`` (these figures draw no random numbers)
            cannot be overridden.

    Returns:
        (the remaining fields, the feature names, θ̂ of their length).
    """
    if figure not in figures:
        raise ValueError(f"figure {figure!r}: choose one of {', '.join(figures)}")
    values = read(directory / f"{figure}.toml", quick=quick)
    for key, value in (overrides or {}).items():
        if value is None:
            continue
        if key == "seed":
            raise ValueError(f"seed: {figure} draws no random numbers, it takes no seed")
        if key not in values or key == table:
            raise ValueError(f"{key}: not a setting of {figure} that can be overridden")
        values[key] = value
    features = take(values, "features")
    if not isinstance(features, list | tuple):
        raise ValueError(f"features = {features!r}: expected a list of feature names")
    features = check_feature_names(tuple(features))
    theta = vector("theta", take(values, "theta"), len(features))
    return values, features, theta

"""The key-by-key reference of a study file (the docs page ``study-files.md`` includes it),
written from the schema's own list of keys and the registries, so it cannot drift."""

from __future__ import annotations

import re
from collections.abc import Mapping

from corrections_sim import components
from corrections_sim.learning.base import LEARNERS
from corrections_sim.people.corrections import CORRECTIONS
from corrections_sim.people.users import USERS
from corrections_sim.registry import Registry
from corrections_sim.study.legacy import LEGACY_KEYS
from corrections_sim.study.schema import STUDY_KEYS


def _first_line(cls) -> str:
    """A class's docstring's first paragraph, as Markdown (roles and double backticks plain)."""
    doc = " ".join((cls.__doc__ or "").strip().split("\n\n")[0].split())
    doc = re.sub(r":(?:func|class|mod|data|meth):`~?([^`]+)`", r"`\1`", doc)
    return doc.replace("``", "`")


def _toml(value) -> str:
    """A default as a study file writes it."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"
    return repr(value)


def _shown(value, registry: Registry | None = None) -> str:
    if value is None:
        return "absent"
    if value is components.dataclasses.MISSING:
        return "required"
    if registry is not None and isinstance(value, tuple):
        value = [{"name": components.name_of(registry, v), **components.params(v)} for v in value]
    elif registry is not None:
        value = {"name": components.name_of(registry, value), **components.params(value)}
    return f"`{_toml(value)}`"


def reference_markdown() -> str:
    """The study-file reference (a docs page), written from this schema and the registries:
    every key with its default and meaning, then every registered learner, user and
    correction model with its parameters and their defaults."""
    lines = ["| key | default | meaning |", "|---|---|---|"]
    required = {"theta_star": "required", "theta0": "zeros", "cov0": "identity"}
    for key, (default, meaning) in STUDY_KEYS.items():
        lines.append(f"| `{key}` | {required.get(key) or _shown(default)} | {meaning} |")
    lines.append("| `[quick]` | none | a table of any of these keys, applied with `--quick` |")
    for title, registry, where in (
        ("Learners", LEARNERS, "[learners.{name}]"),
        ("Simulated users", USERS, '[user] name = "{name}"'),
        ("Correction models", CORRECTIONS, '{{ name = "{name}", … }}'),
    ):
        lines += [
            "",
            f"### {title}",
            "",
            "| name | parameters (default) | what it is |",
            "|---|---|---|",
        ]
        for name, cls in registry.items():
            nested = components.nested_registries(cls)
            params = (
                ", ".join(
                    f"`{p}` ({_shown(v, nested.get(p))})"
                    for p, v in components.defaults(cls).items()
                )
                or "none"
            )
            what = _first_line(cls)
            if vars(cls).get("question"):  # its own, not a parent's
                what += f" *Answers:* {cls.question}"
            lines.append(f"| `{where.format(name=name)}` | {params} | {what} |")
    lines += [
        "",
        "### Keys of older study files",
        "",
        "Still accepted, each translated to its place:",
        "",
        "| flat key | now |",
        "|---|---|",
    ]
    for key, target in LEGACY_KEYS.items():
        if target[0] in ("filter", "planner", "user"):
            now = f"`{target[0]}.{target[1]}`" if target[1] else f"`{target[0]}` (its table)"
        elif target[1] is None:
            now = "`learners` (its tables)"
        else:
            now = ", ".join(f"`learners.{n}.{target[2]}`" for n in target[1])
        lines.append(f"| `{key}` | {now} |")
    return "\n".join(lines) + "\n"

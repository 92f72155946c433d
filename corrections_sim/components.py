"""Components: registered dataclasses whose fields are their own parameters.

A learner, a simulated user and a correction model are each a frozen dataclass registered by
name (:class:`~corrections_sim.registry.Registry`). Its fields are its parameters, with their
defaults and their checks (``__post_init__``) in one place, the class. Everything that builds
one from settings goes through :func:`build`, which refuses unknown parameters and names the
key path of a bad value (``learners.KF-A.attenuation_min: must be > 0``)::

    build(LEARNERS, "KF-A", {"attenuation_min": 0.1}, where="learners.KF-A")

A field may itself be a component of another registry (KF-C's ``model`` is a correction
model): declare it with :func:`nested`, and :func:`build` accepts a name (``"deform"``) or a
table (``{name = "waypoint", step = 0.5}``) for it; a field holding several (a tuple), with
:func:`nested_many`, takes a list of those. :func:`params` turns a component back into plain
data (nested ones as ``{"name": ..., **params}``, several as a list of them), for
``summary.json`` and run keys.
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Mapping
from typing import Any

from corrections_sim.registry import Registry


class ParameterError(ValueError):
    """A component's parameter with a bad value; :func:`build` prefixes the key path.

    Args:
        name: the parameter (field) name.
        message: what is wrong, e.g. "must lie in (0, 1], got 1.5".
    """

    def __init__(self, name: str, message: str) -> None:
        super().__init__(f"{name}: {message}")
        self.name = name
        self.message = message

    def __reduce__(self):
        # Pickled as its two arguments, so one raised in a worker process reaches the command
        # (the default pickles the joined message alone, which __init__ cannot take back).
        return (type(self), (self.name, self.message))


def nested(registry: Registry, default: Any) -> Any:
    """A dataclass field holding a component of ``registry`` (default: the instance ``default``)."""
    return dataclasses.field(default_factory=lambda: default, metadata={"registry": registry})


def nested_many(registry: Registry, default: tuple) -> Any:
    """A dataclass field holding a tuple of components of ``registry`` (default: the tuple of
    instances ``default``), given in settings as a list of names or tables."""
    return dataclasses.field(
        default_factory=lambda: tuple(default), metadata={"registry": registry, "many": True}
    )


def _many(cls: type, name: str) -> bool:
    """Whether the field ``name`` of ``cls`` holds several components (:func:`nested_many`)."""
    return any(f.name == name and f.metadata.get("many") for f in dataclasses.fields(cls))


def defaults(cls: type) -> dict[str, Any]:
    """A component class's parameters with their defaults (``dataclasses.MISSING`` if none):
    its dataclass fields, or else its constructor's keyword parameters."""
    if not dataclasses.is_dataclass(cls):
        signature = inspect.signature(cls.__init__)
        return {
            p.name: dataclasses.MISSING if p.default is p.empty else p.default
            for p in list(signature.parameters.values())[1:]
            if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
        }
    out = {}
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        if f.default is not dataclasses.MISSING:
            out[f.name] = f.default
        elif f.default_factory is not dataclasses.MISSING:
            out[f.name] = f.default_factory()
        else:
            out[f.name] = dataclasses.MISSING
    return out


def nested_registries(cls: type) -> dict[str, Registry]:
    """The fields of a component class that hold components of another registry."""
    if not dataclasses.is_dataclass(cls):
        return {}
    return {
        f.name: f.metadata["registry"] for f in dataclasses.fields(cls) if "registry" in f.metadata
    }


def build(registry: Registry, name: str, values: Mapping[str, Any] | None, *, where: str) -> Any:
    """The component ``name`` of ``registry`` with parameters ``values``.

    Args:
        where: the key path of this component in the settings ("user", "learners.KF-C"),
            which every error message starts with.

    Raises:
        ValueError: an unknown name or parameter, or a bad value, in one line starting with
            ``where`` (and the parameter's name).
    """
    try:
        cls = registry[name]
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    values = dict(values or {})
    known = defaults(cls)
    for key in values:
        if key not in known:
            allowed = ", ".join(known) or "none"
            raise ValueError(
                f"{where}.{key}: the {name} {registry.kind} has no such parameter "
                f"(it takes: {allowed})"
            )
    kwargs = {}
    for key, value in values.items():
        inner = nested_registries(cls).get(key)
        if inner is not None and _many(cls, key):
            kwargs[key] = _build_many(inner, value, where=f"{where}.{key}")
        elif inner is not None and not (inner.base and isinstance(value, inner.base)):
            kwargs[key] = build_spec(inner, value, where=f"{where}.{key}")
        else:
            kwargs[key] = value
    try:
        return cls(**kwargs)
    except ParameterError as exc:
        raise ValueError(f"{where}.{exc.name}: {exc.message}") from None
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: {exc}") from None


def _build_many(registry: Registry, values: Any, *, where: str) -> tuple:
    """Several components from a list of names or tables (instances kept as they are)."""
    if isinstance(values, str | Mapping) or not isinstance(values, list | tuple) or not values:
        raise ValueError(
            f"{where} = {values!r}: expected a non-empty list of {registry.kind} names or tables"
        )
    return tuple(
        v if registry.base and isinstance(v, registry.base) else build_spec(registry, v, where=w)
        for v, w in ((v, f"{where}[{i}]") for i, v in enumerate(values))
    )


def build_spec(registry: Registry, spec: Any, *, where: str) -> Any:
    """A component from a name (``"deform"``) or a table with ``name`` and its parameters."""
    if isinstance(spec, str):
        return build(registry, spec, {}, where=where)
    if isinstance(spec, Mapping):
        values = dict(spec)
        name = values.pop("name", None)
        if not isinstance(name, str):
            raise ValueError(
                f"{where}.name: missing (which {registry.kind}: {', '.join(registry)})"
            )
        return build(registry, name, values, where=where)
    raise ValueError(
        f"{where} = {spec!r}: expected a {registry.kind} name or a table with its name and "
        "parameters"
    )


def params(component: Any) -> dict[str, Any]:
    """A component's parameters as plain data; nested components as ``{"name", **params}``.
    A component that is not a dataclass reports the attributes named like its constructor's
    parameters."""
    if not dataclasses.is_dataclass(component):
        return {
            k: getattr(component, k) for k in defaults(type(component)) if hasattr(component, k)
        }
    out = {}
    for f in dataclasses.fields(component):
        if not f.init:
            continue
        value = getattr(component, f.name)
        registry = f.metadata.get("registry")
        if registry is not None and f.metadata.get("many"):
            value = [{"name": name_of(registry, v), **params(v)} for v in value]
        elif registry is not None:
            value = {"name": name_of(registry, value), **params(value)}
        out[f.name] = value
    return out


def name_of(registry: Registry, component: Any) -> str:
    """The name ``component``'s class is registered under in ``registry``.

    Raises:
        ValueError: the class is not registered (or under more than one name).
    """
    names = [n for n, cls in registry.items() if cls is type(component)]
    if len(names) != 1:
        raise ValueError(
            f"{type(component).__name__} is registered as {names or 'no'} {registry.kind}"
        )
    return names[0]

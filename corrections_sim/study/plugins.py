"""Plug-in files a study imports before anything else: they register users, learners,
correction models or features, in the main process and in every worker. A ``.json`` plug-in
is a learnt feature (:meth:`corrections_sim.learnt.training.Learnt.save`): loading it
registers the feature under its name."""

from __future__ import annotations

import hashlib
import importlib.util
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class PluginFile:
    """A Python file a study imports before anything else (it registers users, learners or
    features): its absolute path and the SHA-256 of its bytes (so a changed plug-in never
    resumes runs made with the old one)."""

    path: str
    sha256: str

    def as_dict(self) -> dict:
        return {"path": self.path, "sha256": self.sha256}


def parse_plugins(value, base: Path | None) -> tuple[PluginFile, ...]:
    """``plugins`` of a study file: a list of Python files, relative to the study file's
    folder (``base``) unless absolute. Each is imported here (once per process).

    Raises:
        ValueError: names the item: a missing file, or the exception its import raised.
    """
    if isinstance(value, tuple) and all(isinstance(v, PluginFile) for v in value):
        load_plugins(value)
        return value
    if isinstance(value, list | tuple) and all(isinstance(v, Mapping) for v in value):
        value = [v.get("path") for v in value]  # as summary.json records them
    if not isinstance(value, list | tuple) or not all(isinstance(v, str) for v in value):
        raise ValueError(f"plugins = {value!r}: expected a list of Python file paths")
    out = []
    for i, item in enumerate(value):
        path = Path(item).expanduser()
        if not path.is_absolute():
            path = (base or Path.cwd()) / path
        try:
            data = path.resolve().read_bytes()
        except OSError as exc:
            raise ValueError(f"plugins[{i}] = {item!r}: cannot read it ({exc.strerror})") from None
        plugin = PluginFile(str(path.resolve()), hashlib.sha256(data).hexdigest())
        try:
            load_plugins((plugin,))
        except Exception as exc:  # a plug-in's own error, reported in one line
            message = str(exc).splitlines()[0] if str(exc) else ""
            raise ValueError(
                f"plugins[{i}] = {item!r}: importing it raised {type(exc).__name__}: {message}"
            ) from None
        out.append(plugin)
    return tuple(out)


def load_plugins(plugins: tuple[PluginFile, ...]) -> None:
    """Import each plug-in file once per process (workers call this before a task, so
    registrations reach every worker, forked, spawned or on Dask)."""
    for plugin in plugins:
        module = f"corrections_sim_plugin_{hashlib.sha256(plugin.path.encode()).hexdigest()[:12]}"
        if module in sys.modules:
            continue
        if plugin.path.endswith(".json"):  # a learnt feature
            from corrections_sim.learnt.training import load

            load(plugin.path)
            sys.modules[module] = sys.modules[__name__]  # loaded: once per process
            continue
        spec = importlib.util.spec_from_file_location(module, plugin.path)
        if spec is None or spec.loader is None:
            raise ImportError(f"{plugin.path} is not a Python file")
        loaded = importlib.util.module_from_spec(spec)
        sys.modules[module] = loaded
        try:
            spec.loader.exec_module(loaded)
        except BaseException:
            del sys.modules[module]
            raise

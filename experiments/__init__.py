"""The figures' settings as data: ``<figure>.toml``, each with a ``paper`` and a ``quick`` preset.

This folder ships inside the package as ``corrections_sim.experiments`` (see pyproject.toml),
so the presets are read through ``importlib.resources`` from a clone and from a wheel alike.
"""

"""Which folder a figure goes to, and when it may replace what is there.

The policy (docs/getting-started.md, "Output folders and interrupts"): paper-scale presets write
to ``results/`` and quick presets to the scratch folder ``results/quick/`` (ignored by git)
unless ``--out`` says otherwise. A figure folder is replaced only by the same figure made with
the same settings (said in one line); a folder made with other settings, by another preset, or
holding files no figure wrote is refused unless ``--force`` is given, and then the command says
what it replaces. So the committed ``results/`` changes only when a paper-scale command is run
with the settings it already records, or with ``--force``.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

#: Default output folders of the paper-scale and the quick presets.
PAPER_OUT = Path("results")
QUICK_OUT = Path("results") / "quick"


class FolderTaken(ValueError):
    """The figure folder holds results another command made; ``--force`` replaces them."""


def default_out(quick: bool) -> Path:
    """Where a figure goes without ``--out``."""
    return QUICK_OUT if quick else PAPER_OUT


def _short(value, width: int = 40) -> str:
    text = json.dumps(value)
    return text if len(text) <= width else text[: width - 1] + "…"


def differences(old: dict, new: dict) -> dict[str, tuple]:
    """Settings recorded in both ``old`` and ``new`` whose values differ: {name: (old, new)}.

    A setting only one side records (one added to the code since, say) is not compared: the
    old summary cannot say which value it ran with.
    """
    old, new = json.loads(json.dumps(old)), json.loads(json.dumps(new))
    return {k: (old[k], new[k]) for k in old if k in new and old[k] != new[k]}


def check_replace(
    folder: Path,
    figure: str,
    preset: str,
    settings: dict,
    force: bool,
    upgrade: Callable[[dict], dict] | None = None,
) -> str:
    """Whether ``folder`` may receive ``figure`` made with ``settings``; checked before anything
    is computed or written. ``upgrade`` turns settings recorded by an older version into
    today's form (so the same study compares equal whichever version recorded it).

    Returns:
        "" if the folder holds nothing, else one line saying what will be replaced.

    Raises:
        FolderTaken: the folder holds another figure, another preset's or other settings'
            results, or files without a readable ``summary.json``, and ``force`` is False.
    """
    if not folder.is_dir() or not any(p for p in folder.iterdir() if not p.name.startswith(".")):
        return ""
    try:
        old = json.loads((folder / "summary.json").read_text())
        if not isinstance(old, dict):
            raise ValueError("not a JSON object")
    except (OSError, ValueError):
        what = "files without a readable summary.json"
    else:
        made = f" (made {old['timestamp']})" if "timestamp" in old else ""
        if old.get("figure") != figure:
            what = f"{old.get('figure')!r}, not {figure}{made}"
        elif isinstance(old.get("settings"), dict):
            earlier = upgrade(old["settings"]) if upgrade is not None else old["settings"]
            diff = differences(earlier, settings)
            if not diff:
                return f"replacing {folder}: {figure} with the same settings{made}"
            shown = [f"{k} {_short(a)} (now {_short(b)})" for k, (a, b) in diff.items()]
            more = f"; and {len(shown) - 4} more" if len(shown) > 4 else ""
            source = old.get("preset")
            source = (
                f" of the {source} preset (now {preset})" if source not in (None, preset) else ""
            )
            what = f"{figure}{source} made with other settings{made}: "
            what += "; ".join(shown[:4]) + more
        elif old.get("preset") == preset:
            return f"replacing {folder}: {figure}, {preset} preset{made}"
        else:
            what = f"{figure}, {old.get('preset')} preset{made}"
    if force:
        return f"replacing {folder} (--force): it held {what}"
    raise FolderTaken(f"{folder.name}/ holds {what}; give --force to replace it, or another --out")

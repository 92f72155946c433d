"""Drive the page from a script with Playwright and a system chromium, as a person would with
the mouse: the browser tests, ``bench interact`` and scripted demo sessions use it.

Everything is read from the page itself (the DOM and the page's initial camera), so it drives
a server in this process or another one. Waits are on page state, never on a fixed time.
Needs the ``dev`` extra (``playwright``) and a chromium: Debian's ``apt-get install chromium``
(Playwright's own browser download is not used).
"""

from __future__ import annotations

import os
import re
import shutil
import time
from collections.abc import Callable

import numpy as np

from corrections_sim.interact.page import HANDLE_SCALE, project

#: chromium's flags for a machine without a GPU or a user namespace sandbox.
LAUNCH_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"]
VIEWPORT = {"width": 1280, "height": 720}
_CUP = re.compile(r"Cup at waypoint (\d+)(?: moved to)?: \(([-\d.]+), ([-\d.]+), ([-\d.]+)\) m")


def chromium() -> str | None:
    """The system chromium's path (``$CHROMIUM`` first), or None."""
    for candidate in (os.environ.get("CHROMIUM"), "chromium", "chromium-browser"):
        if candidate and (path := shutil.which(candidate)):
            return path
    return None


def launch(playwright):
    """A headless chromium (the system's) through Playwright."""
    path = chromium()
    if path is None:
        raise RuntimeError("no chromium: apt-get install chromium (or set $CHROMIUM)")
    return playwright.chromium.launch(executable_path=path, args=LAUNCH_ARGS)


def wait_for(predicate: Callable[[], object], what: str, timeout: float = 60.0):
    """``predicate()``'s first truthy value, polled; TimeoutError naming ``what``."""
    end = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > end:
            raise TimeoutError(f"{what}: not within {timeout:.0f} s")
        time.sleep(0.05)


def open_page(browser, url: str, *, viewport: dict | None = None):
    """A new tab on ``url`` once the page shows its plan (its submit button)."""
    tab = browser.new_page(viewport=viewport or VIEWPORT)
    tab.goto(url)
    tab.get_by_text("Submit correction").wait_for(timeout=120_000)
    tab.locator("canvas").first.wait_for(timeout=120_000)
    wait_for(lambda: cup_position(tab), "the cup's position on the page")
    return tab


def cup_position(tab) -> tuple[int, np.ndarray] | None:
    """(waypoint, cup centre (3,)) as the page states them, or None before it does."""
    match = _CUP.search(tab.locator("body").inner_text())
    if match is None:
        return None
    return int(match.group(1)), np.array([float(match.group(i)) for i in (2, 3, 4)])


def status(tab) -> str:
    return tab.locator("body").inner_text()


def drag_cup(tab, pixels_up: float, *, steps: int = 10) -> None:
    """Drag the handle's vertical (z) arrow ``pixels_up`` pixels up (down if negative) with
    the mouse, in the page's initial view."""
    _, cup = cup_position(tab)
    box = tab.locator("canvas").first.bounding_box()
    x, y = project(cup + (0.0, 0.0, 0.7 * HANDLE_SCALE), box["width"], box["height"])
    x, y = box["x"] + x, box["y"] + y
    tab.mouse.move(x, y)
    tab.mouse.down()
    for i in range(1, steps + 1):
        tab.mouse.move(x, y - pixels_up * i / steps)
    tab.mouse.up()


def click(tab, label: str) -> None:
    tab.get_by_role("button", name=label).click()


def set_number(tab, index: int, value: float) -> None:
    """Type ``value`` into the page's ``index``-th number box (the sliders' boxes, in order)."""
    box = tab.locator("input.mantine-NumberInput-input").nth(index)
    box.fill(f"{value}")
    box.press("Enter")

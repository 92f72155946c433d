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
import threading
import time
from collections.abc import Callable, Sequence

import numpy as np

from corrections_sim.pages.drawing import (
    CAMERA_FOV,
    CAMERA_LOOK_AT,
    CAMERA_POSITION,
    HANDLE_SCALE,
    project,
)

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


def open_page(browser, url: str, *, viewport: dict | None = None, physical: bool = False):
    """A new tab on ``url`` once the page shows its plan (its submit button; a physical
    session's play button)."""
    tab = browser.new_page(viewport=viewport or VIEWPORT)
    tab.goto(url)
    ready = "Play: push the cup while it moves" if physical else "Submit correction"
    tab.get_by_text(ready).wait_for(timeout=120_000)
    tab.locator("canvas").first.wait_for(timeout=120_000)
    if not physical:
        wait_for(lambda: cup_position(tab), "the cup's position on the page", timeout=120.0)
    return tab


def frame_rate(tab, seconds: float = 2.0) -> float:
    """Frames per second the page draws (requestAnimationFrame callbacks over ``seconds``)."""
    return tab.evaluate(
        """(seconds) => new Promise((done) => {
            let frames = 0;
            const start = performance.now();
            const tick = (now) => {
                frames += 1;
                if (now - start < seconds * 1000) requestAnimationFrame(tick);
                else done(frames / ((now - start) / 1000));
            };
            requestAnimationFrame(tick);
        })""",
        seconds,
    )


def push_cup(tab, cup, pixels_up: float, *, steps: int = 12, hold: float = 0.5) -> None:
    """Grab the handle's vertical arrow at the cup's position ``cup`` (3,) now, drag it
    ``pixels_up`` pixels up in ``steps`` moves, hold ``hold`` s, let go."""
    start = on_screen(tab, handle_arrow(cup))
    tab.mouse.move(*start)
    tab.mouse.down()
    for i in range(1, steps + 1):
        tab.mouse.move(start[0], start[1] - pixels_up * i / steps)
    time.sleep(hold)
    tab.mouse.up()


def on_screen(tab, point, camera=None) -> tuple[float, float]:
    """The page's pixel of world ``point`` (3,) in the canvas, seen from ``camera`` (a viser
    client's camera: the view the person has now) or, without one, from the page's initial
    view. A press that misses the handle and moves orbits the view, so a script that goes on
    after a miss must aim through the client's camera."""
    box = tab.locator("canvas").first.bounding_box()
    view = {}
    if camera is not None:
        view = dict(
            position=camera.position,
            look_at=camera.look_at,
            up=camera.up_direction,
            fov=camera.fov,
        )
    x, y = project(point, box["width"], box["height"], **view)
    return box["x"] + x, box["y"] + y


def reach_and_grab(
    tab, point, *, camera=None, reach: float = 0.3, pull: float = 12.0, hold: float = 0.1
) -> tuple[float, float]:
    """As a hand does it: move the pointer to the screen point of world ``point`` (3,) (seen
    from ``camera``, see :func:`on_screen`) in ``reach`` seconds, from 150 pixels down and to
    the left of it, press, pull ``pull`` pixels up (a press becomes a grab only once it
    moves), hold ``hold`` s, let go. Returns the pixel pressed."""
    target = on_screen(tab, point, camera)
    start = (target[0] - 120.0, target[1] + 90.0)
    tab.mouse.move(*start)
    steps = 10
    began = time.monotonic()
    for i in range(1, steps + 1):
        f = i / steps
        tab.mouse.move(start[0] + f * (target[0] - start[0]), start[1] + f * (target[1] - start[1]))
        time.sleep(max(0.0, began + reach * f - time.monotonic()))
    tab.mouse.down()
    for i in range(1, 4):
        tab.mouse.move(target[0], target[1] - pull * i / 3)
    time.sleep(hold)
    tab.mouse.up()
    return target


def handle_arrow(position) -> np.ndarray:
    """The point a person aims at to grab the handle at ``position`` (3,): its vertical
    arrow, 0.7 of the way up."""
    return np.asarray(position, float) + 0.7 * HANDLE_SCALE * np.eye(3)[2]


def cup_position(tab) -> tuple[int, np.ndarray] | None:
    """(waypoint, cup centre (3,)) as the page states them (a participant's page in an
    element it does not show), or None before it does."""
    text = tab.locator("body").inner_text()
    if _CUP.search(text) is None:
        text = " ".join(e.get_attribute("data-cup") or "" for e in tab.locator("[data-cup]").all())
    match = _CUP.search(text)
    if match is None:
        return None
    return int(match.group(1)), np.array([float(match.group(i)) for i in (2, 3, 4)])


def status(tab) -> str:
    return tab.locator("body").inner_text()


def drag_cup(tab, pixels_up: float, *, steps: int = 10, camera=None) -> None:
    """Drag the handle's vertical (z) arrow ``pixels_up`` pixels up (down if negative) with
    the mouse, aiming through ``camera`` (see :func:`on_screen`; default the page's initial
    view). A retry after a miss must give the client's camera: the miss orbited the view."""
    _, cup = cup_position(tab)
    x, y = on_screen(tab, cup + 0.7 * HANDLE_SCALE * np.eye(3)[2], camera)
    _mouse_drag(tab, (x, y), (x, y - pixels_up), steps)


def move_cup(tab, axis: int, metres: float, *, steps: int = 10, camera=None) -> None:
    """Drag the handle's arrow along world ``axis`` (0 x, 1 y, 2 z) by ``metres``: the mouse
    moves from the arrow to where that point would be after the move (both seen through
    ``camera``, as for :func:`drag_cup`)."""
    _, cup = cup_position(tab)
    direction = np.eye(3)[axis]
    start = on_screen(tab, cup + 0.7 * HANDLE_SCALE * direction, camera)
    end = on_screen(tab, cup + (0.7 * HANDLE_SCALE + metres) * direction, camera)
    _mouse_drag(tab, start, end, steps)


def _mouse_drag(tab, start, end, steps: int) -> None:
    tab.mouse.move(*start)
    tab.mouse.down()
    for i in range(1, steps + 1):
        f = i / steps
        tab.mouse.move(start[0] + f * (end[0] - start[0]), start[1] + f * (end[1] - start[1]))
    tab.mouse.up()


def until_landed(
    drag: Callable[[], None],
    landed: Callable[[], object],
    *,
    attempts: int = 3,
    timeout: float = 20.0,
) -> None:
    """Run the mouse ``drag`` until ``landed()`` (e.g. the server counted a drag): a drag
    made while software WebGL has not yet drawn the handle where the page says misses it,
    and is made again."""
    for attempt in range(1, attempts + 1):
        drag()
        try:
            wait_for(landed, "the drag reaching the server", timeout)
            return
        except TimeoutError:
            if attempt == attempts:
                raise


def click(tab, label: str) -> None:
    tab.get_by_role("button", name=label).click()


def set_number(tab, index: int, value: float) -> None:
    """Type ``value`` into the page's ``index``-th number box (the sliders' boxes, in order)."""
    box = tab.locator("input.mantine-NumberInput-input").nth(index)
    box.fill(f"{value}")
    box.press("Enter")


def _shown(tab, selector: str, index: int):
    """The ``index``-th element matching ``selector`` that the page lays out, once there is
    one (viser has inputs of its own: hidden ones, and the server's address, ws://…)."""
    script = (
        "s => Array.from(document.querySelectorAll(s)).filter(e => e.offsetParent !== null"
        " && !/^wss?:/.test(e.value)).map(e => e.id)"
    )
    ids = wait_for(lambda: (found := tab.evaluate(script, selector))[index:] and found, selector)
    return tab.locator(f"[id='{ids[index]}']")


def fill_text(tab, index: int, text: str) -> None:
    """Type ``text`` into the page's ``index``-th shown text box (in order)."""
    box = _shown(tab, "input.mantine-TextInput-input", index)
    box.fill(text)
    box.press("Enter")


def choose(tab, index: int, option: str) -> None:
    """Pick ``option`` (the start of its text) in the page's ``index``-th shown drop-down."""
    _shown(tab, "input.mantine-Select-input", index).click()
    tab.get_by_role("option", name=option).first.click()


class SocketTab:
    """A tab without a browser: a websocket that speaks just enough of viser's protocol (the
    viewer's camera, which is when viser counts a client as connected) and drains whatever
    the server sends. The page is built for it on the server as for a browser's tab, so the
    tests of the server's state run without software WebGL. A context manager; closing it is
    a tab closing."""

    def __init__(self, url: str) -> None:
        import msgspec
        import viser
        import websockets.sync.client as ws

        self.socket = ws.connect(
            url.replace("http://", "ws://"), subprotocols=[f"viser-v{viser.__version__}"]
        )
        camera = {
            "type": "ViewerCameraMessage",
            "wxyz": [1.0, 0.0, 0.0, 0.0],
            "position": [float(v) for v in CAMERA_POSITION],
            "fov": CAMERA_FOV,
            "near": 0.01,
            "far": 100.0,
            "image_height": VIEWPORT["height"],
            "image_width": VIEWPORT["width"],
            "look_at": [float(v) for v in CAMERA_LOOK_AT],
            "up_direction": [0.0, 0.0, 1.0],
        }
        self.socket.send(msgspec.msgpack.encode(camera))
        self.received = 0
        self._reader = threading.Thread(target=self._drain, name="tab", daemon=True)
        self._reader.start()

    def _drain(self) -> None:
        try:
            while True:
                self.socket.recv()
                self.received += 1
        except Exception:  # closed, by either side: the tab is gone
            return

    def close(self) -> None:
        self.socket.close()
        self._reader.join(timeout=10)

    def __enter__(self) -> SocketTab:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --- a participant's answers, as fast as the page takes them --------------------------------

#: A value as a participant's page echoes it: "Received: **70 (0: very low, …)**" or the
#: line of an item not answered yet.
_ECHO = re.compile(r"Received: ([^\s:]+)|Not answered yet|Nothing written yet")


def number_boxes(tab):
    """The number boxes beside the page's sliders, in order."""
    return tab.locator("input.mantine-NumberInput-input")


def fast_numbers(tab, values: Sequence[float], then_click: str | None = None) -> float:
    """Type ``values`` into the first number boxes and (``then_click``) press that button,
    all from one script in the page, as fast as it takes input; the milliseconds from the
    first value to the click, as the page timed them."""
    script = """([values, label]) => {
        const setter = Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, 'value').set;
        const boxes = Array.from(document.querySelectorAll('input.mantine-NumberInput-input'));
        const start = performance.now();
        values.forEach((v, i) => {
            const box = boxes[i];
            setter.call(box, String(v));
            box.dispatchEvent(new Event('input', {bubbles: true}));
        });
        if (label) {
            const button = Array.from(document.querySelectorAll('button'))
                .find(b => b.textContent.trim() === label);
            button.click();
        }
        return performance.now() - start;
    }"""
    return float(tab.evaluate(script, [list(values), then_click]))


#: The line under a slider (a TLX scale): "Received: 70 (0: very low, …)" or unanswered.
_SLIDER_ECHO = re.compile(r"Received: (\d+) \(0: |Not answered yet: move the slider")


def echoes(tab) -> list[str | None]:
    """What the server has received of each item of the questionnaire on the page, in order
    (None: nothing yet)."""
    return [m.group(1) for m in _ECHO.finditer(status(tab))]


def slider_echoes(tab) -> list[str | None]:
    """What the server has received of each slider of the questionnaire (its TLX scales), in
    the order of the number boxes, whatever items come before or between them."""
    return [m.group(1) for m in _SLIDER_ECHO.finditer(status(tab))]


def _set_until(tab, index: int, value: float, away: float, seen: Callable[[float], bool]):
    """Type ``value`` into number box ``index`` until the page says the server has it
    (``seen``); where the box already shows it (a change the page never sent, or a start
    that is no answer), a step to ``away`` first: the page counts only a moved control."""
    if float(number_boxes(tab).nth(index).input_value() or "nan") == value:
        set_number(tab, index, away)
        wait_for(lambda: seen(away), "the step away reaching the server")
    set_number(tab, index, value)
    wait_for(lambda: seen(value), "the value reaching the server")


def _plain(value: float) -> str:
    return f"{value:g}"


def _echo_at(tab, index: int) -> str | None:
    got = slider_echoes(tab)
    return got[index] if index < len(got) else None


def answer_sliders(tab, values: Sequence[float], *, rounds: int = 6) -> dict:
    """A participant who sets a questionnaire's sliders (its first number boxes) to
    ``values`` as fast as the page takes input and presses Submit in the same moment, then
    reads what the page says it received and mends it until the page's confirmation shows
    exactly ``values``, and confirms; the questionnaire's other items (a Likert item before
    the TLX, as in experiments/protocol.toml) must be answered already. Returns {window_ms,
    lost (values the first submit did not carry), rounds}."""
    old = _button(tab, "Submit answers")
    window = fast_numbers(tab, values, "Submit answers")
    lost = None
    for round_ in range(1, rounds + 1):
        _redrawn(tab, old)
        wait_for(
            lambda: "Please check your answers" in status(tab) or "Not taken" in status(tab),
            "the page's answer to Submit",
        )
        if "Please check your answers" in status(tab):
            shown = confirmed_sliders(tab)
            if lost is None:
                lost = sum(a != _plain(v) for a, v in zip(shown, values, strict=False))
            if shown[: len(values)] == [_plain(v) for v in values]:
                click(tab, "Yes, submit these answers")
                return {"window_ms": window, "lost": lost, "rounds": round_}
            old = _button(tab, "Change an answer")
            old.click()
            _redrawn(tab, old)
            wait_for(lambda: "Submit answers" in status(tab), "the questionnaire again")
        got = slider_echoes(tab)
        if lost is None:
            lost = sum(a != _plain(v) for a, v in zip(got, values, strict=False))
        for i, v in enumerate(values):
            if got[i] != _plain(v):
                away = v + 5 if v <= 95 else v - 5
                _set_until(tab, i, v, away, lambda x, i=i: _echo_at(tab, i) == _plain(x))
        old = _button(tab, "Submit answers")
        old.click()
    raise TimeoutError(f"the answers did not go through in {rounds} rounds")


def _button(tab, label: str):
    """The button ``label`` on the page now (an element: a redrawn page has a new one)."""
    return tab.get_by_role("button", name=label).element_handle()


def _redrawn(tab, element) -> None:
    """Wait until ``element`` has left the page (the server drew the step again)."""
    tab.wait_for_function("e => !e.isConnected", arg=element, timeout=60_000)


def confirmed_values(tab) -> list[str]:
    """The values of the page's confirmation table, in order (its first word each)."""
    rows = tab.locator("table").last.locator("tbody tr").all()
    return [row.locator("td").nth(1).inner_text().split()[0].rstrip(":") for row in rows]


def confirmed_sliders(tab) -> list[str]:
    """The values of the confirmation table's slider rows (the TLX scales), in order."""
    from corrections_sim.userstudy.protocol import TLX_TITLES

    rows = tab.locator("table").last.locator("tbody tr").all()
    return [
        row.locator("td").nth(1).inner_text().split()[0].rstrip(":")
        for row in rows
        if row.locator("td").nth(0).inner_text().strip() in TLX_TITLES.values()
    ]


def state_preference(tab, values: Sequence[float]) -> None:
    """State the preference ``values`` (one per feature, the trial page's first sliders):
    each typed and waited for until the page's "We have" line shows it (a value the box
    already shows is stepped away from first, since the page counts only a moved slider),
    then "State my preference" and the page's record of it."""
    tab.get_by_role("button", name="State my preference").wait_for(timeout=120_000)

    def have(i: int) -> str | None:
        found = re.search(r"We have: (.*)", status(tab))
        parts = found.group(1).split(", ") if found else []
        return parts[i].split(" ")[-1] if i < len(parts) else None

    for i, value in enumerate(values):
        away = value + 0.5 if value <= 1.5 else value - 0.5
        _set_until(tab, i, value, away, lambda x, i=i: have(i) == f"{x:+.1f}")
    click(tab, "State my preference")
    wait_for(lambda: "recorded as" in status(tab), "the stated preference recorded")

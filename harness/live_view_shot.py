"""The live view during a sustained press, as a person sees it, and its re-tare button.

:func:`sustained_press_on_the_view` runs the live loop on the simulated board's stream
(faster than real time, :func:`eskin.device.simulate.accelerated_stream`) into a
:class:`~eskin.deploy.view.LiveView`, presses one weight or several for ``press_s`` of
board time, and holds there while headless Chromium reads the page and takes its
picture; then the weights are lifted and the page's re-tare button is clicked, and the
page must show the tare the live loop took on request. ``tests/test_live_ghosts.py``
runs it on the small test stack; ``python -m harness.live_view_shot [scene]`` on the
workspace's stack writes docs/screenshots/live_sustained_press.png for a one-contact
scene (a 2-minute press) and docs/screenshots/live_two_contacts.png for a two-contact
one (two weights for 10 s; docs/live.md).
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from pathlib import Path
from typing import Any

from eskin.deploy.live import live_estimates
from eskin.deploy.view import LiveView
from eskin.device.simulate import accelerated_stream, live_board
from harness.live_hour import Press

WAIT_S = 60.0  # each wait on the other side (the loop, or the page) has this deadline


def sustained_press_on_the_view(stack, params, browser, path: Path, *,
                                press: Press = ((5, 5, 5.2136),),
                                press_s: float = 120.0) -> dict[str, Any]:
    """What the page showed at the end of the press (its texts), and after the re-tare
    button was clicked (``tared``); the picture is written to ``path``.
    ``press``: the weights, placed at once."""
    board = live_board(params, stack.skin)
    period_ms = int(params.sim_board.frame_period_ms)
    at_end, lifted, done = threading.Event(), threading.Event(), threading.Event()
    failure: list[BaseException] = []

    with LiveView(scene=stack.scene, kind=stack.kind, device="sim", skin=stack.skin) as view:
        def loop() -> None:
            try:
                pressed_frames = int(press_s * 1000 / period_ms)
                estimates, pressed_at, lifted_at = 0, None, None

                def batches():  # as fast as it goes, then in real time once lifted
                    for batch in accelerated_stream(board, batch_frames=8):
                        if lifted_at is not None:
                            time.sleep(len(batch) * period_ms / 1000)
                        yield batch

                for record in live_estimates(stack, batches(), settings=params.live,
                                             with_change=True, requests=view.requests):
                    view.show(record)
                    estimates += "seq" in record
                    if pressed_at is None and estimates >= 50:
                        for x, y, newtons in press:
                            board.handle(f"SIM PRESS {x} {y} {newtons} 100".encode())
                        pressed_at = estimates
                    elif pressed_at is not None and lifted_at is None \
                            and estimates >= pressed_at + pressed_frames:
                        at_end.set()
                        if not lifted.wait(WAIT_S):
                            raise TimeoutError("the page was not read within its deadline")
                        board.handle(b"SIM CLEAR")
                        lifted_at = estimates
                    if "tare" in record and record["tare"]["reason"] == "request":
                        done.wait(WAIT_S)  # the page reads the tare, then the loop ends
                        return
                    if lifted_at is not None and estimates > lifted_at + WAIT_S * 1000 / period_ms:
                        raise TimeoutError("no re-tare was asked for from the page")
            except BaseException as err:  # noqa: BLE001 - the caller reports it
                failure.append(err)
                at_end.set()

        worker = threading.Thread(target=loop, daemon=True)
        worker.start()
        try:
            page = browser.new_page(viewport={"width": 980, "height": 640})
            page.goto(view.url)
            if not at_end.wait(WAIT_S * 5):
                raise TimeoutError("the live loop never reached the press's end")
            if failure:
                raise failure[0]
            # the page lists contacts in the stack's order: row-major, as the scene's
            placed = "; ".join(f"x {x}, y {y}" for x, y, _ in sorted(press))
            page.wait_for_function(
                f"document.getElementById('location').textContent === '{placed}'",
                timeout=WAIT_S * 1000)
            shown = {name: page.inner_text(f"#{name}")
                     for name in ("contact", "location", "force", "stretch", "drift")}
            path.parent.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(path))
            lifted.set()
            page.wait_for_function(
                "document.getElementById('contact').textContent.startsWith('no touch')",
                timeout=WAIT_S * 1000)
            page.click("#tare")
            page.wait_for_function(
                "document.getElementById('tared').textContent.startsWith('again at frame')",
                timeout=WAIT_S * 1000)
            shown["tared"] = page.inner_text("#tared")
        finally:
            lifted.set()
            done.set()
            worker.join(timeout=WAIT_S)
    if failure:
        raise failure[0]
    return shown


def main() -> int:
    from eskin.catalog import stack_path
    from eskin.config.base import load_params
    from eskin.config.params import Params
    from eskin.deploy.stack import ExportedStack
    from eskin.kinds import get_kind
    from tests.conftest import headless_chromium

    params = load_params(Params)
    scene = sys.argv[1] if len(sys.argv) > 1 else next(iter(params.scenes))
    stack = ExportedStack.from_file(stack_path(scene))
    if get_kind(stack.kind).contacts == 1:
        path = Path("docs/screenshots/live_sustained_press.png")
        press, press_s = ((5, 5, 5.2136),), 120.0
    else:  # two of the plan's nodes and forces
        path = Path("docs/screenshots/live_two_contacts.png")
        press, press_s = ((1, 10, 3.2536), (10, 1, 5.2136)), 10.0
    with contextlib.ExitStack() as resources:
        browser = resources.enter_context(headless_chromium())
        shown = sustained_press_on_the_view(stack, params, browser, path, press=press,
                                            press_s=press_s)
    print(f"{path}: {shown}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

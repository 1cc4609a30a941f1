"""The live view's layout for a skin of any size, pressed on the simulated board.

No stack is trained for most skin sizes, so :func:`view_on_the_board` runs no stack: the
simulated board of ``skin`` streams on a pty (its own process) as for ``eskin live
--simulated``, the first frames are its untouched reading, and each frame is shown as the
change of every channel from it; the node under the largest row and the largest column
change stands in for the estimate (no force: a stack gives that). A click on the page
presses the board through the view, as the live loop does (:meth:`LiveView.carry_out_presses`
with the link's ``command``, between two batches of the stream).

:data:`LAYOUT` is what ``tests/test_live.py`` reads back from the page: the page's width
and where the status column (and how much of it is hidden), the node cells, the bars
and the labels shown lie.
``python -m harness.live_view_layout DIR`` writes the 10 × 10 and 32 × 32 pages at
1280 × 800 (the whole page), each with a weight on its far corner node, to
DIR/live-RxC.png.
"""

from __future__ import annotations

import contextlib
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from eskin.deploy.view import LiveView, Pressing
from eskin.kinds import ONE_CONTACT
from eskin.skin import Skin, skin_from_dict

UNTOUCHED_FRAMES = 20
CONTACT_COUNTS = 8.0  # on a row and a column: a touch (the untouched noise is about ±3)
WAIT_S = 30.0

# Where the page's parts lie (getBoundingClientRect: left, right, top, bottom in px).
LAYOUT = """() => {
  const place = e => { const r = e.getBoundingClientRect();
                       return [r.left, r.right, r.top, r.bottom]; };
  const all = selector => [...document.querySelectorAll(selector)];
  const text = e => { const range = document.createRange(); range.selectNodeContents(e);
                      return place(range); };  // a label's text, wider or not than its slot
  const shown = selector => all(selector).filter(e => getComputedStyle(e).visibility !== "hidden")
    .map(text);
  return {scroll_width: document.documentElement.scrollWidth, width: innerWidth,
          readout: place(document.getElementById("readout")),
          readout_hidden: document.getElementById("readout").scrollWidth
            - document.getElementById("readout").clientWidth,
          cells: Object.fromEntries(all("#map .cell").map(c => [c.id, place(c)])),
          bars: all("#bars div").map(place),
          bar_labels: shown("#barlabels div"), x_labels: shown("#map .xlabel"),
          y_labels: shown("#map .ylabel")};
}"""


@contextlib.contextmanager
def view_on_the_board(params, skin: Skin, *, weight_n: float = 5.0
                      ) -> Iterator[tuple[LiveView, list[BaseException]]]:
    """A pressable :class:`LiveView` of ``skin`` fed by its simulated board (``params``:
    an :class:`eskin.config.Params`), once it shows frames; and the failures of its loop."""
    from eskin.acquisition.session import simulated_board
    from eskin.deploy.live import stream_events
    from eskin.device.host import StreamFrame
    from eskin.device.link import SerialLink
    from eskin.device.physics import skin_params

    stop, shown, failure = threading.Event(), threading.Event(), []

    def loop(view: LiveView) -> None:
        try:
            with contextlib.ExitStack() as resources:
                board = resources.enter_context(simulated_board(
                    skin_params(params.sim), skin=skin,
                    rest_length_mm=float(params.acquire.rest_length_mm), frame_period_ms=12))
                link = resources.enter_context(SerialLink(board.port, timeout_s=5.0))
                link.connect()
                stream = resources.enter_context(contextlib.closing(stream_events(link)))
                untouched: list[np.ndarray] = []
                for batch in stream:
                    view.carry_out_presses(link.command)
                    for event in batch:
                        if not isinstance(event, StreamFrame):
                            continue
                        counts = np.asarray(event.frame.counts, dtype=np.float64)
                        if len(untouched) < UNTOUCHED_FRAMES:
                            untouched.append(counts)
                            continue
                        view.show(board_record(event.frame, counts - np.mean(untouched, 0),
                                               skin))
                        shown.set()
                    if stop.is_set():
                        return
        except Exception as err:  # noqa: BLE001 - the caller reports it
            failure.append(err)
            shown.set()

    with LiveView(scene=f"{skin.rows}x{skin.columns}", kind=ONE_CONTACT.name, device="sim",
                  skin=skin, pressing=Pressing(weight_n, (weight_n,))) as view:
        worker = threading.Thread(target=loop, args=(view,), daemon=True)
        worker.start()
        try:
            if not shown.wait(WAIT_S) or failure:
                raise failure[0] if failure else TimeoutError("the board sent no frames")
            yield view, failure
        finally:
            stop.set()
            worker.join(timeout=WAIT_S)


def board_record(frame, change: np.ndarray, skin: Skin) -> dict[str, Any]:
    """What the page is shown of one frame: its change from the untouched reading, and
    the node under the largest row and column change as its location."""
    rows, columns = change[:skin.rows], change[skin.rows:]
    touch = bool(rows.max() >= CONTACT_COUNTS and columns.max() >= CONTACT_COUNTS)
    return {"seq": frame.seq, "t_ms": frame.t_ms, "x": int(rows.argmax()) + 1,
            "y": int(columns.argmax()) + 1, "force": None, "stretch": None,
            "contact": touch, "contact_probability": None, "drift_counts": None,
            "change_counts": [round(float(v), 1) for v in change]}


def pressed_page(browser, view: LiveView, node: tuple[int, int], *,
                 viewport: tuple[int, int] = (1280, 800)):
    """The view in a new page of ``browser``, node ``node`` clicked, once the page shows
    the weight laid there and the board's frames a touch."""
    page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
    page.goto(view.url)
    page.wait_for_function("document.getElementById('seq').textContent !== '–'",
                           timeout=WAIT_S * 1000)
    x, y = node
    page.click(f"#cell-{x}-{y}")
    page.wait_for_function(
        f"document.getElementById('pressed').textContent.endsWith('N on x {x}, y {y}')"
        " && document.getElementById('contact').textContent.startsWith('touch')",
        timeout=WAIT_S * 1000)
    return page


def main() -> int:
    from eskin.config.base import load_params
    from eskin.config.params import Params
    from tests.conftest import headless_chromium

    out = Path(sys.argv[1] if len(sys.argv) > 1 else ".")
    params = load_params(Params)
    with headless_chromium() as browser:
        for skin in (skin_from_dict({"rows": n, "columns": n}) for n in (10, 32)):
            with view_on_the_board(params, skin) as (view, _):
                page = pressed_page(browser, view, (skin.rows, skin.columns))
                path = out / f"live-{skin.rows}x{skin.columns}.png"
                page.screenshot(path=str(path), full_page=True)
                print(f"{path}: {page.evaluate(LAYOUT)['scroll_width']} px wide")
    return 0


if __name__ == "__main__":
    sys.exit(main())

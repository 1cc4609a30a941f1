"""The live view: a page on 127.0.0.1 showing what the stack makes of each frame.

A person pressing the skin looks at it: the skin's map of nodes (size_x × size_y: R × C on
a row/column skin, 10 × 10 on the paper's) with the estimated contact(s)
(marked by force), the force, the location, the stretch, whether there is contact and
how sure the detector is, the drift since the tare, every channel's change from the
untouched reading as bars on an axis in ADC counts, and the frame rate; a button (and
the key t) asks for a re-tare (``POST /tare``). On the simulated board a click on a node
presses the skin there with the weight set on the page, and a second click lifts it
(``POST /press``, which ``eskin press`` sends too): the live loop hands it to the board
as its ``SIM`` commands, on the link it streams on (:meth:`LiveView.carry_out_presses`).
A real board is pressed by hand, and the page says so. The page holds an
``EventSource`` on ``/events``; every client is sent the newest state only (a slow
browser skips frames, nothing queues), and ``/state`` answers it once as JSON.

A page, not a terminal view: it draws the map as the skin is laid out, any machine on the
bench can open it (through an SSH tunnel: it binds to 127.0.0.1 only), and it is tested
the way the report page is, in headless Chromium, reading what the page shows.
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Future, wait
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from eskin.errors import EskinError
from eskin.skin import AnySkin

KEEPALIVE_S = 10.0  # an idle stream sends a comment this often, so a dead client is noticed
# A press from the page ramps in as a hand lays a weight (make bench's live hour's
# press_ramp_ms): the stack sees the load rise, as it would on the bench.
PRESS_RAMP_MS = 100
PRESS_WAIT_S = 10.0  # how long POST /press waits for the live loop to carry it out
MAX_BODY_BYTES = 1024  # a press request is a short JSON object

PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>eskin live: {scene}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 1.5em; background: #fafafa; color: #222; }}
h1 {{ font-size: 1.2em; margin: 0 0 .8em; }}
/* Any skin up to 32 × 32 in a 1,280 px window: the status column keeps its width, the
map takes what is left (its cells shrink, 4:3 as at full size), and the bars share the
page's width; a label too wide for its slot shows every k-th one (fit() below). */
main {{ display: flex; gap: 2em; align-items: flex-start; }}
#map {{ display: grid; grid-template-columns: 1.6em repeat({size_x}, minmax(0, 2.6em)); gap: 3px;
  flex: 0 1 auto; min-width: 0; }}
#map div {{ display: flex; align-items: center; justify-content: center;
  font-size: .75em; color: #777; white-space: nowrap; }}
#map .xlabel {{ height: 2.6em; }}
#map .cell {{ background: #e4e7eb; border-radius: 4px; color: #222; box-sizing: border-box;
  aspect-ratio: 4 / 3; overflow: hidden; container-type: inline-size; }}
#map .cell span {{ font-size: clamp(7px, 34cqi, 1em); }} /* 1em (12 px) at full size */
#map.pressable .cell {{ cursor: pointer; }}
#map.pressable .cell:hover {{ outline: 2px solid #8fb0dc; }}
#map .cell.pressed {{ border: 3px dashed #1a5fb4; }}
.thinned {{ visibility: hidden; }}
#readout {{ flex: 1 0 26em; min-width: 0; }}
#readout p {{ margin: .3em 0; font-size: 1.1em; }}
#readout b {{ display: inline-block; min-width: 9.5em; font-weight: 600; color: #555; }}
#contact.touch {{ color: #b3261e; font-weight: 700; }}
#press {{ margin-top: 1em; border: 1px solid #ccd; border-radius: 6px; max-width: 24em; }}
#press legend {{ font-weight: 600; color: #555; }}
#press p {{ font-size: .95em; }}
#weight {{ width: 6.5em; font-size: 1em; }}
#press-error {{ color: #b3261e; }}
#channels {{ margin: 1.5em 0 0; }}
#channels figcaption {{ font-size: .85em; color: #555; margin-bottom: .4em; }}
#chart {{ display: flex; gap: 6px; height: 8em; }}
#axis {{ width: 3.5em; flex: none; height: 100%; display: flex; flex-direction: column;
  justify-content: space-between; align-items: flex-end; font-size: .7em; color: #555;
  border-right: 1px solid #999; padding-right: 4px; line-height: 0; }}
#bars {{ display: grid; grid-template-columns: repeat({terminals}, minmax(0, 30px)); gap: 3px;
  align-items: end; height: 100%; flex: 0 1 auto; min-width: 0;
  background: linear-gradient(#ccc 1px, transparent 1px) 0 0 / 100% 50%; }}
#bars div {{ background: #4a78b5; min-height: 1px; }}
#barlabels div {{ display: flex; justify-content: center; }} /* a wide label: centred */
#barlabels {{ display: grid; grid-template-columns: repeat({terminals}, minmax(0, 30px));
  gap: 3px; font-size: .7em; color: #777; white-space: nowrap;
  margin-left: calc(3.5em + 11px); }} /* the axis' width, its padding, border and gap */
</style></head>
<body>
<h1>eskin live: <span id="scene">{scene}</span> ({kind}) on <span id="device">{device}</span></h1>
<main>
<div id="map"></div>
<div id="readout">
<p><b>contact</b><span id="contact">waiting for frames</span></p>
<p><b>location</b><span id="location">–</span></p>
<p><b>force</b><span id="force">–</span></p>
<p><b>stretch λ</b><span id="stretch">–</span></p>
<p><b>drift</b><span id="drift">–</span></p>
<p><b>frame</b><span id="seq">–</span></p>
<p><b>frames/s</b><span id="rate">–</span></p>
<p><b>lost, damaged</b><span id="lost">0, 0</span></p>
<p><b>tare</b><span id="tared">–</span></p>
<p><button id="tare" title="the next frames become the untouched reading (key t)">
re-tare (t)</button></p>
{press_panel}
</div>
</main>
<figure id="channels">
<figcaption>each channel's change from the untouched reading, in ADC counts
(the frames' unit; blue above it, grey below)</figcaption>
<div id="chart"><div id="axis"><span id="tick-top">20</span><span id="tick-middle">10</span>
<span>0</span></div><div id="bars"></div></div>
<div id="barlabels"></div>
</figure>
<script>
const pressing = {pressing};
const map = document.getElementById("map");
// A label's text in a span of its own: its width is the text's, wider or not than its slot.
function labelled(parent, text, kind) {{
  const label = document.createElement("div"), span = document.createElement("span");
  span.textContent = text; label.appendChild(span); label.className = kind;
  parent.appendChild(label);
  return label;
}}
map.appendChild(document.createElement("div"));
const xLabels = [], yLabels = [], barLabels = [[]];
for (let x = 1; x <= {size_x}; x++) xLabels.push(labelled(map, "x" + x, "xlabel"));
for (let y = {size_y}; y >= 1; y--) {{
  yLabels.push(labelled(map, "y" + y, "ylabel"));
  for (let x = 1; x <= {size_x}; x++) {{
    const cell = document.createElement("div");
    cell.className = "cell"; cell.id = `cell-${{x}}-${{y}}`; map.appendChild(cell);
    if (pressing) cell.onclick = () => pressAt(x, y);
  }}
}}
const names = {names};
for (const [i, name] of names.entries()) {{
  const bar = document.createElement("div"); bar.id = "bar-" + name;
  document.getElementById("bars").appendChild(bar);
  // a row/column skin's labels in two runs (x1.., y1..), each thinned from its first
  if ({row_column} && i === {size_x}) barLabels.push([]);
  barLabels.at(-1).push(labelled(document.getElementById("barlabels"), name, "barlabel"));
}}
// Many terminals in a narrow window: show every k-th label of a run, k the fewest slots
// its widest label needs (along the run: x across, y down), so that none overlap.
function thin(runs, across) {{
  const all = runs.flat();
  if (all.length < 2) return;
  for (const label of all) label.classList.remove("thinned");
  const place = label => label.getBoundingClientRect();
  const [a, b] = [place(all[0]), place(all[1])];
  const slot = Math.abs(across ? b.left - a.left : b.top - a.top);
  const widest = Math.max(...all.map(label => {{
    const text = place(label.firstChild); return across ? text.width : text.height; }}));
  const k = slot > 0 ? Math.max(1, Math.ceil((widest + 3) / slot)) : 1;
  for (const run of runs) run.forEach((label, i) => label.classList.toggle("thinned", i % k !== 0));
}}
function fit() {{ thin([xLabels], true); thin([yLabels], false); thin(barLabels, true); }}
fit();
addEventListener("resize", fit);
const text = (id, value) => {{ document.getElementById(id).textContent = value; }};
const fixed = (v, digits) => v === null || v === undefined ? "–" : v.toFixed(digits);
// The bars' full height: a round number of counts at or above the largest change (20 at
// least, so that noise stays low), so that the axis reads in plain numbers.
function scaleTop(change) {{
  const most = Math.max(20, ...change.map(Math.abs));
  const power = 10 ** Math.floor(Math.log10(most));
  return [1, 2, 5, 10].map(step => step * power).find(top => top >= most);
}}
let marked = [], first = null, pressed = [];
function showPressed(weights) {{
  pressed = weights || [];
  for (const cell of document.querySelectorAll(".cell.pressed")) cell.classList.remove("pressed");
  for (const w of pressed) {{
    const cell = document.getElementById(`cell-${{w.x}}-${{w.y}}`);
    if (cell) cell.classList.add("pressed");
  }}
  if (pressing) text("pressed", pressed.length === 0 ? "nothing pressed"
    : pressed.map(w => `${{w.force_n}} N on x ${{w.x}}, y ${{w.y}}`).join("; "));
}}
function show(state) {{
  if (state.tare) text("tared", state.tare.reason === "request"
    ? `again at frame ${{state.tare.at_seq}}, on ${{state.tare.frames}} frames`
    : `${{state.tare.frames}} frames at start`);
  if (state.taring) text("tared", "taring: keep the skin untouched");
  showPressed(state.pressed);
  const e = state.estimate;
  if (!e) return;
  for (const cell of marked) {{ cell.style.background = ""; cell.replaceChildren(); }}
  marked = [];
  // two contacts under one force sensor: their total force, none per contact
  const total = !("x" in e) && "force" in e;
  // a counting stack (two contacts, trained with fewer) says how many press: those first
  const contacts = ("x" in e ? [[e.x, e.y, e.force]]
    : [[e.x1, e.y1, total ? null : e.force1], [e.x2, e.y2, total ? null : e.force2]])
    .slice(0, "contacts" in e ? (e.contacts || 0) : undefined);
  const touching = "contact" in e ? e.contact : true;
  if (touching) for (const [x, y, f] of contacts) {{
    const cell = document.getElementById(`cell-${{x}}-${{y}}`);
    if (!cell) continue;
    const shade = total ? (e.force || 0) / 2 : (f || 0);
    const strength = Math.max(0.25, Math.min(1, shade / 6));
    cell.style.background = `rgba(179, 38, 30, ${{strength}})`;
    const force = document.createElement("span");  // sized to the cell (its CSS)
    force.textContent = total ? "" : `${{fixed(f, 1)}} N`;
    cell.replaceChildren(force);
    marked.push(cell);
  }}
  const contact = document.getElementById("contact");
  contact.className = touching ? "touch" : "";
  contact.textContent = (!touching ? "no touch" : !("contacts" in e) ? "touch"
    : `${{e.contacts}} contact${{e.contacts === 1 ? "" : "s"}}`) +
    (e.contact_probability === null || e.contact_probability === undefined ? ""
     : ` (p = ${{e.contact_probability.toFixed(3)}})`);
  text("location", touching ? contacts.map(([x, y]) => `x ${{x}}, y ${{y}}`).join("; ") : "–");
  text("force", !touching ? "0 N"
    : total ? `${{fixed(e.force, 2)}} N in all (the training recording gave no force per contact)`
    : contacts.map(([, , f]) => `${{fixed(f, 2)}} N`).join("; "));
  text("stretch", fixed(e.stretch, 3));
  text("drift", `${{fixed(e.drift_counts, 1)}} counts`);
  text("seq", `${{e.seq}} (t = ${{(e.t_ms / 1000).toFixed(2)}} s)`);
  if (first === null) first = [e.seq, e.t_ms];
  else if (e.t_ms > first[1])
    text("rate", ((e.seq - first[0]) / (e.t_ms - first[1]) * 1000).toFixed(1));
  text("lost", `${{state.lost}}, ${{state.rejected}}`);
  const change = e.change_counts || [];
  const top = scaleTop(change);
  text("tick-top", `${{top}}`);
  text("tick-middle", `${{top / 2}}`);
  change.forEach((v, i) => {{
    const bar = document.getElementById("bar-" + names[i]);
    bar.style.height = `${{Math.abs(v) / top * 100}}%`;
    bar.style.background = v < 0 ? "#999" : "#4a78b5";
    bar.title = `${{names[i]}}: ${{v.toFixed(1)}} counts`;
  }});
}}
// Re-tare: the next frames become the untouched reading (keep the skin untouched).
const tare = () => fetch("/tare", {{method: "POST"}});
document.getElementById("tare").onclick = tare;
// Press: the weight set on the page on a clicked node; a click on a pressed node lifts it.
async function press(body) {{
  const answer = await fetch("/press", {{method: "POST", body: JSON.stringify(body),
                                        headers: {{"Content-Type": "application/json"}}}});
  const reply = await answer.json();
  text("press-error", answer.ok ? "" : reply.error);
  if (answer.ok) showPressed(reply.pressed);
}}
function pressAt(x, y) {{
  if (pressed.some(w => w.x === x && w.y === y)) return press({{x, y, release: true}});
  return press({{x, y, force_n: Number(document.getElementById("weight").value)}});
}}
if (pressing) document.getElementById("release").onclick = () => press({{release: true}});
document.addEventListener("keydown", event => {{
  if (event.target.tagName === "INPUT") return;
  if (event.key === "t") tare();
  if (event.key === "r" && pressing) press({{release: true}});
}});
if (pressing) map.classList.add("pressable");
const events = new EventSource("/events");
events.onmessage = message => show(JSON.parse(message.data));
</script>
</body></html>
"""

# The page's press controls: on the simulated board, and instead of them on a real one.
PRESS_PANEL = """<fieldset id="press"><legend>press the simulated skin</legend>
<p><label>weight <input id="weight" type="number" min="{lightest}" max="{heaviest}"
step="any" value="{weight}" list="levels"> N</label>
<datalist id="levels">{levels}</datalist></p>
<p>Click a node to lay the weight on it ({weights}); click it again, or
<button id="release" title="lift every weight (key r)">release (r)</button>, to lift it.
The trained levels: {named_levels}.</p>
<p><b>pressed</b><span id="pressed">nothing pressed</span></p>
<p id="press-error"></p>
</fieldset>"""
NO_PRESS_PANEL = """<p id="press-off">Pressing from this page needs the simulated board
(<code>eskin live {scene} --simulated</code>): it drives the simulated skin through the
board's <code>SIM</code> commands, which a real board has not got. Press this skin by
hand.</p>"""


@dataclass(frozen=True)
class Weight:
    """A weight lying on node (x, y) of the simulated skin."""

    x: int
    y: int
    force_n: float

    def as_dict(self) -> dict[str, Any]:
        return {"x": self.x, "y": self.y, "force_n": self.force_n}


@dataclass(frozen=True)
class Pressing:
    """How the page may press the simulated skin: the weight it offers first, the scene's
    trained levels (N), how many weights may lie at once (the scene's contacts), and the
    heaviest the board takes."""

    weight_n: float
    levels: tuple[float, ...]
    contacts: int = 1
    max_n: float = 50.0

    @classmethod
    def of_scene(cls, forces: Sequence[float], contacts: int, *, max_n: float) -> Pressing:
        """The scene's heaviest level first: a light weight reads through its seating, and
        its estimate is the least sure (docs/simulator.md)."""
        levels = tuple(sorted({float(f) for f in forces if f > 0}))
        return cls(levels[-1] if levels else 1.0, levels, contacts, max_n)

    def panel(self) -> str:
        weights = ("one weight at a time: a click elsewhere moves it" if self.contacts == 1
                   else f"up to {self.contacts} weights; a further click lifts the oldest")
        return PRESS_PANEL.format(
            weight=self.weight_n, lightest=min(0.1, self.weight_n), heaviest=self.max_n,
            weights=weights,
            levels="".join(f'<option value="{level}">' for level in self.levels),
            named_levels=", ".join(f"{level:g}" for level in self.levels) + " N"
            if self.levels else "none declared")


@dataclass(frozen=True)
class PressRequest:
    """What ``POST /press`` asks: lay ``force_n`` on (x, y), or lift the weight there
    (``release``), or lift every weight (``release`` and no node)."""

    x: int | None = None
    y: int | None = None
    force_n: float | None = None

    @property
    def release(self) -> bool:
        return self.force_n is None

    @classmethod
    def parse(cls, body: bytes, skin: AnySkin, pressing: Pressing) -> PressRequest:
        """The request in ``body``, or ValueError saying what is wrong with it."""
        example = ('{"x": 6, "y": 4, "force_n": 5.2}, {"x": 6, "y": 4, "release": true} '
                   'or {"release": true}')
        try:
            message = json.loads(body)
        except (ValueError, UnicodeDecodeError):
            raise ValueError(f"not JSON: send {example}") from None
        if not isinstance(message, dict):
            raise ValueError(f"not a JSON object: send {example}")
        node = [message.get(name) for name in ("x", "y")]
        if message.get("release") is True and node == [None, None]:
            return cls()
        for name, value, top in (("x", node[0], skin.size_x), ("y", node[1], skin.size_y)):
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= top:
                raise ValueError(f"{name} {value!r} is no node of the {skin.describe()}: "
                                 f"{name} is a whole number 1..{top}")
        if message.get("release") is True:
            return cls(*node)
        force = message.get("force_n")
        if isinstance(force, bool) or not isinstance(force, (int, float)) \
                or not math.isfinite(force) or not 0 < force <= pressing.max_n:
            raise ValueError(f"force_n {force!r}: give the weight in newtons, more than 0 "
                             f"and at most {pressing.max_n:g} (the board's heaviest)")
        return cls(*node, float(force))

    def applied_to(self, weights: list[Weight], contacts: int) -> list[Weight]:
        """The weights that lie once this request is carried out."""
        if self.x is None:
            return []
        kept = [w for w in weights if (w.x, w.y) != (self.x, self.y)]
        if self.release:
            return kept
        return [*kept, Weight(self.x, self.y, self.force_n)][-contacts:]


def sim_commands(before: list[Weight], after: list[Weight]) -> list[str]:
    """The simulated board's commands that take its weights from ``before`` to ``after``.
    It lifts weights only all at once (``SIM CLEAR``), so those that stay are laid again,
    at once; a new one ramps in (:data:`PRESS_RAMP_MS`)."""
    return ["SIM CLEAR", *(f"SIM PRESS {w.x} {w.y} {w.force_n!r}"
                           + ("" if w in before else f" {PRESS_RAMP_MS}") for w in after)]


class PressRefused(EskinError):
    """A press the view could not carry out: ``status`` is the HTTP status it answers."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


def bar_names(skin: AnySkin) -> list[str]:
    """Each channel's bar label: a row/column skin's terminals as the map names them (x1..xR,
    y1..yC), a channel array's channels by their own names."""
    return [c.removeprefix("c") for c in skin.channels] if skin.row_column else skin.channels


class LiveView:
    """Serve the page; :meth:`show` each record of :func:`eskin.deploy.live.live_estimates`."""

    def __init__(self, *, scene: str, kind: str, device: str, skin: AnySkin,
                 port: int = 0, pressing: Pressing | None = None) -> None:
        """``pressing``: the page may press the skin (the simulated board only)."""
        panel = NO_PRESS_PANEL.format(scene=scene) if pressing is None else pressing.panel()
        self.page = PAGE.format(scene=scene, kind=kind, device=device, size_x=skin.size_x,
                                size_y=skin.size_y, terminals=skin.terminals,
                                names=json.dumps(bar_names(skin)), press_panel=panel,
                                row_column=json.dumps(skin.row_column),
                                pressing=json.dumps(pressing is not None)).encode()
        self.skin, self.pressing = skin, pressing
        self._state: dict[str, Any] = {"estimate": None, "lost": 0, "rejected": 0, "tare": None,
                                       "taring": False, "pressed": []}
        self._requests: list[str] = []
        self._presses: list[tuple[PressRequest, Future]] = []
        self._weights: list[Weight] = []
        self._version = 0
        self._changed = threading.Condition()
        self._closed = False
        view = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args: object) -> None:  # no access log on stderr
                pass

            def do_GET(self) -> None:  # noqa: N802 - http.server's name
                if self.path == "/":
                    self._send(200, "text/html; charset=utf-8", view.page)
                elif self.path == "/state":
                    self._send(200, "application/json", view.state_json().encode())
                elif self.path == "/events":
                    self._events()
                else:
                    self._send(404, "text/plain", b"not found\n")

            def do_POST(self) -> None:  # noqa: N802 - http.server's name
                if self.path == "/tare":
                    view.request("tare")
                    self._send(202, "application/json", b'{"requested":"tare"}')
                elif self.path == "/press":
                    try:
                        weights = view.press(self._body())
                    except PressRefused as err:
                        self._send(err.status, "application/json",
                                   json.dumps({"error": str(err)}).encode())
                    else:
                        self._send(200, "application/json",
                                   json.dumps({"pressed": weights}).encode())
                else:
                    self._send(404, "text/plain", b"not found\n")

            def _body(self) -> bytes:
                try:
                    length = int(self.headers.get("Content-Length", "0"))
                except ValueError:
                    length = -1
                if not 0 <= length <= MAX_BODY_BYTES:
                    raise PressRefused(400, f"a press request is a JSON object of at most "
                                       f"{MAX_BODY_BYTES} bytes, with its Content-Length")
                return self.rfile.read(length)

            def _send(self, status: int, kind: str, body: bytes) -> None:
                self.send_response(status)
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(body)

            def _events(self) -> None:
                self.send_response(200)
                self.send_header("Content-Type", "text/event-stream")
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                try:
                    seen = -1
                    while not view._closed:
                        with view._changed:
                            last = seen
                            view._changed.wait_for(
                                lambda last=last: view._version != last or view._closed,
                                KEEPALIVE_S)
                            fresh, seen = view._version != seen, view._version
                            data = view.state_json()
                        message = f"data: {data}\n\n" if fresh else ": idle\n\n"
                        self.wfile.write(message.encode())
                        self.wfile.flush()
                except (BrokenPipeError, ConnectionResetError):
                    return  # the browser went away

        self._server = ThreadingHTTPServer(("127.0.0.1", port), Handler)
        self._server.daemon_threads = True
        self.port = self._server.server_address[1]
        self.url = f"http://127.0.0.1:{self.port}/"
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True)
        self._thread.start()

    def request(self, command: str) -> None:
        """A command from the page (the re-tare button, key t), for :meth:`requests`."""
        with self._changed:
            self._requests.append(command)
            self._state["taring"] = command == "tare" or self._state["taring"]
            self._version += 1
            self._changed.notify_all()

    def requests(self) -> list[str]:
        """The commands the page sent since the last call (live_estimates' ``requests``)."""
        with self._changed:
            out, self._requests = self._requests, []
        return out

    def press(self, body: bytes, *, wait_s: float = PRESS_WAIT_S) -> list[dict[str, Any]]:
        """Carry out the press request ``body`` (``POST /press``) through the live loop
        (:meth:`carry_out_presses`), and give the weights that lie after it; PressRefused
        (with the HTTP status to answer) when it is not carried out."""
        if self.pressing is None:
            raise PressRefused(409, "this live view reads a real board, pressed by hand: "
                               "pressing from the view needs `eskin live --simulated`")
        try:
            request = PressRequest.parse(body, self.skin, self.pressing)
        except ValueError as err:
            raise PressRefused(400, str(err)) from None
        with self._changed:
            # The start tare's record can reach the view a batch before the first estimate
            # (a batch ending on the tare's last frame), and the page shows the tare done:
            # a press sent in between waits for that estimate instead of being refused.
            self._changed.wait_for(lambda: self._state["estimate"] is not None
                                   or self._state["taring"] or self._state["tare"] is None,
                                   timeout=wait_s)
            if self._state["estimate"] is None or self._state["taring"]:
                raise PressRefused(409, "the tare is under way: keep the skin untouched, "
                                   "and press once the view shows frames")
            done: Future = Future()
            self._presses.append((request, done))
        wait([done], timeout=wait_s)
        if done.cancel():  # not taken in time, and now it never will be
            raise PressRefused(504, f"the live loop did not take the press within "
                               f"{wait_s:g} s: is the board streaming?")
        try:
            return done.result(timeout=wait_s)  # taken: carried out, or about to be
        except Exception as err:  # the board refused, or the link failed
            raise PressRefused(502, f"the board did not take the press: {err}") from None

    def carry_out_presses(self, send: Callable[[str], object]) -> None:
        """Send the board the commands of the press requests waiting (``send``: the live
        loop's ``link.command``, between two batches of the stream, on the loop's thread);
        each requester is told the weights that lie after it, or why it failed."""
        with self._changed:
            waiting, self._presses = self._presses, []
        for request, done in waiting:
            if not done.set_running_or_notify_cancel():
                continue  # its requester stopped waiting
            wanted = request.applied_to(self._weights, self.pressing.contacts)
            laid: list[Weight] | None = None  # None until the board's weights are lifted
            try:
                for command, weight in zip(sim_commands(self._weights, wanted),
                                           [None, *wanted], strict=True):
                    send(command)
                    laid = [] if weight is None else [*laid, weight]
            except BaseException as err:
                self._lay(self._weights if laid is None else laid)  # what the board has
                done.set_exception(err)
                if not isinstance(err, EskinError):
                    raise
            else:
                self._lay(laid)
                done.set_result([w.as_dict() for w in laid])

    def _lay(self, weights: list[Weight]) -> None:
        with self._changed:
            self._weights = weights
            self._state["pressed"] = [w.as_dict() for w in weights]
            self._version += 1
            self._changed.notify_all()

    def state_json(self) -> str:
        return json.dumps(self._state, separators=(",", ":"), allow_nan=False)

    def show(self, record: dict[str, Any]) -> None:
        with self._changed:
            if "seq" in record:
                self._state["estimate"] = record
            elif "gap" in record:
                self._state["lost"] += record["gap"]["lost"]
            elif "rejected" in record:
                self._state["rejected"] += 1
            elif "tare" in record:
                self._state["tare"] = record["tare"]
                self._state["taring"] = False
            self._version += 1
            self._changed.notify_all()

    def close(self) -> None:
        with self._changed:
            self._closed = True
            self._changed.notify_all()
        self._server.shutdown()
        self._server.server_close()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def press_on_view(port: int, request: dict[str, Any], *, timeout_s: float = 2 * PRESS_WAIT_S
                  ) -> list[dict[str, Any]]:
    """``POST /press`` to the live view on 127.0.0.1:``port`` (``eskin press``): the
    weights that lie after it, or an EskinError saying in one line why not."""
    import http.client
    import urllib.error
    import urllib.request

    where = f"127.0.0.1:{port}"
    call = urllib.request.Request(f"http://{where}/press", data=json.dumps(request).encode(),
                                  headers={"Content-Type": "application/json"}, method="POST")
    try:
        with urllib.request.urlopen(call, timeout=timeout_s) as answer:
            return json.loads(answer.read())["pressed"]
    except urllib.error.HTTPError as err:
        try:
            said = json.loads(err.read())["error"]
        except (ValueError, KeyError, TypeError):
            said = (f"it answered {err.code} {err.reason} to POST /press: is it an eskin "
                    "live view (`eskin live --view`) of this version?")
        raise EskinError(f"the live view on {where}: {said}") from None
    except urllib.error.URLError as err:
        reason = getattr(err.reason, "strerror", None) or err.reason
        raise EskinError(f"no live view on {where} ({reason}): start one with `eskin live "
                         f"<scene> --simulated --view {port}`, or give its port with "
                         "--view PORT") from None
    except (http.client.HTTPException, ConnectionError, ValueError, KeyError) as err:
        raise EskinError(f"{where} is not an eskin live view (it answered POST /press "
                         f"with {type(err).__name__}): give the view's port with --view "
                         "PORT") from None
    except TimeoutError:
        raise EskinError(f"the live view on {where} did not answer within {timeout_s:g} s")\
            from None

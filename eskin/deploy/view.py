"""The live view: a page on 127.0.0.1 showing what the stack makes of each frame.

A person pressing the skin looks at it: the skin's map of nodes (size_x × size_y: R × C on
a row/column skin, 10 × 10 on the paper's) with the estimated contact(s)
(marked by force), the force, the location, the stretch, whether there is contact and
how sure the detector is, the drift since the tare, every channel's change from the
untouched reading as bars on an axis in ADC counts, and the frame rate; a button (and
the key t) asks for a re-tare (``POST /tare``). The page holds an ``EventSource`` on
``/events``; every client is sent the newest state only (a slow browser skips frames,
nothing queues), and ``/state`` answers it once as JSON.

A page, not a terminal view: it draws the map as the skin is laid out, any machine on the
bench can open it (through an SSH tunnel: it binds to 127.0.0.1 only), and it is tested
the way the report page is, in headless Chromium, reading what the page shows.
"""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from eskin.skin import AnySkin

KEEPALIVE_S = 10.0  # an idle stream sends a comment this often, so a dead client is noticed

PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>eskin live: {scene}</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 1.5em; background: #fafafa; color: #222; }}
h1 {{ font-size: 1.2em; margin: 0 0 .8em; }}
main {{ display: flex; gap: 2em; align-items: flex-start; }}
#map {{ display: grid; grid-template-columns: 1.6em repeat({size_x}, 2.6em); gap: 3px; }}
#map div {{ height: 2.6em; display: flex; align-items: center; justify-content: center;
  font-size: .75em; color: #777; }}
#map .cell {{ background: #e4e7eb; border-radius: 4px; color: #222; }}
#readout {{ min-width: 17em; }}
#readout p {{ margin: .3em 0; font-size: 1.1em; }}
#readout b {{ display: inline-block; min-width: 9.5em; font-weight: 600; color: #555; }}
#contact.touch {{ color: #b3261e; font-weight: 700; }}
#channels {{ margin: 1.5em 0 0; }}
#channels figcaption {{ font-size: .85em; color: #555; margin-bottom: .4em; }}
#chart {{ display: flex; gap: 6px; height: 8em; }}
#axis {{ width: 3.5em; height: 100%; display: flex; flex-direction: column;
  justify-content: space-between; align-items: flex-end; font-size: .7em; color: #555;
  border-right: 1px solid #999; padding-right: 4px; line-height: 0; }}
#bars {{ display: grid; grid-template-columns: repeat({terminals}, 30px); gap: 3px;
  align-items: end; height: 100%;
  background: linear-gradient(#ccc 1px, transparent 1px) 0 0 / 100% 50%; }}
#bars div {{ background: #4a78b5; min-height: 1px; }}
#barlabels {{ display: grid; grid-template-columns: repeat({terminals}, 30px); gap: 3px;
  font-size: .7em; color: #777; text-align: center;
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
const map = document.getElementById("map");
map.appendChild(document.createElement("div"));
for (let x = 1; x <= {size_x}; x++) {{
  const label = document.createElement("div"); label.textContent = "x" + x; map.appendChild(label);
}}
for (let y = {size_y}; y >= 1; y--) {{
  const label = document.createElement("div"); label.textContent = "y" + y; map.appendChild(label);
  for (let x = 1; x <= {size_x}; x++) {{
    const cell = document.createElement("div");
    cell.className = "cell"; cell.id = `cell-${{x}}-${{y}}`; map.appendChild(cell);
  }}
}}
const names = {names};
for (const name of names) {{
  const bar = document.createElement("div"); bar.id = "bar-" + name;
  document.getElementById("bars").appendChild(bar);
  const label = document.createElement("div"); label.textContent = name;
  document.getElementById("barlabels").appendChild(label);
}}
const text = (id, value) => {{ document.getElementById(id).textContent = value; }};
const fixed = (v, digits) => v === null || v === undefined ? "–" : v.toFixed(digits);
// The bars' full height: a round number of counts at or above the largest change (20 at
// least, so that noise stays low), so that the axis reads in plain numbers.
function scaleTop(change) {{
  const most = Math.max(20, ...change.map(Math.abs));
  const power = 10 ** Math.floor(Math.log10(most));
  return [1, 2, 5, 10].map(step => step * power).find(top => top >= most);
}}
let marked = [], first = null;
function show(state) {{
  if (state.tare) text("tared", state.tare.reason === "request"
    ? `again at frame ${{state.tare.at_seq}}, on ${{state.tare.frames}} frames`
    : `${{state.tare.frames}} frames at start`);
  if (state.taring) text("tared", "taring: keep the skin untouched");
  const e = state.estimate;
  if (!e) return;
  for (const cell of marked) {{ cell.style.background = ""; cell.textContent = ""; }}
  marked = [];
  // two contacts under one force sensor: their total force, none per contact
  const total = !("x" in e) && "force" in e;
  const contacts = "x" in e ? [[e.x, e.y, e.force]]
    : [[e.x1, e.y1, total ? null : e.force1], [e.x2, e.y2, total ? null : e.force2]];
  const touching = "contact" in e ? e.contact : true;
  if (touching) for (const [x, y, f] of contacts) {{
    const cell = document.getElementById(`cell-${{x}}-${{y}}`);
    if (!cell) continue;
    const shade = total ? (e.force || 0) / 2 : (f || 0);
    const strength = Math.max(0.25, Math.min(1, shade / 6));
    cell.style.background = `rgba(179, 38, 30, ${{strength}})`;
    cell.textContent = total ? "" : `${{fixed(f, 1)}} N`;
    marked.push(cell);
  }}
  const contact = document.getElementById("contact");
  contact.className = touching ? "touch" : "";
  contact.textContent = (touching ? "touch" : "no touch") +
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
document.addEventListener("keydown", event => {{ if (event.key === "t") tare(); }});
const events = new EventSource("/events");
events.onmessage = message => show(JSON.parse(message.data));
</script>
</body></html>
"""


def bar_names(skin: AnySkin) -> list[str]:
    """Each channel's bar label: a row/column skin's terminals as the map names them (x1..xR,
    y1..yC), a channel array's channels by their own names."""
    return [c.removeprefix("c") for c in skin.channels] if skin.row_column else skin.channels


class LiveView:
    """Serve the page; :meth:`show` each record of :func:`eskin.deploy.live.live_estimates`."""

    def __init__(self, *, scene: str, kind: str, device: str, skin: AnySkin,
                 port: int = 0) -> None:
        self.page = PAGE.format(scene=scene, kind=kind, device=device, size_x=skin.size_x,
                                size_y=skin.size_y, terminals=skin.terminals,
                                names=json.dumps(bar_names(skin))).encode()
        self._state: dict[str, Any] = {"estimate": None, "lost": 0, "rejected": 0, "tare": None,
                                       "taring": False}
        self._requests: list[str] = []
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
                else:
                    self._send(404, "text/plain", b"not found\n")

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

"""Transports for the simulated board: a pseudo-terminal or a loopback TCP socket.

Thin shells around :class:`~eskin.device.board.SimulatedBoard` behind a
:class:`~eskin.device.faults.FaultyLine`: they move bytes, split command
lines, write answers and act out the line's stalls and disappearances. ``eskin device simulate``
runs one in its own process and prints the port to open with pyserial —
a pty path such as ``/dev/pts/7`` or ``socket://127.0.0.1:PORT``.
"""

from __future__ import annotations

import errno
import os
import select
import socket
import sys
import time
import tty
from collections.abc import Callable, Iterator
from pathlib import Path

from eskin.device.board import SimulatedBoard
from eskin.device.faults import Chunk, FaultyLine, Pause
from eskin.device.protocol import MAX_LINE_BYTES

LOOPBACK = "127.0.0.1"


class _LineServer:
    """Feeds command lines to the board and collects what it answers, through the faults."""

    def __init__(self, line: FaultyLine) -> None:
        self.line = line
        self._pending = bytearray()
        self._next_stream = 0.0

    @property
    def board(self) -> SimulatedBoard:
        return self.line.board  # a reset fault replaces it

    def received(self, data: bytes) -> list[Chunk]:
        self._pending += data
        out: list[Chunk] = []
        while (end := self._pending.find(b"\n")) >= 0:
            line = bytes(self._pending[:end])
            del self._pending[: end + 1]
            self.line.asked(line)
            out += self.line.answer(self.board.handle(line))
        if len(self._pending) > MAX_LINE_BYTES:
            self._pending.clear()
            out.append(b"#ERR ? line too long\n")
        return out

    def idle(self) -> list[Chunk]:
        """While streaming, one frame per frame period of real time."""
        if not self.board.streaming:
            return []
        now = time.monotonic()
        if now < self._next_stream:
            return []
        self._next_stream = now + self.board.frame_period_ms / 1000
        return self.line.answer(self.board.frames(1))

    def timeout(self) -> float:
        return self.board.frame_period_ms / 1000 if self.board.streaming else 0.5


def _orphaned(parent: int) -> bool:
    """True once the process that started us is gone (killed, even by SIGKILL)."""
    return os.getppid() != parent


def _play(chunks: list[Chunk], write: Callable[[bytes], int]) -> float | None:
    """Write the bytes, sit out the stalls; the seconds to stay away if the port vanishes."""
    for chunk in chunks:
        if isinstance(chunk, Pause):
            if chunk.vanish:
                return chunk.seconds
            time.sleep(chunk.seconds)
            continue
        view = memoryview(chunk)
        while view:
            view = view[write(view):]
    return None


def _new_pty(link: Path | None) -> tuple[int, int, str]:
    """A raw pty (master, slave, slave path); ``link``, if given, now points to it."""
    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    if link is not None:
        # Like a udev /dev/serial/by-id name: one path that follows the device.
        staged = link.with_name(link.name + ".new")
        staged.unlink(missing_ok=True)
        staged.symlink_to(path)
        os.replace(staged, link)
    return master, slave, path


def serve_pty(line: FaultyLine, announce: Callable[[str], None], *,
              link: Path | None = None) -> None:
    """Serve on a pseudo-terminal until killed or orphaned; announce its path first.

    The board keeps the slave end open too, so the port survives the host
    closing and reopening it, as a USB adapter that stays plugged in does.
    With ``link``, the announced port is that path, a symlink to the current
    pty: when a ``vanish`` fault closes the pty, the link disappears, and it
    comes back pointing at a new pty, as a re-plugged adapter's by-id name does.
    """
    if line.faults.vanish and link is None:
        raise ValueError("vanish faults need a link path that follows the pty (--link)")
    parent = os.getppid()
    server = _LineServer(line)
    master, slave, path = _new_pty(link)
    announce(str(link) if link is not None else path)
    try:
        while True:
            away = _serve_pty_until_vanish(master, server, parent)
            if away is not None and link is not None:
                link.unlink(missing_ok=True)  # gone before the pty closes: no dangling path
            os.close(master)
            os.close(slave)
            if away is None:
                return
            time.sleep(away)
            master, slave, path = _new_pty(link)
    finally:
        line.close()


def _serve_pty_until_vanish(master: int, server: _LineServer, parent: int) -> float | None:
    def write(data: memoryview) -> int:
        return os.write(master, data)

    _play([server.board.hello()], write)
    while not _orphaned(parent):
        ready, _, _ = select.select([master], [], [], server.timeout())
        if ready:
            try:
                data = os.read(master, 4096)
            except OSError as err:  # EIO: no reader on the slave side
                if err.errno != errno.EIO:
                    raise
                time.sleep(0.05)
                continue
            away = _play(server.received(data), write)
            if away is not None:
                return away
        away = _play(server.idle(), write)
        if away is not None:
            return away
    return None


def serve_socket(line: FaultyLine, port: int, announce: Callable[[str], None]) -> None:
    """Serve one client at a time on 127.0.0.1 only; announce the pyserial URL.
    A ``vanish`` fault drops the connection and accepts none for ``vanish_s``."""
    parent = os.getppid()
    server = _LineServer(line)
    try:
        with socket.create_server((LOOPBACK, port)) as listener:
            announce(f"socket://{LOOPBACK}:{listener.getsockname()[1]}")
            listener.settimeout(0.5)
            while not _orphaned(parent):
                try:
                    conn, _ = listener.accept()
                    conn.settimeout(None)
                except TimeoutError:
                    continue
                # The board writes each line as it is ready (a frame, an #OK), as a UART
                # does. With Nagle's algorithm a small write waits for the ACK of the one
                # before, which the host delays up to 40 ms: 44 ms per SIM CLEAR + SAMPLE
                # 20 on loopback, against 1.7 ms on a pty (docs/acquisition.md).
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                with conn:
                    away = _serve_connection(conn, server, parent)
                if away:
                    time.sleep(away)
    finally:
        line.close()


def _serve_connection(conn: socket.socket, server: _LineServer, parent: int) -> float | None:
    conn.sendall(server.board.hello())
    while not _orphaned(parent):
        ready, _, _ = select.select([conn], [], [], server.timeout())
        if ready:
            try:
                data = conn.recv(4096)
            except ConnectionResetError:
                return None
            if not data:
                return None
            away = _play(server.received(data), conn.send)
            if away is not None:
                return away
        away = _play(server.idle(), conn.send)
        if away is not None:
            return away
    return None


def accelerated_stream(board: SimulatedBoard, *, batch_frames: int) -> Iterator[list]:
    """The frames ``board`` streams, as the transports send them (one ``frames(1)`` a
    frame period, so the same readings), without waiting out the periods: batches of
    ``batch_frames`` stream events, parsed as the host parses them. A command the caller
    gives ``board.handle`` between batches (``SIM PRESS``, ``STRETCH``) acts from the next
    batch on: an hour of the live stack on the simulated skin in minutes (tests, make
    bench's live hour)."""
    from eskin.device.host import StreamFrame
    from eskin.device.protocol import parse_line

    while True:
        yield [StreamFrame(parse_line(board.frames(1).rstrip(b"\n"), board.skin.terminals))
               for _ in range(batch_frames)]


def live_board(params, skin) -> SimulatedBoard:
    """The board `eskin live --simulated` streams, in this process: params.yaml's ``sim``,
    ``sim_board`` frame period and the rig's rest length (``params``, an
    :class:`eskin.config.Params`), on ``skin`` (the stack's). For the live hour and the
    tests, with :func:`accelerated_stream`."""
    from eskin.device.physics import skin_params

    return SimulatedBoard(skin_params(params.sim), skin=skin,
                          rest_length_mm=float(params.acquire.rest_length_mm),
                          frame_period_ms=int(params.sim_board.frame_period_ms))


def announce_stdout(port: str) -> None:
    """First stdout line is the port: what a parent process reads to connect."""
    sys.stdout.write(port + "\n")
    sys.stdout.flush()


def serve_config(config: dict, *, socket_port: int | None = None,
                 link: Path | None = None) -> None:
    """Serve the simulated board ``config`` describes (``sim``, ``skin``, ``rest_length_mm``,
    ``corrupt_fraction``, ``frame_period_ms``, ``faults``) on a pty, or on a loopback
    socket, announcing the port on stdout; until the parent process is gone. ``skin`` is
    as params.yaml declares one (``{rows, columns}``); none is the paper's."""
    from eskin.device.faults import LinkFaults
    from eskin.device.physics import SkinParams
    from eskin.skin import skin_from_dict

    sim = SkinParams.from_mapping(config["sim"])
    skin = skin_from_dict(config.get("skin"))

    def power_on() -> SimulatedBoard:  # again after every injected reset
        return SimulatedBoard(sim, skin=skin, rest_length_mm=config["rest_length_mm"],
                              corrupt_fraction=config["corrupt_fraction"],
                              frame_period_ms=config["frame_period_ms"])

    line = FaultyLine(power_on, LinkFaults.from_mapping(config.get("faults")))
    try:
        if socket_port is not None:
            serve_socket(line, socket_port, announce_stdout)
        else:
            serve_pty(line, announce_stdout, link=link)
    except KeyboardInterrupt:
        pass


def main(argv: list[str] | None = None) -> int:
    """``python -m eskin.device.simulate --config-json JSON [--socket PORT | --link PATH]``:
    the acquisition's own board process (``eskin device simulate`` is the user's)."""
    import argparse
    import json

    parser = argparse.ArgumentParser(prog="python -m eskin.device.simulate")
    parser.add_argument("--config-json", required=True)
    parser.add_argument("--socket", type=int)
    parser.add_argument("--link", type=Path)
    args = parser.parse_args(argv)
    serve_config(json.loads(args.config_json), socket_port=args.socket, link=args.link)
    return 0


if __name__ == "__main__":
    sys.exit(main())

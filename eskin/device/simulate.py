"""Transports for the simulated board: a pseudo-terminal or a loopback TCP socket.

Thin shells around :class:`~eskin.device.board.SimulatedBoard`: they move
bytes, split command lines and write answers. ``eskin device simulate``
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
from collections.abc import Callable

from eskin.device.board import SimulatedBoard
from eskin.device.protocol import MAX_LINE_BYTES

LOOPBACK = "127.0.0.1"


class _LineServer:
    """Feeds command lines to the board and collects what it answers."""

    def __init__(self, board: SimulatedBoard) -> None:
        self.board = board
        self._pending = bytearray()
        self._next_stream = 0.0

    def received(self, data: bytes) -> bytes:
        self._pending += data
        out = []
        while (end := self._pending.find(b"\n")) >= 0:
            line = bytes(self._pending[:end])
            del self._pending[: end + 1]
            out.append(self.board.handle(line))
        if len(self._pending) > MAX_LINE_BYTES:
            self._pending.clear()
            out.append(b"#ERR ? line too long\n")
        return b"".join(out)

    def idle(self) -> bytes:
        """While streaming, one frame per frame period of real time."""
        if not self.board.streaming:
            return b""
        now = time.monotonic()
        if now < self._next_stream:
            return b""
        self._next_stream = now + self.board.frame_period_ms / 1000
        return self.board.frames(1)

    def timeout(self) -> float:
        return self.board.frame_period_ms / 1000 if self.board.streaming else 0.5


def _orphaned(parent: int) -> bool:
    """True once the process that started us is gone (killed, even by SIGKILL)."""
    return os.getppid() != parent


def _write_all(write: Callable[[bytes], int], data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[write(view):]


def serve_pty(board: SimulatedBoard, announce: Callable[[str], None]) -> None:
    """Serve on a new pseudo-terminal until killed or orphaned; announce its path first.

    The board keeps the slave end open too, so the port survives the host
    closing and reopening it, as a USB adapter that stays plugged in does.
    """
    parent = os.getppid()
    master, slave = os.openpty()
    tty.setraw(slave)
    announce(os.ttyname(slave))
    server = _LineServer(board)
    _write_all(lambda b: os.write(master, b), board.hello())
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
            _write_all(lambda b: os.write(master, b), server.received(data))
        _write_all(lambda b: os.write(master, b), server.idle())


def serve_socket(board: SimulatedBoard, port: int, announce: Callable[[str], None]) -> None:
    """Serve one client at a time on 127.0.0.1 only; announce the pyserial URL."""
    parent = os.getppid()
    with socket.create_server((LOOPBACK, port)) as listener:
        announce(f"socket://{LOOPBACK}:{listener.getsockname()[1]}")
        listener.settimeout(0.5)
        while not _orphaned(parent):
            try:
                conn, _ = listener.accept()
                conn.settimeout(None)
            except TimeoutError:
                continue
            with conn:
                conn.sendall(board.hello())
                server = _LineServer(board)
                while not _orphaned(parent):
                    ready, _, _ = select.select([conn], [], [], server.timeout())
                    if ready:
                        try:
                            data = conn.recv(4096)
                        except ConnectionResetError:
                            break
                        if not data:
                            break
                        conn.sendall(server.received(data))
                    conn.sendall(server.idle())


def announce_stdout(port: str) -> None:
    """First stdout line is the port: what a parent process reads to connect."""
    sys.stdout.write(port + "\n")
    sys.stdout.flush()

"""How fast :class:`~eskin.device.link.SerialLink` takes in a board's bytes, and how late.

A board in a thread of this process greets, answers ``STREAM ON``, then sends its stream
over a real port — a loopback ``socket://`` or a pseudo-terminal — and the link reads it
as ``eskin live`` does (:meth:`SerialLink.stream`):

* throughput: ``megabytes`` of frame lines (a streaming board) or of one junk line (a
  broken one), then a last frame as the end mark; bytes taken in per second of wall time,
  from the first byte sent to the end mark's event;
* latency: frames sent one at a time, 12 ms apart (the Python board's period); the time
  from each ``send`` to its event, median and largest.

    PYTHONPATH=. python -m harness.link_throughput [--megabytes 4] [--transport socket pty]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import select
import socket
import statistics
import threading
import time
import tty
from collections.abc import Callable, Iterator

from eskin.device.host import Junk, StreamFrame
from eskin.device.link import SerialLink
from eskin.device.protocol import encode_frame

HELLO = b"#HELLO eskin bench-1 terminals=20 adc_bits=10 id=bench-0001\n"
COUNTS = [512] * 20


def frames_payload(megabytes: float) -> bytes:
    """Frame lines, seq from 0, about ``megabytes`` MB; the last one is the end mark."""
    line = encode_frame(0, 0, COUNTS)
    n = max(2, int(megabytes * 1e6 / len(line)))
    return b"".join(encode_frame(seq, 12 * seq, COUNTS) for seq in range(n))


def junk_payload(megabytes: float) -> bytes:
    """One junk line of about ``megabytes`` MB, then a frame: the end mark."""
    return b"~" * int(megabytes * 1e6) + b"\n" + encode_frame(0, 0, COUNTS)


class _Board:
    """Answers HELLO and STREAM, and on STREAM ON hands the line to ``then``."""

    def __init__(self, then: Callable[[Callable[[bytes], None]], None]) -> None:
        self.then = then
        self.sent_at: list[float] = []

    def serve(self, read: Callable[[], bytes | None], write: Callable[[bytes], None]) -> None:
        inbox = b""
        while True:
            data = read()
            if data is None:
                return
            inbox += data
            while b"\n" in inbox:
                line, inbox = inbox.split(b"\n", 1)
                word = line.strip().upper()
                if word == b"HELLO":
                    write(HELLO)
                elif word.startswith(b"STREAM"):
                    write(b"#OK " + word + b"\n")
                    if word == b"STREAM ON":
                        self.then(write)


@contextlib.contextmanager
def served(board: _Board, transport: str) -> Iterator[str]:
    """``board`` on a loopback socket or a pty, in a thread; yields the port name."""
    stop = threading.Event()
    if transport == "socket":
        listener = socket.create_server(("127.0.0.1", 0))
        port = f"socket://127.0.0.1:{listener.getsockname()[1]}"

        def run() -> None:
            conn, _ = listener.accept()
            # A board's frame goes out when written (no Nagle wait for the last one's ACK).
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

            def read() -> bytes | None:
                ready, _, _ = select.select([conn], [], [], 0.05)
                if not ready:
                    return None if stop.is_set() else b""
                try:
                    return conn.recv(4096) or None
                except OSError:
                    return None

            with conn:
                board.serve(read, conn.sendall)
    else:
        master, slave = os.openpty()
        tty.setraw(slave)
        port = os.ttyname(slave)

        def run() -> None:
            def read() -> bytes | None:
                if stop.is_set():
                    return None
                ready, _, _ = select.select([master], [], [], 0.05)
                return os.read(master, 4096) if ready else b""

            def write(data: bytes) -> None:
                view = memoryview(data)
                while view:
                    select.select([], [master], [], 1.0)
                    view = view[os.write(master, view[:65536]):]

            board.serve(read, write)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        yield port
    finally:
        stop.set()
        thread.join(timeout=5)
        if transport == "socket":
            listener.close()
        else:
            os.close(master)
            os.close(slave)


def throughput(payload: bytes, transport: str, *, timeout_s: float = 120.0) -> dict:
    """MB/s at which the link takes in ``payload`` (its last line a frame: the end mark)."""
    started: list[float] = []

    def blast(write: Callable[[bytes], None]) -> None:
        started.append(time.monotonic())
        write(payload)

    last_seq = int(payload.rstrip(b"\n").rsplit(b"\n", 1)[-1].split(b",")[1])
    board = _Board(blast)
    frames = junk = 0
    with served(board, transport) as port, SerialLink(port, timeout_s=timeout_s) as link:
        link.connect()
        link.start_stream()
        for batch in link.stream():
            frames += sum(isinstance(e, StreamFrame) for e in batch)
            junk += sum(isinstance(e, Junk) for e in batch)
            if any(isinstance(e, StreamFrame) and e.frame.seq == last_seq for e in batch):
                break
        seconds = time.monotonic() - started[0]
        link.stop_stream()
    return {"transport": transport, "bytes": len(payload), "seconds": round(seconds, 3),
            "mb_per_s": round(len(payload) / seconds / 1e6, 2), "frames": frames,
            "junk_events": junk}


def latency(transport: str, *, frames: int = 100, period_s: float = 0.012) -> dict:
    """Milliseconds from a frame's send to its event, frames sent ``period_s`` apart."""
    board = _Board(lambda write: None)
    arrived: dict[int, float] = {}
    with served(board, transport) as port, SerialLink(port, timeout_s=5.0) as link:
        link.connect()

        def trickle(write: Callable[[bytes], None]) -> None:
            def run() -> None:
                for seq in range(frames):
                    board.sent_at.append(time.monotonic())
                    write(encode_frame(seq, 12 * seq, COUNTS))
                    time.sleep(period_s)
            threading.Thread(target=run, daemon=True).start()

        board.then = trickle
        link.start_stream()
        for batch in link.stream():
            now = time.monotonic()
            for event in batch:
                if isinstance(event, StreamFrame):
                    arrived[event.frame.seq] = now
            if frames - 1 in arrived:
                break
        link.stop_stream()
    delays = [(arrived[seq] - board.sent_at[seq]) * 1000 for seq in sorted(arrived)]
    return {"transport": transport, "frames": len(delays),
            "median_ms": round(statistics.median(delays), 3),
            "max_ms": round(max(delays), 3)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--megabytes", type=float, default=4.0)
    parser.add_argument("--transport", nargs="+", default=["socket", "pty"],
                        choices=["socket", "pty"])
    args = parser.parse_args()
    for transport in args.transport:
        for name, payload in (("junk line", junk_payload(args.megabytes)),
                              ("frames", frames_payload(args.megabytes))):
            result = throughput(payload, transport)
            print(f"{transport:6} {name:9}: {result['bytes'] / 1e6:.1f} MB in "
                  f"{result['seconds']:.2f} s = {result['mb_per_s']:.2f} MB/s")
        result = latency(transport)
        print(f"{transport:6} latency  : median {result['median_ms']:.2f} ms, largest "
              f"{result['max_ms']:.2f} ms over {result['frames']} frames 12 ms apart")


if __name__ == "__main__":
    main()

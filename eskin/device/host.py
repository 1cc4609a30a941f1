"""The host side of protocol v1 as a pure state machine (after h11).

Bytes from the board go in through :meth:`HostProtocol.receive`; requests go
out as the bytes :meth:`HostProtocol.send_command`, :meth:`~HostProtocol.send_sample`
or :meth:`~HostProtocol.send_fence` return; what happened comes out as events.
The object never touches a port or a clock: :class:`~eskin.device.link.SerialLink`
moves the bytes, keeps the deadlines and reopens.

The accounting of frames to requests lives here and only here:

* one request is open at a time; it is numbered, and every frame it is
  credited with is a :class:`SampleFrame` carrying that number;
* a frame that arrives while no ``SAMPLE`` is open is :class:`Stray` (a board
  left streaming, a late frame of an earlier request) and is never stored;
* the sequence check runs across requests, never restarting but at a
  ``#HELLO``: a replayed answer goes backwards and is a :class:`Violation`
  (and what was owed is forgotten: a count that went back may be a restart
  whose ``#HELLO`` was lost, glued to a line the reset tore; so the violation
  has ``restart`` set, and the link calls it a restart: the board is told its
  stretch and weights again);
* a frame credited to a ``SAMPLE n`` is placed in its answer by its sequence
  number: its index is its seq less the seq the answer begins at, so a frame
  lost on the line leaves its place empty and the frames after it keep theirs
  (the caller asks again for what is missing, and keeps what came);
* a ``SAMPLE n`` is :class:`SampleComplete` with all n places filled (n frames
  in one unbroken sequence), then ``#OK SAMPLE n``; an ``#OK SAMPLE n`` with
  places empty is :class:`SampleIncomplete`: the board finished its answer, and
  frames were lost on the way. A frame beyond the n-th place, an ``#OK`` for
  another count, a reply to another command: a :class:`Violation`, and the
  request is closed, so everything the board sends after it is stray until the
  next request;
* a ``#HELLO`` from the board the session began with is :class:`Restarted`
  (it forgot its state); from any other board it is :class:`OtherBoard`, and
  nothing that board sends is ever credited to a request; from a board of other
  terminals than the skin the host reads (``terminals``) it is :class:`OtherSkin`,
  at the greeting too, and its frames fail the parser;
* the n sequence numbers of a ``SAMPLE n``'s answer are that request's, however
  it ended (an ``#OK`` before the n-th frame, a violation): its answer begins
  after the last frame seen or owed before it, when every frame the board sent
  since the sequence was known is one of those (the last answer was placed and
  ended with its ``#OK``); else (after a connect, a ``#HELLO``, a violation, a
  fence, a frame sent unasked, an answer not placed) at its first frame. A frame
  carrying one of them later is stray, never the first frame of the next answer
  (a board that lags by a frame would otherwise shift every later sample by
  one); one of them lost is that request's loss, not the next one's (an answer
  whose last frame was damaged costs one retry, not two);
* with no sequence number to place an answer by, its first frame to arrive
  begins it (a frame lost on the line leaves a line that could not be trusted);
  but with such a line before that frame, the frames it lacks may have been its
  first: its frames are not placed (``SampleFrame.placed`` False: their index
  counts from the first that arrived) unless all n arrive, and nothing after its
  last frame is owed (owing it would cost every later answer its first frame, and the
  condition its attempts);
* board time (``t_ms``) never falls from one frame the board sends to the next,
  within an answer or across answers, as the sequence never does. Each frame is
  judged against both its neighbours among the frames accepted: against the last
  one, when it arrives, and by the next one. A frame whose time fell below the last
  accepted is :class:`Junk` (a damaged frame whose CRC-8 matched by chance; its place
  stays empty), and the time is not followed down, so a second fallen frame is
  caught as surely as the first. A next frame that falls below the last accepted
  but not below the one before it says the last one jumped forward: that one is
  :class:`TimeJumped` (taken back from its answer, open or closed) and the next is
  accepted. With no frame before the last to tell which of the two is wrong, both
  go. :meth:`HostProtocol.watch` asks for the verdict on a frame that has no next
  neighbour yet (the last frame of a condition);
* after a violation, an answer that ended with fewer frames than asked, or an
  ``#OK`` that is not the open request's (a duplicated or spoofed one, or one
  with no request open), the next request is preceded by a fence (``STREAM
  OFF``, answered in order): what the board sent before its ``#OK`` belongs to
  no request (:attr:`HostProtocol.needs_fence`), so the host is never a reply
  behind the board: a stray ``#OK`` costs at most one retry;
* a ``SAMPLE`` whose answer has stalled may be probed (:meth:`HostProtocol.send_probe`:
  ``STREAM OFF``, the request left open): the board answers commands in order, so
  when the probe's ``#OK`` comes with the ``SAMPLE`` still open, the answer is over
  and its ``#OK`` was lost on the line; the frames that came keep their places, and
  a probe ``#OK`` that comes after the ``SAMPLE``'s own is absorbed;
* after ``#OK STREAM ON`` (:meth:`HostProtocol.send_stream`) frames outside a
  ``SAMPLE`` are :class:`StreamFrame`, and a lost sequence number is a
  :class:`StreamGap`, until the ``#OK`` of a ``STREAM OFF``, a greeting, or a
  ``#HELLO`` (a restarted board has stopped streaming).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from eskin.device.protocol import (
    Frame,
    FrameParser,
    Hello,
    ParseError,
    Reply,
    SequenceBackwards,
    SequenceGap,
)


@dataclass(frozen=True)
class Greeted:
    """The board answered ``HELLO`` and the ``STREAM OFF`` fence after it."""

    hello: Hello


@dataclass(frozen=True)
class Answered:
    """``#OK`` for the open command (or fence)."""

    request: int
    reply: Reply


@dataclass(frozen=True)
class Refused:
    """``#ERR`` for the open request: asking again will not help."""

    request: int
    reply: Reply


@dataclass(frozen=True)
class SampleFrame:
    """Frame ``index`` (0-based) of the answer to ``SAMPLE`` request ``request``.

    ``placed`` False: no seq placed the answer and a damaged line came before its first
    frame to arrive, so ``index`` counts from that frame, which may not have been the
    answer's first; only a :class:`SampleComplete` answer places such frames."""

    request: int
    index: int
    frame: Frame
    placed: bool = True


@dataclass(frozen=True)
class SampleComplete:
    """Exactly the n frames asked for arrived, in sequence, then ``#OK SAMPLE n``."""

    request: int
    frames: int


@dataclass(frozen=True)
class SampleIncomplete:
    """``#OK SAMPLE n`` after ``frames`` of the n: the others were lost on the line. The
    request is closed; the frames credited keep their places."""

    request: int
    frames: int
    requested: int


@dataclass(frozen=True)
class Violation:
    """The board broke the protocol for the open request, which is now closed.

    ``restart``: a ``SAMPLE``'s frame count went back: the board may have restarted with
    its ``#HELLO`` lost on the line, and forgotten what it was told (or it replayed an old
    answer)."""

    request: int
    reason: str
    line: bytes = field(default=b"", repr=False)
    restart: bool = False


@dataclass(frozen=True)
class Restarted:
    """The session's board said ``#HELLO`` unasked: it restarted and forgot its state."""

    hello: Hello
    request: int | None


@dataclass(frozen=True)
class OtherBoard:
    """A ``#HELLO`` from a board other than the session's."""

    hello: Hello
    expected: str


@dataclass(frozen=True)
class OtherSkin:
    """A ``#HELLO`` of a board whose terminals are not the ``expected`` of the skin read."""

    hello: Hello
    expected: int


@dataclass(frozen=True)
class Stray:
    """A frame outside any ``SAMPLE`` request: counted, never stored."""

    frame: Frame


@dataclass(frozen=True)
class StreamFrame:
    """A frame of the live stream (``STREAM ON``)."""

    frame: Frame


@dataclass(frozen=True)
class StreamGap:
    """Frames of the live stream were lost: ``got`` arrived where ``expected`` was due."""

    expected: int
    got: int


@dataclass(frozen=True)
class TimeJumped:
    """``frame``, accepted before, was judged by the frame after it: its board time jumped
    forward (a damaged frame whose CRC-8 matched by chance). Credited to ``request`` at
    ``index`` (None: credited to no request), it is taken back: its place is empty."""

    frame: Frame
    request: int | None
    index: int | None


@dataclass
class _Timed:
    """A frame accepted by the board-time check, and where it was credited."""

    frame: Frame
    request: int | None = None
    index: int | None = None


@dataclass(frozen=True)
class Junk:
    """A line that could not be trusted (bad CRC, torn, garbage)."""

    error: ParseError


HostEvent = (Greeted | Answered | Refused | SampleFrame | SampleComplete | SampleIncomplete
             | Violation | Restarted | OtherBoard | OtherSkin | Stray | StreamFrame
             | StreamGap | Junk | TimeJumped)


@dataclass
class _Request:
    number: int
    kind: str          # "greet" | "command" | "fence" | "sample"
    name: str          # the command word whose #OK closes it
    text: str
    n: int = 0         # SAMPLE: frames asked for
    got: int = 0       # SAMPLE: frames credited
    start: int | None = None  # SAMPLE: the seq its answer begins at (index 0), once known
    placed: bool = True       # SAMPLE: start is known to be the answer's first seq
    junk_first: bool = False  # SAMPLE: a line that could not be trusted came before it
    probed: bool = False      # SAMPLE: a probe (STREAM OFF) was sent while it was open
    junk_last: bool = False   # SAMPLE: a line that could not be trusted since its last frame
    begun: bool = False       # SAMPLE: a line of its answer (a frame, or junk) arrived


class ProtocolStateError(RuntimeError):
    """The host code asked for something out of order (a bug, not the board's fault)."""


class HostProtocol:
    """Host side of protocol v1: requests out, board bytes in, events out.

    Parameters
    ----------
    device_id
        The board the session began with. Once known (given here, or from
        the first greeting), a ``#HELLO`` with another id is :class:`OtherBoard`.
    terminals
        The readings per frame of the skin the host reads (its rows + columns): a
        ``#HELLO`` with another count is :class:`OtherSkin`. None (a caller with no skin,
        giving a board its id, say): whatever the board's ``#HELLO`` says.
    """

    def __init__(self, device_id: str | None = None, terminals: int | None = None) -> None:
        self.device_id = device_id
        self.terminals = terminals
        self.hello: Hello | None = None
        self.needs_fence = False
        self.streaming = False  # the board answered STREAM ON, and nothing stopped it since
        self.stray_frames = 0
        self.junk_lines = 0
        self._parser = FrameParser(terminals)
        self._open: _Request | None = None
        self._requests = 0
        self._greet_hello: Hello | None = None
        self._last_seq: int | None = None   # of the last frame seen, any request
        # The last two frames the board-time check accepted (each judged by the next).
        self._time_last: _Timed | None = None
        self._time_before: _Timed | None = None
        self._watched: Frame | None = None
        self.watched_verdict: bool | None = None  # see watch()
        # After a reconnect, the watched frame's time: a next frame not below it vouches for
        # it; one below may be a restarted board's, and judges nothing.
        self._watch_floor: int | None = None
        self._owed_up_to: int | None = None  # seqs that belong to an earlier SAMPLE's answer
        # Every frame the board sent since the sequence was known is seen or owed, so its
        # next frame's seq is known: a SAMPLE answer can be placed before it arrives.
        self._next_seq_known = False
        self._probe_oks = 0  # probes sent whose #OK STREAM OFF has not come yet

    # ------------------------------------------------------------ requests

    @property
    def open_request(self) -> int | None:
        return self._open.number if self._open else None

    def send_greeting(self) -> bytes:
        """``HELLO`` then the ``STREAM OFF`` fence: every ``#HELLO`` before the fence's
        ``#OK`` belongs to this greeting (a power-up greeting may come late)."""
        self._start("greet", "STREAM", "HELLO")
        self._greet_hello = None
        return b"HELLO\nSTREAM OFF\n"

    def send_command(self, text: str) -> bytes:
        """A command answered by ``#OK <word>`` (``STRETCH``, ``SIM ...``)."""
        word = text.split()[0].upper()
        if word in ("SAMPLE", "HELLO"):
            raise ProtocolStateError(f"{word} has its own request method")
        self._start("command", word, text)
        return text.encode("ascii") + b"\n"

    def send_fence(self) -> bytes:
        """``STREAM OFF``: when its ``#OK`` arrives the board has sent all it owed."""
        self._start("fence", "STREAM", "STREAM OFF")
        if self.streaming:  # a streamed frame it absorbs may have been lost
            self._next_seq_known = False
        # Else the next answer's first seq stays known unless what the fence absorbs says
        # otherwise (a damaged line, a frame nobody was owed): a short answer's top-up is
        # placed by seq as it would have been without the fence.
        return b"STREAM OFF\n"

    def send_stream(self) -> bytes:
        """``STREAM ON``: once its ``#OK`` arrives, frames are :class:`StreamFrame`."""
        return self.send_command("STREAM ON")

    def send_sample(self, n: int) -> bytes:
        if n < 1:
            raise ProtocolStateError(f"SAMPLE asks for at least one frame, not {n}")
        request = self._start("sample", "SAMPLE", f"SAMPLE {n}")
        request.n = n
        if self._next_seq_known:
            last = self._last_seq if self._last_seq is not None else -1
            owed = self._owed_up_to if self._owed_up_to is not None else -1
            request.start = max(last, owed) + 1
        return b"SAMPLE %d\n" % n

    def send_probe(self) -> bytes:
        """``STREAM OFF`` with the open ``SAMPLE`` left open: its ``#OK`` ends the answer
        if the answer's own ``#OK`` was lost (:meth:`_reply`)."""
        request = self._open
        if request is None or request.kind != "sample":
            raise ProtocolStateError("a probe is sent only while a SAMPLE is open")
        request.probed = True
        self._probe_oks += 1
        return b"STREAM OFF\n"

    @property
    def answer_begun(self) -> bool:
        """The open ``SAMPLE``'s answer has begun: a frame or a damaged line came."""
        return self._open is not None and self._open.begun

    def abandon(self) -> None:
        """Give up on the open request (its deadline passed, the port failed): what the
        board sends for it later is stray, and the next request is fenced."""
        if self._open is not None:
            self._owe(self._open)
            self._open = None
            self.needs_fence = True
            self._next_seq_known = False

    def reset_link(self) -> None:
        """A new connection: partial lines and the sequence are forgotten."""
        self._parser = FrameParser(self.terminals)
        self._open = None
        self._forget_sequence(keep_watch=True)
        self.streaming = False
        self._probe_oks = 0

    @property
    def line_ending_hint(self) -> str | None:
        """Why nothing the board sends ends a line, if its bytes say (CR-only endings)."""
        return self._parser.line_ending_hint

    def _start(self, kind: str, name: str, text: str) -> _Request:
        if self._open is not None:
            raise ProtocolStateError(f"{text!r} sent while {self._open.text!r} is open")
        self._requests += 1
        self._open = _Request(self._requests, kind, name, text)
        if kind in ("fence", "greet"):
            self.needs_fence = False
        return self._open

    # ------------------------------------------------------------ board bytes

    def receive(self, data: bytes) -> list[HostEvent]:
        events: list[HostEvent] = []
        for event in self._parser.feed(data):
            self._handle(event, events)
        return events

    def _handle(self, event, events: list[HostEvent]) -> None:
        request = self._open
        if request is not None and isinstance(event, Frame | ParseError):
            request.begun = True
        if isinstance(event, Hello):
            self._hello(event, events)
        elif isinstance(event, Frame):
            time_fell = self._judge_time(event, events)
            self._last_seq = event.seq
            owed = self._owed_up_to is not None and event.seq <= self._owed_up_to
            if self.streaming and (request is None or request.kind != "sample"):
                if time_fell:
                    self.junk_lines += 1
                    events.append(Junk(ParseError(time_fell, event.line)))
                else:
                    events.append(StreamFrame(event))
            elif request is None or request.kind != "sample" or owed:
                # An owed frame answers an earlier request (one whose #OK came too early,
                # say): it is never credited to a later one, however continuous its seq.
                # Any other was sent unasked: more like it may have been lost.
                self._next_seq_known = self._next_seq_known and owed
                self.stray_frames += 1
                events.append(Stray(event))
            elif time_fell:
                if request.got == 0:
                    request.junk_first = True
                request.junk_last = True
                self.junk_lines += 1
                events.append(Junk(ParseError(time_fell, event.line)))
            else:
                self._credit(request, event, events)
        elif isinstance(event, SequenceGap):
            # In a SAMPLE answer a lost frame leaves its place empty (the seq places the
            # rest): nothing to do here.
            if self.streaming and (request is None or request.kind != "sample"):
                events.append(StreamGap(event.expected, event.got))
        elif isinstance(event, ParseError):
            if isinstance(event, SequenceBackwards):
                # The board's count started again (a restart whose #HELLO was lost) or an
                # old answer is replayed: what was owed, and the time, mean nothing now.
                if request is not None and request.kind == "sample":
                    self._count_restarted(events, event.reason, event.line)
                    return
                self._forget_sequence()
            if request is not None and request.kind == "sample":
                request.junk_first = request.junk_first or request.got == 0
                request.junk_last = True
            if request is not None and request.kind == "fence":
                self._next_seq_known = False  # it may have been a frame sent unasked
            self.junk_lines += 1
            events.append(Junk(event))
        elif isinstance(event, Reply):
            self._reply(event, events)

    def _hello(self, hello: Hello, events: list[HostEvent]) -> None:
        request = self._open
        # The board's sequence and time start again (a greeting's #HELLO: perhaps).
        self._forget_sequence(keep_watch=request is not None and request.kind == "greet")
        self.streaming = False  # and it has forgotten STREAM ON
        self._probe_oks = 0  # and any probe it had not answered
        known = self.device_id
        if known is not None and hello.device_id != known:
            self._open = None
            self.needs_fence = True
            events.append(OtherBoard(hello, known))
            return
        if self.terminals is not None and hello.terminals != self.terminals:
            self._open = None
            self.needs_fence = True
            events.append(OtherSkin(hello, self.terminals))
            return
        if request is not None and request.kind == "greet":
            self._greet_hello = hello
            return
        # Unasked: the board restarted. The open request is lost with its state.
        self._open = None
        self.needs_fence = True
        self.hello = hello
        events.append(Restarted(hello, request.number if request else None))

    def _reply(self, reply: Reply, events: list[HostEvent]) -> None:
        request = self._open
        command = reply.command.upper()
        if (self._probe_oks and command == "STREAM" and reply.ok
                and reply.details.strip().upper() == "OFF"):
            self._probe_oks -= 1  # answers are in order: this is the oldest probe's
            if request is not None and request.kind == "sample" and request.probed:
                self._answer_over(request, events, by_probe=True)
            return
        if request is None:
            # A late answer to a request given up on, or an #OK the board sent twice or
            # unasked: nothing to credit, and the next request is fenced, as the board's
            # output is not where the host thought it was.
            self.needs_fence = True
            return
        if request.kind in ("greet", "fence"):
            # A fence absorbs everything the board owed before it; only its own #OK ends it.
            if command == "STREAM" and reply.ok and reply.details.strip().upper() in ("", "OFF"):
                self._open = None
                self.streaming = False
                if request.kind == "fence":
                    events.append(Answered(request.number, reply))
                elif self._greet_hello is None:
                    self._violate(events, "answered STREAM OFF without a #HELLO", reply.line,
                                  request)
                else:
                    hello = self._greet_hello
                    if self.device_id is None:
                        self.device_id = hello.device_id
                    self.hello = hello
                    events.append(Greeted(hello))
            return
        if command != request.name:
            self._violate(events, f"a reply to {command} while waiting for {request.text!r}",
                          reply.line, by_reply=True)
            return
        self._open = None
        if not reply.ok:
            events.append(Refused(request.number, reply))
            return
        if request.kind != "sample":
            if request.text == "STREAM ON":
                self.streaming = True
            elif command == "STREAM":
                self.streaming = False
            events.append(Answered(request.number, reply))
            return
        if reply.details.strip() != str(request.n):
            self._violate(events, f"#OK SAMPLE {reply.details.strip()!r} answered "
                          f"SAMPLE {request.n}", reply.line, request, by_reply=True)
            return
        self._answer_over(request, events)

    def _answer_over(self, request: _Request, events: list[HostEvent], *,
                     by_probe: bool = False) -> None:
        """The board's answer to ``request`` is over: its ``#OK``, or a probe's after it
        (the ``#OK`` lost on the line: the board has sent all it owed, no fence needed)."""
        self._open = None
        self._owe(request)
        # The answer's n seqs are known only if it was placed: then the next follows them.
        # Not placed, its last frame was still its last line (no damaged line after it,
        # then its #OK), so the next answer follows that frame: without this, one damaged
        # first line left every later answer unplaced too, each keeping nothing.
        self._next_seq_known = (request.start is not None and request.placed) or (
            request.got > 0 and not request.junk_last)
        if request.got == request.n:
            events.append(SampleComplete(request.number, request.got))
        else:
            # Frames lost on the line, or this #OK was not the board's answer to this
            # request (a duplicate of the last one, a spoof): then the answer is still on
            # its way, and without a fence its #OK would close the next request, and so
            # on, one reply behind for good. The fence absorbs it; after a probe's #OK
            # the board has sent everything already.
            self.needs_fence = not by_probe
            events.append(SampleIncomplete(request.number, request.got, request.n))

    def _credit(self, request: _Request, frame: Frame, events: list[HostEvent]) -> None:
        """Credit ``frame`` to the open ``SAMPLE`` at the place its seq gives it."""
        if request.start is None:
            # No seq came before the answer: its first frame to arrive begins it, surely
            # only if no damaged line came before that frame.
            request.start = frame.seq
            request.placed = not request.junk_first
        index = frame.seq - request.start
        if index >= request.n:
            self._violate(events, f"more than the {request.n} frames asked for "
                          f"(seq {frame.seq})", frame.line)
            return
        request.got += 1
        request.junk_last = False
        if self._time_last is not None and self._time_last.frame is frame:
            self._time_last.request, self._time_last.index = request.number, index
        events.append(SampleFrame(request.number, index, frame, request.placed))

    def _count_restarted(self, events: list[HostEvent], reason: str, line: bytes) -> None:
        """The board's frame count went back during a ``SAMPLE``'s answer: a restart whose
        ``#HELLO`` was lost (or an old answer replayed). What was owed, and the time, mean
        nothing now; the request is a :class:`Violation` with ``restart`` set: the board
        may have forgotten what it was told."""
        self._forget_sequence()
        self._violate(events, f"{reason} (its frame count started again: a restart whose "
                      "#HELLO was lost, or a replayed answer)", line, owe=False, restart=True)

    def _violate(self, events: list[HostEvent], reason: str, line: bytes = b"",
                 request: _Request | None = None, *, owe: bool = True,
                 by_reply: bool = False, restart: bool = False) -> None:
        request = request or self._open
        self._open = None
        self.needs_fence = True
        if not (by_reply and request is not None and request.kind == "sample"
                and request.start is not None and request.placed):
            # The board may have sent frames beyond its answer. A reply out of turn (a
            # duplicated #OK, say) says nothing of the frames: a placed answer's seqs are
            # owed, and what the fence absorbs beyond them (a frame nobody was owed, a
            # damaged line) forgets the next seq then.
            self._next_seq_known = False
        if request is not None and owe:
            self._owe(request)
        events.append(Violation(request.number if request else 0, reason, line, restart))

    def _owe(self, request: _Request) -> None:
        """A closed ``SAMPLE``'s n seqs are its own, from where its answer began: the seq
        after the last frame seen before it, or else its first frame's."""
        if request.kind == "sample" and request.start is not None and request.placed:
            self._owed_up_to = request.start + request.n - 1
        # Else no seq placed the answer and a damaged line came before its first frame:
        # that line may have been its first frame, so the seqs after its last frame are
        # not taken as its own (each later answer would lose its first frame as owed).

    def _forget_sequence(self, *, keep_watch: bool = False) -> None:
        if keep_watch and self.watch_open and self._watch_floor is None:
            self._watch_floor = self._watched.t_ms
        elif not keep_watch:
            self._watched = self._watch_floor = None
        self._last_seq = self._owed_up_to = None
        self._time_last = self._time_before = None  # the board's time starts again too
        self._next_seq_known = False

    @property
    def watch_open(self) -> bool:
        """The watched frame (:meth:`watch`) awaits its verdict and may still get one."""
        return self._watched is not None and self.watched_verdict is None and (
            self._watch_floor is not None or self.last_accepted is self._watched)

    @property
    def last_accepted(self) -> Frame | None:
        """The last frame the board-time check accepted: the next frame judges it."""
        return self._time_last.frame if self._time_last else None

    def watch(self, frame: Frame) -> None:
        """Report the verdict on ``frame``, the last accepted (:attr:`last_accepted`), in
        :attr:`watched_verdict`: True once a frame after it is accepted, False if that
        frame says it jumped forward; None until then (:attr:`watch_open`), and for good
        if the board restarts first. After a reconnect the next frame vouches for it if
        its time is not below it (below, the board may have restarted)."""
        self._watched, self.watched_verdict, self._watch_floor = frame, None, None

    def _judge_time(self, frame: Frame, events: list[HostEvent]) -> str | None:
        """Judge ``frame``'s board time against the last frames accepted; why it cannot be
        right, or None if it is accepted. May take back the last frame accepted
        (:class:`TimeJumped`): then this one is accepted in its stead."""
        last, before = self._time_last, self._time_before
        if self._watch_floor is not None and last is None:
            self.watched_verdict = True if not _fell(self._watch_floor, frame.t_ms) else None
            if self.watched_verdict is None:
                self._watched = None  # a restarted board's time: nothing judged it
            self._watch_floor = None
        if last is None or not _fell(last.frame.t_ms, frame.t_ms):
            if last is not None and last.frame is self._watched:
                self.watched_verdict = True
            self._time_before, self._time_last = last, _Timed(frame)
            return None
        reason = (f"board time went backwards at seq {frame.seq} ({last.frame.t_ms} then "
                  f"{frame.t_ms}): a damaged frame whose CRC-8 matched by chance")
        if before is not None and _fell(before.frame.t_ms, frame.t_ms):
            return reason  # below both: this one fell; the time is not followed down
        # Above the one before the last (or no such one to ask): the last one may have
        # jumped forward. With the one before to vouch for this frame, the last goes;
        # with none, either may be wrong, and both go.
        self._take_back(last, events)
        if before is None:
            self._time_last = None
            return reason + " (or the frame before it jumped forward)"
        self._time_last = _Timed(frame)
        return None

    def _take_back(self, timed: _Timed, events: list[HostEvent]) -> None:
        if timed.frame is self._watched:
            self.watched_verdict = False
        request = self._open
        if request is not None and timed.request == request.number:
            request.got -= 1
        events.append(TimeJumped(timed.frame, timed.request, timed.index))


def _fell(earlier: int, later: int) -> bool:
    """Board time fell from ``earlier`` to ``later`` (but for its 32-bit wrap, 49 days)."""
    return later < earlier and earlier - later < 2**31

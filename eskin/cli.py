"""The ``eskin`` command line: a one-line error and a non-zero exit for anything a user
can fix, the traceback only with ``--debug``."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from eskin import __version__
from eskin.catalog import (
    SOURCES,
    TASK_NAMES,
)
from eskin.errors import (
    NOTHING_CHANGED,
    RECEIVED_KEPT,
    STEP_NOT_KEPT,
    STOPPED,
    run_friendly,
)
from eskin.lockfile import checked


def _ports(args: argparse.Namespace) -> int:
    from eskin.device.link import list_serial_ports

    ports = list_serial_ports()
    if not ports:
        print("no serial ports found (a simulated board: `eskin device simulate`)")
    for device, description, hwid in ports:
        print(f"{device}\t{description}\t{hwid}")
    return 0


def _simulate(args: argparse.Namespace) -> int:
    from eskin.config.base import load_params
    from eskin.config.params import Params
    from eskin.config.scenes import get_scene, scene_skin
    from eskin.device.simulate import serve_config
    from eskin.skin import PAPER_SKIN

    params = load_params(Params, args.params)
    board = params.sim_board
    skin = (PAPER_SKIN if args.scene is None
            else scene_skin(get_scene(params, args.scene, args.params)))
    config = {"sim": params.sim.model_dump(), "skin": skin.as_dict(),
              "rest_length_mm": params.acquire.rest_length_mm,
              "corrupt_fraction": board.corrupt_fraction
              if args.corrupt is None else args.corrupt,
              "frame_period_ms": board.frame_period_ms,
              "faults": board.faults.model_dump(exclude_unset=True)}
    serve_config(config, socket_port=args.socket, link=args.link)
    return 0


def _set_id(args: argparse.Namespace) -> int:
    from eskin.device.link import set_device_id

    hello = set_device_id(args.port, args.id)
    print(f"the board on {args.port} is now {hello.device_id} (firmware {hello.firmware})")
    return 0


def _live(args: argparse.Namespace) -> int:
    import contextlib

    from eskin.acquisition.session import simulated_board
    from eskin.catalog import raw_dir, stack_path
    from eskin.config.base import load_params
    from eskin.config.params import Params
    from eskin.config.scenes import get_scene, scene_kind, scene_skin
    from eskin.deploy.live import (
        LineBroadcast,
        LiveRecorder,
        json_line,
        live_estimates,
        stream_events,
    )
    from eskin.deploy.stack import ExportedStack, SkinStack
    from eskin.device.link import SerialLink, SkinMismatch
    from eskin.device.physics import skin_params

    def note(message: str) -> None:
        print(f"eskin live: {message}", file=sys.stderr, flush=True)

    params = load_params(Params, args.params)
    scene_params = get_scene(params, args.scene, args.params)
    tare_frames = params.live.tare_frames if args.tare_frames is None else args.tare_frames
    if tare_frames < 0 or args.frames < 0:
        raise ValueError("--tare-frames and --frames count frames: 0 or more")
    settings = params.acquire
    if args.onnx is not None:
        stack = ExportedStack.from_file(Path(args.onnx) if args.onnx else stack_path(args.scene))
        if stack.scene != args.scene:
            raise ValueError(f"{args.onnx} is the {stack.scene} stack, not {args.scene}'s")
    elif args.alias:
        from eskin.tracking.registry import stack_from_registry

        stack = stack_from_registry(args.scene, args.alias, log=note)
    else:
        stack = SkinStack.from_workspace(args.scene)
    if args.record and scene_params.source == "import":
        raise ValueError(f"--record keeps a board's frames in the raw log of a scene acquired "
                         f"from a board; {args.scene} is imported from a file")
    declared = scene_kind(scene_params).name
    if declared != stack.kind:
        raise ValueError(f"scenes.{args.scene} is a {declared} scene in {args.params}, but its "
                         f"trained stack is {stack.kind}: run `dvc repro` to train it again")
    if scene_skin(scene_params) != stack.skin:
        raise ValueError(f"scenes.{args.scene} is on the {scene_skin(scene_params).describe()} "
                         f"in {args.params}, but its trained stack reads the "
                         f"{stack.skin.describe()}: run `dvc repro` to train it again")
    if not stack.skin.row_column:
        raise ValueError(f"{args.scene} is an {stack.skin.describe()}, recorded by its own "
                         "instrument: live reads a row/column skin's board (protocol v1)")
    with contextlib.ExitStack() as resources:
        port = args.port
        if args.simulated:
            board = resources.enter_context(simulated_board(
                skin_params(params.sim), skin=stack.skin,
                rest_length_mm=float(settings.rest_length_mm),
                frame_period_ms=int(params.sim_board.frame_period_ms)))
            port = board.port
        link = resources.enter_context(SerialLink(port, terminals=stack.skin.terminals,
                                                  timeout_s=float(settings.timeout_s)))
        try:
            hello = link.connect()
        except SkinMismatch as err:
            raise ValueError(f"the board on {port} has {err.hello.terminals} terminals, but "
                             f"the {args.scene} stack reads the {stack.skin.describe()}: "
                             "connect the board built for this skin") from None
        if not args.any_device:
            stack.check_board(hello.device_id)
        note(f"{args.scene} stack on {hello.device_id} ({port}); tare: keep the skin "
             f"untouched for {tare_frames} frames")
        events = resources.enter_context(contextlib.closing(stream_events(
            link, reconnect_s=float(settings.reconnect_s), notify=note)))
        recorder = None
        if args.record:
            source = "simulated" if args.simulated else "serial"
            recorder = LiveRecorder.open(
                raw_dir(args.scene), args.scene, hello, source=source,
                port="simulated board (pty)" if args.simulated else port,
                stack=(f"onnx {args.onnx or stack_path(args.scene)}" if args.onnx is not None
                       else f"registry @{args.alias}" if args.alias else "workspace"))
            resources.callback(lambda: note(
                f"recorded {recorder.frames} frame(s) in {recorder.attempts} attempt(s) as "
                f"session {recorder.session} of {recorder.writer.path}; `dvc repro` puts "
                f"them in data/processed/{args.scene}.live.parquet"))
            resources.callback(recorder.close)
            events = recorder.tap(events)
        if "contact" not in stack.columns:
            note(f"{args.scene}: this stack cannot count contacts (its scene presses every "
                 "contact on every sample), so it reports each on every frame; a scene "
                 "recorded with contact_counts: [0, 1, 2] learns how many press (docs/live.md)")
        broadcast = view = None
        try:
            if args.serve is not None:
                broadcast = resources.enter_context(LineBroadcast(args.serve, notify=note))
                note(f"serving the JSON lines on 127.0.0.1:{broadcast.port}")
            if args.view is not None:
                from eskin.deploy.view import LiveView, Pressing
                from eskin.device.board import MAX_NEWTONS
                from eskin.kinds import KINDS

                # Only the simulated board can be pressed from the page: through its SIM
                # commands, on this link.
                pressing = Pressing.of_scene(
                    getattr(scene_params, "forces", ()), KINDS[stack.kind].contacts,
                    max_n=MAX_NEWTONS) if args.simulated else None
                view = resources.enter_context(LiveView(
                    scene=args.scene, kind=stack.kind, device=hello.device_id, skin=stack.skin,
                    port=args.view, pressing=pressing))
                note(f"the live view is at {view.url}" + (
                    f"; click a node to press the simulated skin there (or `eskin press X Y "
                    f"NEWTONS --view {view.port}`)" if pressing else ""))
        except OSError as err:  # the port is taken, say
            raise ValueError(f"cannot serve on 127.0.0.1 ({err.strerror or err})") from None
        def requests() -> list[str]:  # re-tare from the page or a socket client
            if view is not None and view.pressing is not None:
                view.carry_out_presses(link.command)  # between two batches of the stream
            return [*(view.requests() if view else ()),
                    *(broadcast.requests() if broadcast else ())]

        estimates = 0
        try:
            for record in live_estimates(stack, events, tare_frames=tare_frames,
                                         settings=params.live, requests=requests,
                                         with_change=view is not None, notify=note):
                if view is not None:
                    view.show(record)
                line = json_line(record)
                if not args.quiet:
                    print(line, flush=True)
                if broadcast is not None:
                    broadcast.send(line)
                estimates += "seq" in record
                if args.frames and estimates >= args.frames:
                    break
        except KeyboardInterrupt:  # how a live session ends
            note(f"stopped after {estimates} estimates")
    return 0


def _press(args: argparse.Namespace) -> int:
    from eskin.deploy.view import press_on_view

    wrong = (args.force_n is not None or (args.x is None) != (args.y is None)
             if args.release else None in (args.x, args.y, args.force_n))
    if wrong:
        raise ValueError("eskin press takes X Y NEWTONS (e.g. eskin press 6 4 5.2), or "
                         "--release (with X Y: that node's weight only)")
    if args.release:
        request = {"release": True} if args.x is None else {
            "x": args.x, "y": args.y, "release": True}
    else:
        request = {"x": args.x, "y": args.y, "force_n": args.force_n}
    weights = press_on_view(args.view, request)
    print("pressed: " + ("nothing" if not weights else "; ".join(
        f"{w['force_n']:g} N on x {w['x']}, y {w['y']}" for w in weights)))
    return 0


def _export(args: argparse.Namespace) -> int:
    from eskin.steps import export

    _check_params(args.params)
    print(export.run(args.scene, args.params))
    return 0


DESCRIPTION = """\
Acquire, train on and use a soft capacitive e-skin. The pipeline's steps are DVC
stages (dvc repro runs them all); these commands run one step, or work beside it.
Runs are logged to MLflow by one stage, track, last in dvc repro and dvc exp run;
no command here logs a run. A mistake you can fix is one line and exit code 1;
--debug shows the traceback."""

EXAMPLES = """\
examples:
  eskin device simulate                 serve the simulated skin; prints its port
  eskin acquire single_force            acquire a scene of params.yaml (resumes)
  eskin train single_force force        cross-validate, refit one task (no MLflow)
  eskin live single_force --simulated --frames 10
                                        the trained stack on a board's stream
  eskin compare --last 2                two variants' headline scores side by side
  eskin audit                           which dataset version trained which run
  eskin promote single_force --experiment force-rf
                                        alias champion on that experiment's stack

eskin COMMAND --help describes a command, with examples."""

PARAMS_HELP = "the parameters file (default params.yaml)"


class _HelpFormatter(argparse.HelpFormatter):
    """A command's description wrapped to the terminal; its examples (the epilog, which
    starts ``examples:``) kept line for line, one command a line."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if text.startswith("examples:"):
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


def _examples(*examples: tuple[str, str], note: str = "") -> str:
    """``examples:``, each command beside what it does (under it, if the command is long),
    then ``note``, a paragraph written as it is to be shown."""
    lines = ["examples:"]
    for command, what in examples:
        if len(command) > 36:
            lines += [f"  {command}", f"  {'':36}  {what}"]
        else:
            lines.append(f"  {command:<36}  {what}")
    return "\n".join(lines) + (f"\n\n{note}" if note else "")


def _command(commands, name: str, summary: str, examples: str, *,
             interrupted: str) -> argparse.ArgumentParser:
    """A subcommand: ``summary`` in ``eskin --help``'s list and atop its own --help, its
    examples under it; ``interrupted``: what a Ctrl-C leaves (eskin.errors)."""
    parser = commands.add_parser(name, help=summary, description=summary, epilog=examples,
                                 formatter_class=_HelpFormatter)
    parser.set_defaults(interrupted=interrupted)
    return parser


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="eskin", description=DESCRIPTION, epilog=EXAMPLES,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"eskin {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    commands = parser.add_subparsers(dest="command", required=True)

    ports = _command(commands, "ports", "list the serial ports a board may be on (pyserial's "
                     "list_ports)",
                     _examples(("eskin ports", "device, description, hardware id")),
                     interrupted=NOTHING_CHANGED)
    ports.set_defaults(run=_ports)

    device = _command(commands, "device", "the board: serve a simulated one, or give a real "
                      "one its id",
                      _examples(("eskin device simulate", "the simulated skin on a pty"),
                                ("eskin device set-id /dev/ttyACM0 lab2-skin1",
                                 "a new board's id, once")),
                      interrupted=NOTHING_CHANGED)
    device_commands = device.add_subparsers(dest="device_command", required=True)
    simulate = _command(
        device_commands, "simulate", "serve the simulated skin on a pseudo-terminal (or a "
        "loopback socket) and print the port to open, until Ctrl-C",
        _examples(("eskin device simulate", "the paper's 10 × 10 skin; prints its pty"),
                  ("eskin device simulate --socket 0", "on socket://127.0.0.1:<a free port>"),
                  ("eskin device simulate --corrupt 0.01", "1 % of frames damaged on the wire"),
                  ("eskin device simulate --scene two_force", "the skin of scenes.two_force")),
        interrupted=NOTHING_CHANGED)
    simulate.add_argument("--params", type=Path, default=Path("params.yaml"),
                          help=PARAMS_HELP + "; its sim and sim_board sections")
    simulate.add_argument("--scene", help="simulate the skin of scenes.SCENE "
                          "(default: the paper's 10 × 10)")
    simulate.add_argument("--socket", type=int, metavar="PORT",
                          help="serve on socket://127.0.0.1:PORT instead (0: any free port)")
    simulate.add_argument("--corrupt", type=float, metavar="FRACTION",
                          help="damage this share of frames on the wire")
    simulate.add_argument("--link", type=Path, metavar="PATH",
                          help="also a symlink at PATH that follows the pty (needed for "
                          "vanish faults: the pty is replaced when the link comes back)")
    simulate.set_defaults(run=_simulate)
    set_id = _command(
        device_commands, "set-id", "give a board its device id, once (kept in its EEPROM; a "
        "board without one is refused by acquisition)",
        _examples(("eskin device set-id /dev/ttyACM0 lab2-skin1", "the board now greets as "
                   "lab2-skin1")),
        interrupted="the board may or may not have taken the id (a second set-id says "
        "which it has)")
    set_id.add_argument("port", help="e.g. /dev/ttyACM0 (eskin ports lists them)")
    set_id.add_argument("id", help="up to 24 letters, digits, '-' or '_', e.g. lab2-skin1")
    set_id.set_defaults(run=_set_id)

    acquire = _command(
        commands, "acquire", "acquire a scene of params.yaml into data/raw/<scene>/ (resumes "
        "where it stopped; the acquire stage of dvc repro)",
        _examples(("eskin acquire single_force", "from the source params.yaml names"),
                  ("eskin acquire single_force --source serial --port /dev/ttyACM0",
                   "from a board"),
                  ("eskin acquire single_force --source emulated",
                   "from the firmware under simavr")),
        interrupted=RECEIVED_KEPT)
    ingest = _command(
        commands, "ingest", "build data/processed/<scene>.parquet from the scene's raw data "
        "(the ingest step of dvc repro's prepare stage)",
        _examples(("eskin ingest single_force", "→ data/processed/single_force.parquet")),
        interrupted=STEP_NOT_KEPT)
    for sub in (acquire, ingest):
        sub.add_argument("scene", help="a scene of params.yaml, e.g. single_force")
        sub.add_argument("--params", type=Path, default=Path("params.yaml"), help=PARAMS_HELP)
        sub.set_defaults(run=_pipeline_step)
    acquire.add_argument("--source", choices=SOURCES, help="override scenes.<scene>.source")
    acquire.add_argument("--port", help="override scenes.<scene>.port (serial source)")
    acquire.add_argument("--no-progress", action="store_true",
                         help="no progress bar (for logs and CI)")

    live = _command(
        commands, "live", "run a scene's trained stack on a board's stream: one JSON line per "
        "frame on stdout (seq, t_ms, stretch, contact, x, y, force), until Ctrl-C",
        _examples(("eskin live single_force --port /dev/ttyACM0", "on a board"),
                  ("eskin live single_force --simulated --frames 10",
                   "10 estimates from the simulated board"),
                  ("eskin live single_force --simulated --view 8050",
                   "shown at http://127.0.0.1:8050/"),
                  ("eskin live single_force --simulated --onnx",
                   "the exported stack: under 1 ms a frame"),
                  ("eskin live single_force --port /dev/ttyACM0 --alias champion",
                   "the stack `eskin promote` gave the alias")),
        interrupted="a recording (--record) keeps every frame received so far in the raw "
        "log; nothing else was changed")
    live.add_argument("scene", help="the scene whose trained models to use")
    live.add_argument("--params", type=Path, default=Path("params.yaml"), help=PARAMS_HELP)
    where = live.add_mutually_exclusive_group(required=True)
    where.add_argument("--port", help="the board's port, e.g. /dev/ttyACM0")
    where.add_argument("--simulated", action="store_true",
                       help="start the simulated board (params.yaml's sim) and read it")
    which = live.add_mutually_exclusive_group()
    which.add_argument("--alias", metavar="NAME",
                       help="the models registered in MLflow under this alias (e.g. champion, "
                       "which `eskin promote` sets) instead of the workspace's")
    which.add_argument("--onnx", nargs="?", const="", metavar="FILE",
                       help="the stack exported as ONNX (default models/<scene>/stack.onnx, "
                       "which dvc repro writes), run by onnxruntime: under 1 ms a frame")
    live.add_argument("--tare-frames", type=int, metavar="N",
                      help="frames with nothing pressed, taken as the tare at start and "
                      "on request (default: live.tare_frames of params.yaml, 100, about "
                      "1.2 s; 0: no tare)")
    live.add_argument("--frames", type=int, default=0, metavar="N",
                      help="stop after N estimates (default: run until Ctrl-C)")
    live.add_argument("--serve", type=int, metavar="PORT",
                      help="also send the JSON lines to every client of 127.0.0.1:PORT "
                      "(0: a free port, printed); a client's line {\"command\": \"tare\"} "
                      "re-tares")
    live.add_argument("--view", type=int, metavar="PORT",
                      help="show the estimates on a page at http://127.0.0.1:PORT/ "
                      "(0: a free port, printed; its button, or key t, re-tares)")
    live.add_argument("--record", action="store_true",
                      help="also append the frames to the scene's raw log as a live session "
                      "(dvc repro then keeps them in data/processed/<scene>.live.parquet)")
    live.add_argument("--quiet", action="store_true", help="no JSON lines on stdout")
    live.add_argument("--any-device", action="store_true",
                      help="use the stack on a board other than the one it was trained on")
    live.set_defaults(run=_live)

    press = _command(
        commands, "press", "press (or release) the simulated skin of a running `eskin live "
        "--simulated --view PORT`, as a click on its page does",
        _examples(("eskin press 6 4 5.2", "5.2 N on the node at x 6, y 4"),
                  ("eskin press --release", "lift every weight")),
        interrupted=NOTHING_CHANGED)
    press.add_argument("x", type=int, nargs="?", metavar="X", help="the node's x (row), 1..R")
    press.add_argument("y", type=int, nargs="?", metavar="Y", help="the node's y (column), 1..C")
    press.add_argument("force_n", type=float, nargs="?", metavar="NEWTONS",
                       help="the weight, in newtons (the scene's levels read best)")
    press.add_argument("--release", action="store_true",
                       help="lift every weight (with X Y: the one on that node)")
    press.add_argument("--view", type=int, default=8050, metavar="PORT",
                       help="the live view's port, as given to `eskin live --view` "
                       "(default 8050)")
    press.set_defaults(run=_press)

    featurize = _command(
        commands, "featurize", "build data/features/<scene>.parquet and the fitted transform "
        "(featurize.method; the featurize step of dvc repro's prepare stage)",
        _examples(("eskin featurize single_force", "→ data/features/single_force.parquet")),
        interrupted=STEP_NOT_KEPT)
    featurize.add_argument("scene", help="a scene of params.yaml, e.g. single_force")
    featurize.add_argument("--params", type=Path, default=Path("params.yaml"), help=PARAMS_HELP)
    featurize.set_defaults(run=_learning_step)
    train = _command(
        commands, "train", "write the settings and draw a scene's folds, then "
        "cross-validate and refit a task (train.<task> of params.yaml), or every task, into "
        "the workspace, as the pipeline's settings, folds and train stages do, keeping a "
        "task trained from the same features, folds, settings and code; logs nothing to "
        "MLflow",
        _examples(("eskin train single_force force", "its scores, predictions and model"),
                  ("eskin train single_force", "every task of the scene, as its stage does"),
                  note="dvc repro trains every scene in its train stage, then its last stage,\n"
                  "track, logs them to MLflow (eskin compare shows them)."),
        interrupted=STEP_NOT_KEPT)
    train.add_argument("scene", help="a scene of params.yaml, e.g. single_force")
    train.add_argument("task", choices=TASK_NAMES, nargs="?",
                       help="a task (train.<task> in params.yaml; every task if left out); "
                       "one a scene's data cannot support is skipped, with the reason in its "
                       "scores file")
    train.add_argument("--params", type=Path, default=Path("params.yaml"), help=PARAMS_HELP)
    train.set_defaults(run=_learning_step)

    export = _command(
        commands, "export", "write a scene's trained stack as one ONNX file "
        "(models/<scene>/stack.onnx) and check it against the scikit-learn stack",
        _examples(("eskin export single_force", "→ models/single_force/stack.onnx")),
        interrupted=STEP_NOT_KEPT)
    export.add_argument("scene", help="a scene whose models dvc repro has trained")
    export.add_argument("--params", type=Path, default=Path("params.yaml"), help=PARAMS_HELP)
    export.set_defaults(run=_export)

    compare = _command(
        commands, "compare", "the latest run of every variant side by side, from MLflow: "
        "the params that differ, headline scores, run time",
        _examples(("eskin compare", "every variant"),
                  ("eskin compare --last 2", "the two newest"),
                  ("eskin compare --variant force-rf --scheme stratified",
                   "one variant, stratified CV's scores"),
                  ("eskin compare --format markdown --output compare.md", "for a document")),
        interrupted=NOTHING_CHANGED)
    compare.add_argument("--scheme", default="conditions", help="CV scheme of the scores "
                         "(conditions, stratified, trials; default conditions)")
    compare.add_argument("--last", type=int, metavar="N", help="only the N newest variants")
    compare.add_argument("--variant", action="append", metavar="NAME",
                         help="only this variant (repeatable), e.g. a `dvc exp` name")
    _table_options(compare)
    compare.set_defaults(run=_compare)

    audit = _command(
        commands, "audit", "dataset versions (DVC md5) and the MLflow runs each trained; "
        "with --run, one run's lineage checked against the workspace",
        _examples(("eskin audit", "every dataset version and its runs"),
                  ("eskin audit --run RUN_ID", "one run, its id from the table"),
                  ("eskin audit --format csv --output audit.csv", "a row per version")),
        interrupted=NOTHING_CHANGED)
    audit.add_argument("--run", dest="run_id", metavar="RUN_ID", help="audit this run")
    _table_options(audit)
    audit.set_defaults(run=_audit)

    plan = _command(
        commands, "plan", "how many trials per condition a target score needs, and the bench "
        "time they take, from make bench's learning curves",
        _examples(("eskin plan single_force --target force_r2=0.95", "trials for R² 0.95"),
                  ("eskin plan two_force --target localise_accuracy=0.9", "and for two forces"),
                  note="Targets are <task>_<metric>: force_r2, localise_accuracy, "
                  "detect_accuracy,\nstretch_r2. An answer says impossible where the Bayes "
                  "bound forbids the target\n(NOT converged, and no limit, where doubling the "
                  "bound's grid moved it),\nand beyond the floor where the model levels off "
                  "below it."),
        interrupted=NOTHING_CHANGED)
    plan.add_argument("scene", help="a scene, e.g. single_force")
    plan.add_argument("--target", required=True, metavar="TASK_METRIC=VALUE",
                      help="the score to reach, e.g. force_r2=0.95")
    plan.set_defaults(run=_plan)

    reproduce = _command(
        commands, "reproduce", "rerun a registered model's cross-validation on its dataset "
        "version and compare with its run's out-of-fold predictions",
        _examples(("eskin reproduce single_force.force", "its newest version"),
                  ("eskin reproduce single_force.localise.x --version 1", "a given version")),
        interrupted=NOTHING_CHANGED)
    reproduce.add_argument("model", help="a registered model, e.g. single_force.force")
    reproduce.add_argument("--version", help="default: the newest")
    reproduce.set_defaults(run=_reproduce)

    promote = _command(
        commands, "promote", "give an MLflow alias to every registered model of a scene's "
        "stack in one pipeline run (what `eskin live --alias` loads)",
        _examples(("eskin promote single_force --experiment force-rf",
                   "champion on that experiment's stack"),
                  ("eskin promote single_force --alias staging --run RUN_ID",
                   "staging on that pipeline run's stack"),
                  ("eskin promote single_force", "on the workspace's stack"),
                  note="With neither --experiment nor --run: the pipeline run that logged the "
                  "models\ndvc.lock records (the workspace's stack). A model that scores worse "
                  "than the\nversion it takes the alias from is said on stderr."),
        interrupted="the alias may be on part of the stack: run it again")
    promote.add_argument("scene", help="a scene, e.g. single_force")
    promote.add_argument("--alias", default="champion",
                         help="the alias to set (default champion); taken from the scene's "
                         "models outside the stack")
    run_of = promote.add_mutually_exclusive_group()
    run_of.add_argument("--experiment", metavar="NAME",
                        help="the newest pipeline run of this name: a `dvc exp` name, or a "
                        "repro-… variant (`eskin compare` lists them)")
    run_of.add_argument("--run", dest="run_id", metavar="RUN_ID", help="this pipeline run")
    promote.set_defaults(run=_promote)
    return parser


def _table_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--format", choices=["table", "markdown", "csv"], default="table",
                        help="how to print the table (default: table)")
    parser.add_argument("--output", type=Path, help="write the table here instead of printing")


def _emit(text: str, output: Path | None) -> None:
    if output is None:
        print(text, end="")
        return
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(text)
    print(f"wrote {output}")


def _compare(args: argparse.Namespace) -> int:
    from eskin.tracking import compare

    table = compare.variant_table(compare.load_runs(), scheme=args.scheme,
                                      variants=args.variant, last=args.last)
    _emit(compare.render(table, args.format), args.output)
    return 0


def _audit(args: argparse.Namespace) -> int:
    from eskin.tracking import compare

    root = Path.cwd()
    if args.run_id:
        _emit(compare.render_audit(compare.run_audit(args.run_id, root)), args.output)
        return 0
    runs = compare.load_runs()
    scenes = sorted(runs["tags.eskin.scene"].dropna().unique()) if "tags.eskin.scene" in runs \
        else []
    versions = compare.dataset_versions(runs, compare.workspace_digests(root, scenes))
    versions["committed"] = versions["dataset md5"].map(
        compare.commit_dates(root, list(versions["dataset md5"])))
    _emit(compare.render_versions(runs, versions, args.format), args.output)
    return 0


def _plan(args: argparse.Namespace) -> int:
    from eskin.catalog import learning_curve_path
    from eskin.config.base import BENCH_PARAMS, load_params, sections
    from eskin.config.params import Params
    from eskin.config.planning import LearningCurve
    from eskin.config.scenes import get_scene
    from eskin.tracking import planning

    scene = get_scene(load_params(Params), args.scene)
    name, equals, value = args.target.partition("=")
    try:
        wanted = float(value) if equals else None
    except ValueError:
        wanted = None
    if wanted is None:
        raise ValueError(f"--target {args.target!r}: give it as <task>_<metric>=<value>, "
                         "e.g. force_r2=0.95")
    settings = load_params(sections(BENCH_PARAMS, learning_curve=LearningCurve)).learning_curve
    path = learning_curve_path(args.scene)
    curves = planning.read_curves(path, args.scene)
    if scene.source != "import":  # curves of another plan answer for that plan, not this one
        from eskin.data.plan import plan_from_params

        conditions = len(plan_from_params(args.scene, scene).conditions)
        if curves.get("conditions") != conditions:
            print(f"eskin: warning: {path} was measured on {curves.get('conditions')} "
                  f"conditions of {args.scene}; its plan in params.yaml has {conditions} now, "
                  f"so these answers are the old plan's; rerun `cd bench && dvc repro "
                  f"learning_curve@{args.scene}` (make bench)", file=sys.stderr)
    print(planning.describe(planning.plan(curves, name.strip(), wanted, settings), settings))
    return 0


def _reproduce(args: argparse.Namespace) -> int:
    from eskin.tracking import registry

    result = registry.reproduce(args.model, args.version, root=Path.cwd(),
                                log=lambda message: print(message, file=sys.stderr))
    print(registry.render_reproduction(result), end="")
    return 0 if result["reproduced"] else 1


def _promote(args: argparse.Namespace) -> int:
    from eskin.config.base import load_params
    from eskin.config.params import Params
    from eskin.config.scenes import get_scene
    from eskin.tracking import registry

    get_scene(load_params(Params), args.scene)  # before the store: a typo is told at once
    promotion = registry.promote(args.scene, args.alias, variant=args.experiment,
                                 run_id=args.run_id, root=Path.cwd())
    print(registry.render_promotion(promotion), end="")
    warning = registry.render_downgrades(promotion)
    if warning:
        print(warning, file=sys.stderr)
    return 0


def _check_params(path: Path) -> None:
    """The whole params file, checked: a command names a typo in any section, where a
    stage checks the sections it reads (and depends on) alone."""
    from eskin.config.base import load_params
    from eskin.config.params import Params

    load_params(Params, path)


def _learning_step(args: argparse.Namespace) -> int:
    """``eskin featurize`` and ``eskin train``: the pipeline's own steps (eskin.steps), as
    its stages run them; ``train`` first writes the settings and folds it trains from."""
    _check_params(args.params)
    if args.command == "featurize":
        from eskin.steps import featurize

        print(featurize.run(args.scene, args.params))
        return 0
    from eskin.steps import folds, settings, train

    settings.run(args.params)  # every scene's, as the settings stage writes them
    print(folds.run(args.scene, args.params))
    print(train.run(args.scene, args.task, args.params))
    return 0


def _pipeline_step(args: argparse.Namespace) -> int:
    """``eskin acquire`` and ``eskin ingest``: the pipeline's own steps (eskin.steps)."""
    _check_params(args.params)
    if args.command == "acquire":
        from eskin.steps import acquire

        print(acquire.run(args.scene, args.params, source=args.source, port=args.port,
                          progress=not args.no_progress))
    else:
        from eskin.steps import ingest

        print(ingest.run(args.scene, args.params))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    # before any command imports MLflow: its INFO lines are not a command's output
    # (eskin/tracking/runs.py says the same for the publish stage)
    os.environ.setdefault("MLFLOW_LOGGING_LEVEL", "WARNING")
    logging.basicConfig(level=logging.DEBUG if args.debug else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    args.run = checked(args.command, args.run)  # a damaged dvc.lock is told first
    return run_friendly(lambda: args.run(args), debug=args.debug,
                        interrupted=getattr(args, "interrupted", STOPPED))

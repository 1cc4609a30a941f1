"""The ``eskin`` command line: a one-line error and a non-zero exit for anything a user
can fix, the traceback only with ``--debug``."""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

from eskin import __version__

RAW_DIR = Path("data/raw")
PROCESSED_DIR = Path("data/processed")
FEATURES_DIR = Path("data/features")
MODELS_DIR = Path("models")
METRICS_DIR = Path("reports/metrics")
PREDICTIONS_DIR = Path("reports/predictions")
LINEAGE_DIR = Path("reports/lineage")


def task_outputs(scene: str, task: str) -> dict[str, Path]:
    """Where one task's outputs go (the paths dvc.yaml declares)."""
    return {"metrics_path": METRICS_DIR / scene / f"{task}.json",
            "predictions_path": PREDICTIONS_DIR / scene / f"{task}.parquet",
            "model_path": MODELS_DIR / scene / f"{task}.joblib",
            "lineage_path": LINEAGE_DIR / scene / f"{task}.json"}


def _ports(args: argparse.Namespace) -> int:
    from eskin.device.link import list_serial_ports

    ports = list_serial_ports()
    if not ports:
        print("no serial ports found (a simulated board: `eskin device simulate`)")
    for device, description, hwid in ports:
        print(f"{device}\t{description}\t{hwid}")
    return 0


def _simulate(args: argparse.Namespace) -> int:
    from eskin.config import load_params, section, skin_params
    from eskin.device.board import SimulatedBoard
    from eskin.device.faults import FaultyLine, LinkFaults
    from eskin.device.physics import SkinParams
    from eskin.device.simulate import announce_stdout, serve_pty, serve_socket

    if args.config_json:
        config = json.loads(args.config_json)
        sim = SkinParams.from_mapping(config["sim"])
        rest, period = config["rest_length_mm"], config["frame_period_ms"]
        corrupt, faults = config["corrupt_fraction"], config.get("faults")
    else:
        params = load_params(args.params)
        sim, rest = skin_params(params), section(params, "acquire.rest_length_mm")
        corrupt = section(params, "sim_board.corrupt_fraction")
        period = section(params, "sim_board.frame_period_ms")
        faults = params["sim_board"].get("faults")
    if args.corrupt is not None:
        corrupt = args.corrupt

    def power_on() -> SimulatedBoard:  # again after every injected reset
        return SimulatedBoard(sim, rest_length_mm=rest, corrupt_fraction=corrupt,
                              frame_period_ms=period)

    line = FaultyLine(power_on, LinkFaults.from_mapping(faults))
    try:
        if args.socket is not None:
            serve_socket(line, args.socket, announce_stdout)
        else:
            serve_pty(line, announce_stdout, link=args.link)
    except KeyboardInterrupt:
        pass
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="eskin", description=__doc__)
    parser.add_argument("--version", action="version", version=f"eskin {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks")
    commands = parser.add_subparsers(dest="command", required=True)

    ports = commands.add_parser("ports", help="list serial ports (pyserial list_ports)")
    ports.set_defaults(run=_ports)

    device = commands.add_parser("device", help="device tools")
    device_commands = device.add_subparsers(dest="device_command", required=True)
    simulate = device_commands.add_parser(
        "simulate", help="serve the simulated skin on a pseudo-terminal (or a loopback socket) "
        "and print the port to open")
    simulate.add_argument("--params", type=Path, default=Path("params.yaml"))
    simulate.add_argument("--socket", type=int, metavar="PORT",
                          help="serve on socket://127.0.0.1:PORT instead (0: any free port)")
    simulate.add_argument("--corrupt", type=float, metavar="FRACTION",
                          help="damage this share of frames on the wire")
    simulate.add_argument("--link", type=Path, metavar="PATH",
                          help="also a symlink at PATH that follows the pty (needed for "
                          "vanish faults: the pty is replaced when the link comes back)")
    simulate.add_argument("--config-json", help=argparse.SUPPRESS)
    simulate.set_defaults(run=_simulate)

    for name, helptext in (("acquire", "acquire a scene into data/raw/<scene>/ (resumes)"),
                           ("ingest", "build data/processed/<scene>.parquet from the raw data")):
        sub = commands.add_parser(name, help=helptext)
        sub.add_argument("scene", help="a scene of params.yaml, e.g. single_force")
        sub.add_argument("--params", type=Path, default=Path("params.yaml"))
        if name == "acquire":
            sub.add_argument("--source", choices=["simulated", "serial", "import"],
                             help="override acquire.source")
            sub.add_argument("--port", help="override acquire.port (serial source)")
            sub.add_argument("--no-progress", action="store_true")
        sub.set_defaults(run=_pipeline_step)

    featurize = commands.add_parser("featurize", help="build data/features/<scene>.parquet "
                                    "and the fitted transform (featurize.method)")
    featurize.add_argument("scene")
    featurize.add_argument("--params", type=Path, default=Path("params.yaml"))
    featurize.set_defaults(run=_learning_step)
    train = commands.add_parser("train", help="cross-validate, refit and log one task "
                                "(train.<scene>.<task> in params.yaml)")
    train.add_argument("scene")
    train.add_argument("task", help="single_force: stretch, force, detect, localise; "
                       "two_force: force1, force2, localise")
    train.add_argument("--params", type=Path, default=Path("params.yaml"))
    train.add_argument("--no-track", action="store_true", help="do not log to MLflow")
    train.set_defaults(run=_learning_step)

    compare = commands.add_parser(
        "compare", help="the latest run of every variant side by side, from MLflow: "
        "the params that differ, headline scores, run time")
    compare.add_argument("--scheme", default="grouped", help="CV scheme of the scores "
                         "(grouped, stratified; default grouped)")
    compare.add_argument("--last", type=int, metavar="N", help="only the N newest variants")
    compare.add_argument("--variant", action="append", metavar="NAME",
                         help="only this variant (repeatable), e.g. a `dvc exp` name")
    _table_options(compare)
    compare.set_defaults(run=_compare)

    audit = commands.add_parser(
        "audit", help="dataset versions (DVC md5) and the MLflow runs each trained; "
        "with --run, one run's lineage checked against the workspace")
    audit.add_argument("--run", dest="run_id", metavar="RUN_ID", help="audit this run")
    _table_options(audit)
    audit.set_defaults(run=_audit)

    reproduce = commands.add_parser(
        "reproduce", help="rerun a registered model's cross-validation on its dataset "
        "version and compare with its run's out-of-fold predictions")
    reproduce.add_argument("model", help="a registered model, e.g. single_force.force")
    reproduce.add_argument("--version", help="default: the newest")
    reproduce.set_defaults(run=_reproduce)
    return parser


def _table_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--format", choices=["table", "markdown", "csv"], default="table")
    parser.add_argument("--output", type=Path, help="write the table here instead of printing")


def _emit(text: str, output: Path | None) -> None:
    if output is None:
        print(text, end="")
        return
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(text)
    print(f"wrote {output}")


def _compare(args: argparse.Namespace) -> int:
    from eskin import experiments

    table = experiments.variant_table(experiments.load_runs(), scheme=args.scheme,
                                      variants=args.variant, last=args.last)
    _emit(experiments.render(table, args.format), args.output)
    return 0


def _audit(args: argparse.Namespace) -> int:
    from eskin import experiments

    root = Path.cwd()
    if args.run_id:
        _emit(experiments.render_audit(experiments.run_audit(args.run_id, root)), args.output)
        return 0
    runs = experiments.load_runs()
    scenes = sorted(runs["tags.eskin.scene"].dropna().unique()) if "tags.eskin.scene" in runs \
        else []
    versions = experiments.dataset_versions(runs, experiments.workspace_digests(root, scenes))
    versions["committed"] = versions["dataset md5"].map(
        experiments.commit_dates(root, list(versions["dataset md5"])))
    if args.format != "table":
        _emit(experiments.render(versions, args.format), args.output)
        return 0
    parts = [experiments.render(versions, "table")]
    for digest in versions["dataset md5"]:
        parts.append(f"\n{digest} trained:\n"
                     + experiments.render(experiments.runs_of_dataset(runs, digest), "table"))
    _emit("".join(parts), args.output)
    return 0


def _reproduce(args: argparse.Namespace) -> int:
    from eskin import registry

    result = registry.reproduce(args.model, args.version, root=Path.cwd(),
                                log=lambda message: print(message, file=sys.stderr))
    print(registry.render_reproduction(result), end="")
    return 0 if result["reproduced"] else 1


def _learning_step(args: argparse.Namespace) -> int:
    from eskin import learn
    from eskin.config import load_params

    params = load_params(args.params)
    if args.command == "featurize":
        print(learn.featurize(params, args.scene, PROCESSED_DIR, FEATURES_DIR, MODELS_DIR))
    else:
        print(learn.train(params, args.scene, args.task, FEATURES_DIR,
                          params_text=Path(args.params).read_text(), track=not args.no_track,
                          **task_outputs(args.scene, args.task)))
    return 0


def _pipeline_step(args: argparse.Namespace) -> int:
    from eskin import steps
    from eskin.config import load_params

    params = load_params(args.params)
    if args.command == "acquire":
        if args.source:
            params["acquire"]["source"] = args.source
        if args.port:
            params["acquire"]["port"] = args.port
        print(steps.acquire(params, args.scene, RAW_DIR / args.scene,
                            progress=not args.no_progress))
    else:
        print(steps.ingest(params, args.scene, RAW_DIR / args.scene, PROCESSED_DIR))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.debug else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    return run_friendly(lambda: args.run(args), debug=args.debug)


def _terminated(signum, frame) -> None:
    raise SystemExit(128 + signum)


def run_friendly(call, *, debug: bool = False) -> int:
    """Run ``call``; turn the errors a user can act on into one line and exit code 1."""
    from eskin.acquisition.rawlog import RawLogError
    from eskin.acquisition.runner import AcquisitionError
    from eskin.data.schema import DatasetError
    from eskin.device.link import LinkError
    from eskin.experiments import NoRunsError

    # SIGTERM (`dvc queue kill`, a supervisor) unwinds like an exception: an open MLflow
    # run is closed as FAILED, worker processes are shut down, the raw log is flushed.
    signal.signal(signal.SIGTERM, _terminated)
    for stream in (sys.stdout, sys.stderr):  # an ASCII-only terminal: escape, never crash
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="backslashreplace")
    try:
        return call() or 0
    except KeyboardInterrupt:
        print("eskin: interrupted; everything received so far is on disk, rerun to resume",
              file=sys.stderr)
        return 130
    except (DatasetError, LinkError, AcquisitionError, RawLogError, NoRunsError, ValueError,
            KeyError, FileNotFoundError) as err:
        if debug:
            raise
        message = err.args[0] if isinstance(err, KeyError) and err.args else err
        print(f"eskin: error: {message}", file=sys.stderr)
        return 1

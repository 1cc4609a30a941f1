"""A lab's servers: MLflow on PostgreSQL, its artifacts served by MLflow; a DVC remote.

One researcher's clone logs to SQLite in the project (``mlflow.db``). A lab shares
one server: PostgreSQL as MLflow's backend store, and ``mlflow server
--serve-artifacts``, so that clients send artifacts through the server and need no
access to its disk. Every clone then sets ``MLFLOW_TRACKING_URI`` to the server's
address; the pipeline is unchanged. ``make lab-server`` (``python -m eskin.tracking.lab
serve``) starts them, and the DVC remote below, on 127.0.0.1 with their data under
``.lab/``; a lab that serves other machines puts them behind its own network or SSH tunnel.

PostgreSQL refuses to run as root: as root, its commands run as Debian's
``postgres`` user, which owns the data directory.

The lab's data (DVC's outputs: datasets, models, scores) is shared the same way: a DVC
remote in ``.lab/dvc-remote``, served over SFTP by Debian's OpenSSH server on 127.0.0.1
(``dvc-ssh`` is DVC's client for it), to a key made for it. A clone adds the remote,
``dvc pull``s what another pushed, and runs no stage to get it.
"""

from __future__ import annotations

import argparse
import contextlib
import glob
import os
import pwd
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from eskin.errors import EskinError, run_friendly

DATABASE = "mlflow"
START_S = 60.0   # each server has this long to answer


class LabServerError(EskinError, RuntimeError):
    """The lab server could not be set up or started."""


def await_server(process: subprocess.Popen, answers: Callable[[], bool],
                 exited: Callable[[int], str], silent: str) -> None:
    """Wait until a server ``process`` just started ``answers`` (an OSError: not yet), for
    at most :data:`START_S`. A server that exits first fails with ``exited(its code)``; one
    silent to the end is stopped and fails with ``silent``."""
    deadline = time.monotonic() + START_S
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise LabServerError(exited(process.returncode))
        try:
            if answers():
                return
        except OSError:
            pass
        time.sleep(0.25)
    stop_server(process)
    raise LabServerError(silent)


def stop_server(process: subprocess.Popen | None) -> None:
    """A server started in a session of its own: SIGTERM to its process group, SIGKILL
    after 15 s."""
    if process is not None and process.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait(timeout=15)


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _postgres_bin(name: str) -> str:
    found = shutil.which(name) or next(iter(sorted(glob.glob(
        f"/usr/lib/postgresql/*/bin/{name}"), reverse=True)), None)
    if found is None:
        raise LabServerError(f"PostgreSQL's {name} is not installed: run `make lab-server` "
                             "(it installs Debian's postgresql where missing)")
    return found


def _as_postgres(command: list[str]) -> list[str]:
    """PostgreSQL will not run as root: as root, run it as the ``postgres`` user."""
    if os.geteuid() != 0:
        return command
    return ["runuser", "-u", "postgres", "--", *command]


@dataclass
class Postgres:
    """A PostgreSQL cluster in ``directory``, listening on 127.0.0.1:``port`` only."""

    directory: Path
    port: int

    @property
    def data(self) -> Path:
        return self.directory / "pgdata"

    @property
    def uri(self) -> str:
        return f"postgresql+psycopg2://postgres@127.0.0.1:{self.port}/{DATABASE}"

    def _run(self, command: list[str], what: str, timeout_s: float = START_S) -> None:
        try:
            done = subprocess.run(_as_postgres(command), capture_output=True, text=True,
                                  timeout=timeout_s)
        except subprocess.TimeoutExpired:
            raise LabServerError(f"PostgreSQL: {what} took over {timeout_s:g} s") from None
        if done.returncode != 0:
            detail = (done.stderr or done.stdout).strip().splitlines()
            raise LabServerError(f"PostgreSQL: {what} failed: {detail[-1] if detail else '?'}"
                                 f" (log: {self.directory / 'postgres.log'})")

    def start(self) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        if os.geteuid() == 0:  # the postgres user must reach and own its files
            self.directory.chmod(0o755)
            shutil.chown(self.directory, "postgres")
        fresh = not (self.data / "PG_VERSION").exists()
        if fresh:
            self._run([_postgres_bin("initdb"), "-D", str(self.data), "-U", "postgres",
                       "--auth=trust", "-E", "UTF8"], "initdb")
        # Loopback only, and the socket in its own directory (not /var/run/postgresql).
        self._run([_postgres_bin("pg_ctl"), "-D", str(self.data), "-w", "-t", str(int(START_S)),
                   "-l", str(self.directory / "postgres.log"), "-o",
                   f"-h 127.0.0.1 -p {self.port} -k {self.directory}", "start"], "start")
        if fresh:
            self._run([_postgres_bin("createdb"), "-h", "127.0.0.1", "-p", str(self.port),
                       "-U", "postgres", DATABASE], "createdb")

    def stop(self) -> None:
        with contextlib.suppress(LabServerError):
            self._run([_postgres_bin("pg_ctl"), "-D", str(self.data), "-m", "fast", "-w",
                       "stop"], "stop")


@dataclass
class TrackingServer:
    """``mlflow server`` on the PostgreSQL store, serving artifacts from ``artifacts``."""

    store_uri: str
    artifacts: Path
    port: int
    log: Path
    process: subprocess.Popen | None = None

    @property
    def uri(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> None:
        self.artifacts.mkdir(parents=True, exist_ok=True)
        env = {**os.environ, "MLFLOW_ENABLE_TELEMETRY": "false",
               "MLFLOW_DISABLE_TELEMETRY": "true", "DO_NOT_TRACK": "1",
               # No job runner: eskin submits no (GenAI) jobs, and its consumers poll.
               "MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false"}
        with self.log.open("ab") as log:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "mlflow", "server", "--host", "127.0.0.1",
                 "--port", str(self.port), "--workers", "2",
                 "--backend-store-uri", self.store_uri, "--serve-artifacts",
                 "--artifacts-destination", str(self.artifacts)],
                stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        def healthy() -> bool:
            with urllib.request.urlopen(f"{self.uri}/health", timeout=2) as answer:
                return answer.status == 200

        def exited(code: int) -> str:
            return f"mlflow server exited ({code}); its log: {self.log}"

        await_server(self.process, healthy, exited,
                     f"mlflow server did not answer on {self.uri} within {START_S:g} s; "
                     f"its log: {self.log}")

    def stop(self) -> None:
        stop_server(self.process)


SSHD = "/usr/sbin/sshd"  # Debian's openssh-server; run by absolute path (it re-executes itself)


@dataclass
class DataRemote:
    """DVC's remote for a lab: ``directory/dvc-remote`` served over SFTP by OpenSSH's sshd
    on 127.0.0.1:``port``, to one key, made for it (``directory/ssh/client_ed25519``)."""

    directory: Path
    port: int
    process: subprocess.Popen | None = None

    @property
    def ssh(self) -> Path:
        return self.directory / "ssh"

    @property
    def objects(self) -> Path:
        return self.directory / "dvc-remote"

    @property
    def key(self) -> Path:
        return self.ssh / "client_ed25519"

    @property
    def host_key(self) -> Path:
        return self.ssh / "host_ed25519"

    @property
    def log(self) -> Path:
        return self.ssh / "sshd.log"

    @property
    def user(self) -> str:
        return pwd.getpwuid(os.geteuid()).pw_name  # the one AllowUsers lets in

    @property
    def url(self) -> str:
        return f"ssh://{self.user}@127.0.0.1:{self.port}{self.objects}"

    def clone_commands(self, name: str = "lab") -> list[str]:
        """What a clone runs to use the remote: in its .dvc/config.local (the remote is this
        machine's, and git status stays clean). No known_hosts line: DVC's SSH client
        (sshfs) connects with ``known_hosts=None``, checking no host key."""
        return [f"dvc remote add --local --default {name} {self.url}",
                f"dvc remote modify --local {name} keyfile {self.key}"]

    def _keygen(self, path: Path, comment: str) -> None:
        if path.exists():  # kept across restarts: clones keep their keyfile and known_hosts
            return
        done = subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", comment,
                               "-f", str(path)], capture_output=True, text=True,
                              timeout=START_S)
        if done.returncode != 0:
            raise LabServerError(f"ssh-keygen {path} failed: {done.stderr.strip()}")

    def _write_config(self) -> Path:
        authorized = self.ssh / "authorized_keys"
        # restrict: no forwarding, no terminal; ForceCommand below: SFTP only, which is all
        # DVC's remote does.
        authorized.write_text("restrict " + self.key.with_suffix(".pub").read_text())
        authorized.chmod(0o600)
        config = self.ssh / "sshd_config"
        config.write_text("\n".join([
            f"ListenAddress 127.0.0.1:{self.port}",
            f"HostKey {self.host_key}",
            f"PidFile {self.ssh / 'sshd.pid'}",
            f"AuthorizedKeysFile {authorized}",
            f"AllowUsers {self.user}",
            "PermitRootLogin prohibit-password",
            "PubkeyAuthentication yes",
            "PasswordAuthentication no",
            "KbdInteractiveAuthentication no",
            "UsePAM no",
            # The lab's directory may sit under a world-writable one (/tmp), which sshd's
            # check of every parent refuses; its own files are the user's, 0600 in 0700.
            "StrictModes no",
            "Subsystem sftp internal-sftp",
            "ForceCommand internal-sftp",
            "AllowTcpForwarding no",
            "AllowAgentForwarding no",
            "X11Forwarding no",
            "PermitTTY no",
            "",
        ]))
        return config

    def start(self) -> None:
        if not os.access(SSHD, os.X_OK):
            raise LabServerError(f"OpenSSH's sshd is not installed ({SSHD}): run `make "
                                 "lab-server` (it installs Debian's openssh-server where missing)")
        self.ssh.mkdir(parents=True, exist_ok=True)
        self.ssh.chmod(0o700)
        self.objects.mkdir(parents=True, exist_ok=True)
        self._keygen(self.host_key, "eskin lab: the DVC remote's host key")
        self._keygen(self.key, "eskin lab: DVC remote")
        config = self._write_config()
        if os.geteuid() == 0:  # Debian's sshd, as root, separates privileges there
            Path("/run/sshd").mkdir(mode=0o755, exist_ok=True)
        with self.log.open("ab") as log:
            self.process = subprocess.Popen([SSHD, "-D", "-e", "-f", str(config)],
                                            stdout=log, stderr=subprocess.STDOUT,
                                            start_new_session=True)
        def greets() -> bool:  # up when it greets: an SSH server's first line is its version
            with socket.create_connection(("127.0.0.1", self.port), timeout=2) as peer:
                return peer.recv(8).startswith(b"SSH-")

        def exited(code: int) -> str:
            tail = self.log.read_text(errors="replace").strip().splitlines()[-1:]
            return f"sshd exited ({code}): {tail[0] if tail else '?'} (log: {self.log})"

        await_server(self.process, greets, exited,
                     f"sshd did not answer on 127.0.0.1:{self.port} within {START_S:g} s; "
                     f"its log: {self.log}")

    def stop(self) -> None:
        stop_server(self.process)


@contextlib.contextmanager
def data_remote(directory: Path, *, port: int | None = None) -> Iterator[DataRemote]:
    """The lab's DVC remote over SSH on 127.0.0.1, stopped on exit."""
    remote = DataRemote(Path(directory).resolve(), port or free_port())
    remote.start()
    try:
        yield remote
    finally:
        remote.stop()


@contextlib.contextmanager
def lab_server(directory: Path, *, pg_port: int | None = None,
               port: int | None = None) -> Iterator[tuple[Postgres, TrackingServer]]:
    """PostgreSQL and the MLflow server on it, both on 127.0.0.1, stopped on exit."""
    directory = Path(directory).resolve()
    database = Postgres(directory / "postgres", pg_port or free_port())
    database.start()
    try:
        tracking = TrackingServer(database.uri, directory / "artifacts", port or free_port(),
                                  directory / "mlflow-server.log")
        tracking.start()
        try:
            yield database, tracking
        finally:
            tracking.stop()
    finally:
        database.stop()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m eskin.tracking.lab", description=__doc__.split(
        "\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    serve = commands.add_parser("serve", help="start PostgreSQL and the MLflow server on it, "
                                "and the DVC remote over SSH, until Ctrl-C")
    serve.add_argument("--dir", type=Path, default=Path(".lab"),
                       help="where the database and the artifacts live (default .lab)")
    serve.add_argument("--port", type=int, default=5000, help="MLflow's port (default 5000)")
    serve.add_argument("--pg-port", type=int, default=5433,
                       help="PostgreSQL's port (default 5433)")
    serve.add_argument("--ssh-port", type=int, default=2222,
                       help="the DVC remote's SSH port (default 2222)")
    args = parser.parse_args(argv)
    # Ctrl-C (SIGINT) stops the servers even where it came in ignored: a background job of
    # a non-interactive shell starts with SIGINT ignored, and then never stopped.
    signal.signal(signal.SIGINT, signal.default_int_handler)

    def serve_until_stopped() -> int:
        with lab_server(args.dir, pg_port=args.pg_port, port=args.port) as (database, tracking), \
                data_remote(args.dir, port=args.ssh_port) as remote:
            # The experiment made now, so that its page (in the training view) can be named.
            os.environ["MLFLOW_TRACKING_URI"] = tracking.uri
            from eskin.tracking import connection

            experiment = connection.ensure_experiment()
            try:  # from the line that says Ctrl-C on: a Ctrl-C right after it is a clean stop
                print(f"MLflow tracking server on {tracking.uri} (PostgreSQL {database.uri}; "
                      f"artifacts in {tracking.artifacts}); in each clone:\n"
                      f"  export MLFLOW_TRACKING_URI={tracking.uri}\n"
                      f"The training runs: {connection.ui_url(experiment)}\n"
                      f"DVC remote over SSH on 127.0.0.1:{remote.port} (objects in "
                      f"{remote.objects}); in each clone:\n"
                      + "".join(f"  {command}\n" for command in remote.clone_commands()) +
                      "Ctrl-C stops them.", flush=True)
                while tracking.process.poll() is None:
                    time.sleep(1)
            except KeyboardInterrupt:
                return 0
            raise LabServerError(f"mlflow server exited; its log: {tracking.log}")

    return run_friendly(serve_until_stopped, interrupted="the servers it started are stopped")


if __name__ == "__main__":
    sys.exit(main())

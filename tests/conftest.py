import contextlib
import copy
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest
import yaml

os.environ.setdefault("DVC_NO_ANALYTICS", "1")
# Under `make test` two test processes share the machine's two cores (pytest-xdist -n 2).
# OpenMP's threads (the gradient-boosted models') then spin-wait for a core the other
# process holds: two small pipelines side by side took 870 s with OpenMP's defaults, 73 s
# with one thread each, as fast as one pipeline alone with two (measured on this machine).
# Every process a test starts inherits it.
if "PYTEST_XDIST_WORKER" in os.environ:
    os.environ["OMP_NUM_THREADS"] = "1"

# The order of collection, the longest files first. `make test`'s two workers (pytest-xdist
# --dist loadfile) reorder the files by their number of tests, so it holds only for a run
# with --no-loadscope-reorder; with the longest first, `make test` was measured slower
# (930 s of tests against 853 s: the longest ran side by side and slowed each other).
LONGEST_FIRST = ("test_pipeline_tracking.py", "test_foreign_data.py", "test_views.py",
                 "test_stress.py")


def pytest_collection_modifyitems(items):
    def rank(item):
        name = Path(str(item.fspath)).name
        return LONGEST_FIRST.index(name) if name in LONGEST_FIRST else len(LONGEST_FIRST)

    items.sort(key=rank)  # stable: within a file, and among the rest, the order holds


ROOT = Path(__file__).resolve().parents[1]

# `make check`: the tests that start no pipeline, server, emulator or browser (the others
# are marked `starts`: a module's `pytestmark`, or the test's own mark). Under it
# (ESKIN_CHECK=1), a test that starts one anyway fails and names what it started, so
# the mark cannot silently go missing.
CHECK_ENV = "ESKIN_CHECK"
STARTS = (("dvc", "repro"), ("dvc", "exp"), ("mlflow", "server"), ("mlflow", "ui"),
          ("simavr",), ("chromium",), ("postgres",),
          ("pg_ctl",), ("initdb",), ("sshd",), ("make",), ("eskin.device.emulated",))


def starts_what(args) -> str | None:
    """What a process started with ``args`` is, if a check-tier test may not start it."""
    argv = shlex.split(args) if isinstance(args, str) else [str(a) for a in args]
    words = {os.path.basename(word) for word in argv}
    emulator = any(word.startswith("eskin_emulator") for word in words)
    browser = bool(argv) and "playwright" in argv[0]  # its driver, which starts chromium
    if emulator or browser or any(set(pattern) <= words for pattern in STARTS):
        return " ".join(argv)[:120]
    return None


_running_test = [""]
# CPU seconds per test file: this process's and its waited-for children's (DVC, stages,
# servers once stopped), setup and teardown included; a session fixture's build counts in
# the first test that asks for it. `make test` prints the table: on two cores the suite's
# length is bounded by its CPU, not by its waits (issue 55).
_cpu_by_file: Counter[str] = Counter()


def _cpu_seconds() -> float:
    import resource

    own, children = (resource.getrusage(who) for who in (resource.RUSAGE_SELF,
                                                         resource.RUSAGE_CHILDREN))
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    _running_test[0] = item.nodeid  # its fixtures' setup included, of every scope
    before = _cpu_seconds()
    yield
    _running_test[0] = ""
    name = item.nodeid.split("::")[0]
    _cpu_by_file[name] += _cpu_seconds() - before


def pytest_sessionfinish(session):
    if hasattr(session.config, "workeroutput"):  # a pytest-xdist worker: to the controller
        session.config.workeroutput["cpu_by_file"] = dict(_cpu_by_file)


@pytest.hookimpl(optionalhook=True)  # pytest-xdist's
def pytest_testnodedown(node, error):
    _cpu_by_file.update(getattr(node, "workeroutput", {}).get("cpu_by_file", {}))


def pytest_terminal_summary(terminalreporter, config):
    total = sum(_cpu_by_file.values())
    if not config.getoption("--cpu-by-file") or total <= 0:  # none, or below the clock's tick
        return
    terminalreporter.section(f"CPU by test file: {total:.0f} CPU-s in all")
    for name, seconds in _cpu_by_file.most_common(15):
        terminalreporter.write_line(f"{seconds:7.1f} CPU-s {seconds / total:6.1%}  {name}")


def pytest_addoption(parser):
    parser.addoption("--cpu-by-file", action="store_true",
                     help="print the CPU seconds each test file took, the 15 largest")


def pytest_configure(config):
    if os.environ.get(CHECK_ENV) != "1":
        return
    real = subprocess.Popen.__init__

    def guarded(self, args, *rest, **kwargs):
        started = starts_what(args)
        if started is not None:
            raise AssertionError(f"{_running_test[0]} started {started!r}: mark it `starts` "
                                 "(pytest.mark.starts); `make check` leaves those out")
        real(self, args, *rest, **kwargs)

    subprocess.Popen.__init__ = guarded

# Pages (the report, the live view, DVC's plots, MLflow's UI) are tested in Debian's
# chromium, headless; `make test` installs it where missing.
CHROMIUM = shutil.which("chromium")
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="Debian's chromium is missing: `make test` installs it")


@pytest.fixture(autouse=True)
def _mlflow_tracking_uri_per_test():
    """Each test starts with no MLflow tracking URI of another test's. MLflow keeps the one
    `mlflow.set_tracking_uri` sets (a test's, or eskin's own `connection.connect()` run in the
    test's process) in a global that wins over MLFLOW_TRACKING_URI, and writes it to the
    environment too, outside monkeypatch: a later test in the same worker then talked to
    a server since stopped."""
    before = os.environ.get("MLFLOW_TRACKING_URI")
    yield
    if "mlflow" in sys.modules:
        import mlflow

        mlflow.set_tracking_uri(None)
    if before is None:
        os.environ.pop("MLFLOW_TRACKING_URI", None)
    else:
        os.environ["MLFLOW_TRACKING_URI"] = before


@contextlib.contextmanager
def headless_chromium():
    """Debian's chromium under playwright: the browser, closed on leaving."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM,
                                             args=["--no-sandbox", "--disable-gpu"])
        try:
            yield browser
        finally:
            browser.close()


@pytest.fixture(scope="session")
def repo_params():
    return yaml.safe_load((ROOT / "params.yaml").read_text())


@pytest.fixture(scope="session")
def repo_bench_params():
    """bench/params.yaml: `make bench`'s knobs (bench, soak, fuzz)."""
    return yaml.safe_load((ROOT / "bench" / "params.yaml").read_text())


def small_scenes(repo_params: dict) -> dict:
    """The repo's params with small scenes: 2 stretches × 2 forces × 101 nodes × 5 samples
    single force (2,020 rows); 1 stretch × 2 × 2 forces × 36 pairs × 5 two force."""
    params = copy.deepcopy(repo_params)
    params["scenes"]["single_force"].update(stretches=[1.0, 1.07921], forces=[0.0, 3.2536],
                                            samples=5)
    params["scenes"]["two_force"].update(forces=[1.2936, 5.2136], samples=5)
    return params


def typed(params):
    """A scratch params dict (the tests edit them as the YAML reads) validated into the
    :class:`eskin.config.Params` the steps take; a Params as it is."""
    from eskin.config.base import validate_params
    from eskin.config.params import Params

    return params if isinstance(params, Params) else validate_params(params, Params)


def acquire_step(params, scene: str, raw_dir: Path, **kwargs):
    """The acquisition step as its stage runs it: every scene checked, then ``scene``."""
    from eskin.acquisition import acquire
    from eskin.config.base import validating

    params = typed(params)
    with validating():
        acquire.check_scenes(params.scenes, params.cv)
    return acquire.acquire(scene, params.scenes[scene], raw_dir, acquire=params.acquire,
                           sim=params.sim, board=params.sim_board, **kwargs)


def ingest_step(params, scene: str, raw_dir: Path, processed_dir: Path):
    from eskin.steps.ingest import ingest_at

    params = typed(params)
    return ingest_at(scene, params.scenes[scene], raw_dir, processed_dir,
                     ingest=params.ingest)


def featurize_step(params, scene: str, processed_dir: Path, features_dir: Path,
                   models_dir: Path):
    from eskin.steps.featurize import featurize_at

    return featurize_at(scene, processed_dir, features_dir, models_dir,
                        settings=typed(params).featurize)


def train_step(params, scene: str, task: str, features_dir: Path, **kwargs):
    """The folds and training steps as their stages run them (the outputs in ``kwargs``;
    the folds go beside the features, in ``folds/``, unless ``folds_path`` says where)."""
    from eskin.steps.folds import folds_at
    from eskin.steps.train import train_at

    params = typed(params)
    folds = kwargs.pop("folds_path", Path(features_dir).parent / "folds" / f"{scene}.parquet")
    folds_at(Path(features_dir) / f"{scene}.parquet", folds,
             schemes=list(params.cv.schemes), n_splits=int(params.cv.folds),
             seed=int(params.cv.seed), scene=scene)
    return train_at(scene, task, task_params=getattr(params.train, task),
                       configuration=params.train.configuration, cv=params.cv,
                       features_dir=features_dir, folds_path=folds, **kwargs)


def prepared_scene(params: dict, scene: str, root: Path) -> Path:
    """``scene`` acquired from the simulated board over a pty and ingested under ``root``
    (raw/<scene>, processed/); returns the dataset's path."""
    acquire_step(params, scene, root / "raw" / scene, progress=False)
    ingest_step(params, scene, root / "raw" / scene, root / "processed")
    return root / "processed" / f"{scene}.parquet"


def small_stack(params: dict, root: Path):
    """The repo's default models of the single-force scene, trained on ``params``' (the
    small scene's) rows under ``root``: a SkinStack, as `eskin live` builds from the
    workspace's models, for tests that cannot wait for the pipeline's."""
    import joblib
    import pandas as pd

    from eskin.data.schema import read_dataset, read_metadata
    from eskin.deploy.stack import SkinStack, rest_readings
    from eskin.evaluation.crossval import fit_final
    from eskin.evaluation.tasks import get_task
    from eskin.learning.choice import model_settings
    from eskin.learning.estimators import build_model
    from eskin.skin import PAPER_SKIN

    processed = prepared_scene(params, "single_force", root)
    featurize_step(params, "single_force", root / "processed", root / "features",
                   root / "models")
    features = read_dataset(root / "features" / "single_force.parquet")
    models = {}
    for name in ("stretch", "force", "detect", "localise"):
        task = get_task("single_force", name)
        model, hyper = model_settings(getattr(typed(params).train, name), "tuned",
                                      "single_force")
        models[name] = fit_final(task, features, build_model(task.role, model, hyper, PAPER_SKIN),
                                 PAPER_SKIN)
    featurizer = joblib.load(root / "models" / "single_force" / "featurizer.joblib")
    return SkinStack("single_force", "single_force", PAPER_SKIN, featurizer, models,
                     device=read_metadata(processed)["device"],
                     rest=rest_readings(pd.read_parquet(processed), PAPER_SKIN))


@pytest.fixture
def small_params(repo_params):
    return small_scenes(repo_params)


def write_params(directory: Path, params: dict) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "params.yaml"
    path.write_text(yaml.safe_dump(params, sort_keys=False))
    return path


PROJECT_FILES = ["eskin", "stages", "harness", "firmware", "dvc.yaml", "bench", "stress",
                 ".dvcignore", ".gitignore", "pyproject.toml", "README.md"]


def run_checked(args, cwd, env, *, ok=True) -> subprocess.CompletedProcess:
    """Run a command (dvc, git, eskin) in ``cwd``; with ``ok``, fail the test on a non-zero
    exit, showing its output."""
    done = subprocess.run(args, cwd=cwd, env=env, text=True, capture_output=True, timeout=900)
    if ok:
        assert done.returncode == 0, f"{' '.join(args)} failed:\n{done.stdout}\n{done.stderr}"
    return done


def params_trace_dir(root: Path) -> Path:
    """Where a scratch project's processes note the params keys they read."""
    return root.parent / f"{root.name}-params-read"


def project_env(root: Path, tracking_uri: str) -> dict:
    """The environment a scratch project's commands run in, logging to MLflow at
    ``tracking_uri``."""
    bin_dir = str(Path(sys.executable).parent)  # dvc, and the python DVC's stages call
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}",
           "DVC_NO_ANALYTICS": "1", "MLFLOW_ENABLE_TELEMETRY": "false",
           "MLFLOW_TRACKING_URI": tracking_uri,
           # each stage notes the params it reads (tests/test_stage_deps.params_mismatches)
           "ESKIN_PARAMS_TRACE": str(params_trace_dir(root)),
           "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_NAME": "t",
           "GIT_COMMITTER_EMAIL": "t@t"}
    env.pop("DVC_ROOT", None)
    return env


def quick_params(params: dict, *, folds: int, conditions_only: bool = False) -> dict:
    """``params``, changed in place, with the knobs turned down that cost time and that
    tests of the plumbing (not of the scores) do not look at: ``folds`` folds in one
    process, small figures, smaller paper models; with ``conditions_only``, the
    conditions scheme alone (CV and figures)."""
    params["cv"].update(n_jobs=1, folds=folds)
    params["report"].update(dpi=60, page_dpi=50)
    if conditions_only:
        params["cv"]["schemes"] = ["conditions"]
        params["report"].update(schemes=["conditions"], plots_scheme="conditions")
    params["train"]["force"]["paper"]["subsample"] = 200
    params["train"]["localise"]["paper"]["n_estimators"] = 20
    return params


def small_pipeline_params(repo_params: dict) -> dict:
    """The small scenes, with :func:`quick_params` (3 folds)."""
    return quick_params(small_scenes(repo_params), folds=3)


@pytest.fixture(scope="session")
def small_pipeline(tmp_path_factory, repo_params) -> Path:
    """A scratch project with :func:`small_pipeline_params`, reproduced and committed, built
    once per test session: under `make test`'s two workers, by the first that asks while
    the other waits on a lock. Tests work on copies of it (:func:`copy_small_pipeline`)."""
    import fcntl

    base = tmp_path_factory.getbasetemp()
    shared = base.parent if "PYTEST_XDIST_WORKER" in os.environ else base  # the session's
    root, built = shared / "small_pipeline", shared / "small_pipeline.built"
    with (shared / "small_pipeline.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not built.exists():
            shutil.rmtree(root, ignore_errors=True)  # a build that failed half-way
            root.mkdir()
            env = scratch_project(root, small_pipeline_params(repo_params),
                                  f"sqlite:///{shared / 'small_pipeline.db'}")
            for args in (["dvc", "repro"], ["git", "add", "-A"],
                         ["git", "commit", "-qm", "repro"]):
                run_checked(args, root, env)
            built.touch()
    return root


def copy_small_pipeline(small_pipeline: Path, root: Path, tracking_uri: str, *,
                        track: bool = True) -> dict:
    """A copy at ``root`` of the built small pipeline (its git and DVC repositories, cache
    and workspace, and the params its stages noted reading), logging to MLflow at
    ``tracking_uri``; with ``track``, its publish stage run again there, which logs the
    pipeline as its first `dvc repro` did. Returns the environment its commands run in."""
    shutil.copytree(small_pipeline, root, symlinks=True, dirs_exist_ok=True,
                    # DVC's locks and state, and the build's MLflow artifacts: not the copy's
                    ignore=lambda directory, names: {small_pipeline / ".dvc": ["tmp"],
                                                     small_pipeline: ["mlruns"]}.get(
                                                         Path(directory), []))
    shutil.copytree(params_trace_dir(small_pipeline), params_trace_dir(root))
    env = project_env(root, tracking_uri)
    if track:
        run_checked(["dvc", "repro", "--force", "--single-item", "publish"], root, env)
    return env


def scratch_project(root: Path, params: dict, tracking_uri: str, *,
                    bench_params: dict | None = None) -> dict:
    """A scratch copy of the project at ``root`` (code, dvc.yaml, README) with ``params``
    (and ``bench_params`` as bench/params.yaml, the repository's by default), committed in
    a fresh git and DVC repository; returns the environment its commands run in, logging
    to MLflow at ``tracking_uri``."""
    import shutil

    for name in PROJECT_FILES:
        source = ROOT / name
        if source.is_dir():
            shutil.copytree(source, root / name,
                            ignore=shutil.ignore_patterns("__pycache__", "dvc.lock", "build", "tmp",
                                                          "config.local", "bound"))
        else:
            shutil.copy2(source, root / name)
    write_params(root, params)
    if bench_params is not None:
        write_params(root / "bench", bench_params)
    env = project_env(root, tracking_uri)
    for args in (["git", "init", "-q"], ["dvc", "init", "-q"],
                 ["dvc", "config", "core.analytics", "false"]):
        run_checked(args, root, env)
    # the plot templates, and the offline page template `make setup` writes (and names in
    # .dvc/config.local, as here)
    shutil.copytree(ROOT / ".dvc" / "plots", root / ".dvc" / "plots")
    shutil.copy2(ROOT / ".dvc" / ".gitignore", root / ".dvc" / ".gitignore")
    if (root / ".dvc" / "plots" / "offline.html").exists():
        run_checked(["dvc", "config", "--local", "plots.html_template", "plots/offline.html"],
                    root, env)
    for args in (["git", "add", "-A"], ["git", "commit", "-qm", "scratch"]):
        run_checked(args, root, env)
    return env


def acquire_until(params, root, *, complete):
    """`eskin acquire single_force` in its own process, once ``complete`` conditions are in
    the log: (the still running process, the log)."""
    write_params(root, params)
    log = root / "data" / "raw" / "single_force" / "acquisition.log"
    # SIGINT as in a terminal: a shell starting a job in the background (as CI may run
    # `make test`) leaves SIGINT ignored, and Python then never raises KeyboardInterrupt.
    process = subprocess.Popen([sys.executable, "-m", "eskin", "acquire", "single_force",
                                "--no-progress"], cwd=root, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    from harness.soak import wait_for_conditions

    done = wait_for_conditions(log, complete, process, time.monotonic() + 60)
    assert done is not None, f"the acquisition ended before {complete} conditions were complete"
    return process, log


def resume_and_ingest(root: Path, total: int, before: int):
    """`eskin acquire single_force` again after a kill that left ``before`` of ``total``
    trials complete, then `eskin ingest`: the resumed dataset (the summary checked)."""
    import pandas as pd

    resumed = eskin(["acquire", "single_force", "--no-progress"], root)
    assert resumed.returncode == 0, resumed.stderr
    assert f"{total - before} trial(s) acquired, {before} reused" in resumed.stdout
    ingested = eskin(["ingest", "single_force"], root)
    assert ingested.returncode == 0, ingested.stderr
    return pd.read_parquet(root / "data" / "processed" / "single_force.parquet")


def eskin(args, cwd, **kwargs):
    """Run the eskin CLI in its own process, as a user would."""
    return subprocess.run([sys.executable, "-m", "eskin", *args], cwd=cwd, text=True,
                          capture_output=True, timeout=300, **kwargs)


@pytest.fixture(scope="module")
def lab():
    """A lab's tracking server (eskin/tracking/lab.py): PostgreSQL on 127.0.0.1 and `mlflow server
    --serve-artifacts` on it; yields (database, tracking server). One per test module."""
    import shutil
    import tempfile

    from eskin.tracking.lab import LabServerError, lab_server

    home = Path(tempfile.mkdtemp(prefix="eskin-lab-"))  # postgres must reach it: not 0700
    home.chmod(0o755)
    try:
        with lab_server(home) as servers:
            yield servers
    except LabServerError as err:
        pytest.fail(f"{err} (`make test` installs PostgreSQL where missing)")
    finally:
        shutil.rmtree(home, ignore_errors=True)


@pytest.fixture(scope="module")
def mlflow_server(tmp_path_factory):
    """A real `mlflow server` on 127.0.0.1 (SQLite backend, proxied artifacts in a temp dir);
    yields its URI. One per test module, so one module's runs are not another's."""
    import socket
    import time
    import urllib.request

    home = tmp_path_factory.mktemp("mlflow_server")
    with socket.socket() as probe:  # a free loopback port
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    uri = f"http://127.0.0.1:{port}"
    log = (home / "server.log").open("w")
    server = subprocess.Popen(
        [str(Path(sys.executable).parent / "mlflow"), "server", "--host", "127.0.0.1",
         "--port", str(port), "--workers", "1",
         "--backend-store-uri", f"sqlite:///{home / 'mlflow.db'}",
         "--artifacts-destination", str(home / "artifacts")],
        stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
        # No job runner: MLflow 3 starts six huey consumers that poll for (GenAI) jobs
        # eskin never submits, and took half a core for the server's whole life.
        env={**os.environ, "MLFLOW_ENABLE_TELEMETRY": "false",
             "MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false"})
    deadline = time.monotonic() + 90
    while True:
        try:
            with urllib.request.urlopen(f"{uri}/health", timeout=2) as answer:
                if answer.status == 200:
                    break
        except OSError:
            pass
        if server.poll() is not None or time.monotonic() > deadline:
            server.kill()
            pytest.fail(f"mlflow server did not start:\n{(home / 'server.log').read_text()}")
        time.sleep(0.5)
    yield uri
    os.killpg(server.pid, 15)
    try:
        server.wait(timeout=20)
    except subprocess.TimeoutExpired:
        os.killpg(server.pid, 9)
        server.wait()
    log.close()

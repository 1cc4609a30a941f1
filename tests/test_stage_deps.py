"""Declared equals read: each DVC stage lists exactly the code it runs.

A stage's code is the import closure of the module its command runs
(``python -m stages.X``), computed from the source: every ``import`` and
``from … import`` of eskin or stages modules, at module level or inside a
function, and every module a child process is started on (``"-m", "<module>"``
in an argument list, or the imports of ``"-c", <code>``; ``"dvc", "repro"``: every
module the pipeline runs). Imports under ``if TYPE_CHECKING:`` never run, and do not
count. A package's ``__init__.py`` counts imported by name (``from eskin import
__version__``); the others hold no code (checked below). The test fails when dvc.yaml,
bench/dvc.yaml or stress/dvc.yaml misses a file of the closure or lists one the stage does
not run, and says which.

The params half, :func:`params_mismatches`, is called by the tests that reproduce a
scratch project (test_pipeline_tracking, test_foreign_data): each stage process there
notes the params keys it reads (``ESKIN_PARAMS_TRACE``), compared with its declared params.
"""

from __future__ import annotations

import ast
import os
import shlex
from collections.abc import Collection, Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("eskin", "stages", "harness")


def module_file(name: str) -> Path | None:
    """The file of module ``name`` in this project (None for anything else)."""
    if name.split(".")[0] not in PACKAGES:
        return None
    base = ROOT.joinpath(*name.split("."))
    if base.with_suffix(".py").is_file():
        return base.with_suffix(".py")
    if (base / "__init__.py").is_file():
        return base / "__init__.py"
    return None


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(path: Path, source: str | None = None) -> Iterator[str]:
    """Every project module ``path`` (or ``source``, code run as ``path``'s child)
    imports or starts a process on."""
    tree = ast.parse(source or path.read_text(encoding="utf-8"), str(path))
    package = module_name(path) if path.name == "__init__.py" else \
        module_name(path).rpartition(".")[0]
    strings = {target.id: node.value.value for node in tree.body
               if isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant)
               and isinstance(node.value.value, str)
               for target in node.targets if isinstance(target, ast.Name)}
    for node in _running(tree):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            for alias in node.names:  # `from eskin import learn`: a module, not a name
                if module_file(f"{base}.{alias.name}") is not None:
                    yield f"{base}.{alias.name}"
                else:  # a name defined in ``base`` itself (its __init__.py, for a package)
                    yield base
        elif isinstance(node, ast.List | ast.Tuple):
            values = [e.value if isinstance(e, ast.Constant) else
                      strings.get(e.id) if isinstance(e, ast.Name) else None for e in node.elts]
            for flag, target in zip(values, values[1:], strict=False):
                if flag == "-m" and isinstance(target, str):
                    yield "eskin.__main__" if target == "eskin" else target
                if flag == "dvc" and target == "repro":  # the whole pipeline, run
                    yield from pipeline_modules()
                if flag == "-c" and isinstance(target, str):
                    yield from imported_modules(path, target)


def _running(tree: ast.AST) -> Iterator[ast.AST]:
    """Every node of ``tree`` but those under ``if TYPE_CHECKING:``, which never run (a
    type checker's imports)."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.If) and getattr(node.test, "id", None) == "TYPE_CHECKING":
            yield from (n for child in node.orelse for n in [child, *_running(child)])
            continue
        yield node
        yield from _running(node)


def pipeline_modules() -> list[str]:
    """The modules the project's pipeline (dvc.yaml) runs, a stage each."""
    import yaml

    out = []
    for stage in yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"].values():
        words = shlex.split(stage.get("do", stage)["cmd"])
        out.append(words[words.index("-m") + 1])
    return out


# Modules a module runs without importing them by name: loading a saved model
# (eskin/learning/saved.py) unpickles its estimators, which imports the module that
# defines them (and, through it, the Gaussian processes').
RUNS_WHEN_LOADING = {"eskin.learning.saved": ("eskin.learning.estimators",)}


def closure(module: str) -> set[Path]:
    """The files ``module`` runs: itself and everything it imports, transitively
    (with :data:`RUNS_WHEN_LOADING`)."""
    start = module_file(module)
    assert start is not None, f"no module {module}"
    seen: set[Path] = set()
    todo = [start]
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        for name in [*imported_modules(path), *RUNS_WHEN_LOADING.get(module_name(path), ())]:
            found = module_file(name)
            if found is not None and found not in seen:
                todo.append(found)
    return seen


def declared_code(paths: list[Path]) -> set[Path]:
    """The .py files that the declared deps cover (a directory: every file in it)."""
    out = set()
    for path in paths:
        if path.suffix == ".py":
            out.add(path)
        elif path.is_dir():
            out |= set(path.rglob("*.py"))
    return {p for p in out if "__pycache__" not in p.parts}


def implicit_init(path: Path) -> bool:
    """A package's __init__.py, run by importing any module in it (they hold no code,
    checked below; eskin/__init__.py holds the version, counted where it is imported)."""
    return path.name == "__init__.py"


SUBPROJECTS = ("bench", "stress")  # DVC projects of their own (dvc init --subdir)


def project_stages(project: Path) -> Iterator[tuple[str, list[str], object]]:
    """(address from ``project``, command words, stage) of every stage of the project's
    pipeline and of its subprojects'. A subproject's stage runs at the project's root
    (``cd .. && python -m …``): the words are the command's after the ``cd``."""
    from dvc.repo import Repo

    for sub in ("", *SUBPROJECTS):
        if sub and not (project / sub / ".dvc").is_dir():
            continue
        with Repo(str(project / sub)) as repo:
            for stage in repo.index.stages:
                words = shlex.split(stage.cmd if isinstance(stage.cmd, str) else stage.cmd[0])
                if sub:
                    assert words[:3] == ["cd", "..", "&&"], f"{stage.addressing}: {stage.cmd}"
                    words = words[3:]
                address = f"{os.path.relpath(stage.dvcfile.path, project)}:{stage.name}"
                yield address, words, stage


def stages() -> list[tuple[str, str, list[Path]]]:
    """(stage address, module its command runs, declared deps) of every DVC stage."""
    out = []
    for address, words, stage in project_stages(ROOT):
        assert words[:2] == ["python", "-m"], f"{address}: {' '.join(words)}"
        deps = [Path(dep.fs_path) for dep in stage.deps
                if Path(dep.fs_path).is_relative_to(ROOT)]
        out.append((address, words[2], deps))
    return out


STAGES = stages()


@pytest.mark.parametrize("address, module, deps", STAGES, ids=[s[0] for s in STAGES])
def test_each_stage_lists_exactly_the_code_it_runs(address, module, deps):
    ran = closure(module)
    declared = declared_code([d for d in deps if d.parts[len(ROOT.parts)] in PACKAGES])
    counted = {p for p in ran | declared
               if not implicit_init(p) or p == ROOT / "eskin" / "__init__.py"}
    missing = sorted(str(p.relative_to(ROOT)) for p in (ran - declared) & counted)
    unused = sorted(str(p.relative_to(ROOT)) for p in (declared - ran) & counted)
    assert not missing and not unused, (
        f"{address} (python -m {module}): dvc.yaml misses {missing or 'nothing'}; "
        f"lists, but does not run, {unused or 'nothing'}")


@pytest.mark.parametrize("address, module, deps", STAGES, ids=[s[0] for s in STAGES])
def test_a_stage_that_can_run_the_firmware_lists_its_sources(address, module, deps):
    """The emulated board is built from firmware/ (eskin.device.emulated rebuilds it
    before a run): a stage that can run it lists those sources, and no other stage does."""
    from eskin.device.emulated import FIRMWARE_SOURCES

    runs_firmware = ROOT / "eskin/device/emulated.py" in closure(module)
    listed = {ROOT / source for source in FIRMWARE_SOURCES} & set(deps)
    expected = {ROOT / source for source in FIRMWARE_SOURCES} if runs_firmware else set()
    assert listed == expected, (
        f"{address}: {'misses' if runs_firmware else 'lists, but does not run,'} "
        f"{sorted(str(p.relative_to(ROOT)) for p in listed ^ expected)}")


def test_subpackage_init_files_hold_no_code():
    """So a stage that imports eskin.device.link need not list eskin/device/__init__.py."""
    for path in ROOT.glob("*/**/__init__.py"):
        if path.parts[len(ROOT.parts)] not in PACKAGES or path == ROOT / "eskin/__init__.py":
            continue
        body = ast.parse(path.read_text()).body
        assert all(isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)
                   for node in body), f"{path} holds code"


def test_the_closure_finds_what_a_stage_imports_lazily_and_starts_as_a_process(tmp_path):
    """The checker itself: a function-local import and a child process both count."""
    report = closure("eskin.reporting.report")
    assert ROOT / "eskin/evaluation/tasks.py" in report  # imported inside headline_metrics()
    learn = closure("eskin.learning.train")
    assert ROOT / "eskin/learning/gp.py" in learn            # through eskin.learning.estimators
    train = closure("stages.train")
    assert ROOT / "eskin/steps/export.py" in train      # imported inside main()
    session = closure("eskin.acquisition.session")
    assert ROOT / "eskin/device/board.py" in session  # the simulated board's own process


def test_dvc_yaml_trains_every_task_of_the_catalog():
    import yaml

    from eskin.catalog import TASK_NAMES

    pipeline = yaml.safe_load((ROOT / "dvc.yaml").read_text())
    stage = pipeline["stages"]["train"]["do"]
    outs = [next(iter(out)) if isinstance(out, dict) else out for out in stage["outs"]]
    # then the scene's stack, exported in the same process
    assert outs[-2:] == ["models/${key}/stack.onnx", "reports/export/${key}.json"]
    named = [path.rsplit("/", 1)[1].split(".")[0] for path in outs[:-2]]
    assert tuple(dict.fromkeys(named)) == TASK_NAMES
    assert [named.count(task) for task in TASK_NAMES] == [4] * len(TASK_NAMES)
    # each kept in place for the step to keep (persist): DVC would otherwise remove them
    assert all(isinstance(out, dict) and next(iter(out.values()))["persist"]
               for out in stage["outs"])


# ------------------------------------------------------------------ params: declared = read

def params_mismatches(project: Path, trace_dir: Path, *,
                      partly_run: Collection[str] = ()) -> list[str]:
    """Each stage run in ``project`` with ``ESKIN_PARAMS_TRACE=trace_dir`` (the pipeline
    tests' scratch projects), against the params its dvc.yaml entry declares: a key read
    but not declared (changing it would not rerun the stage), or declared but never read
    (changing it reruns the stage for nothing). A declared section covers every key in
    it; a section read whole (iterated, copied) covers every declared key in it.

    "Declared but never read" is judged over every run of a stage's template (``train``
    over its scenes and tasks, names replaced by placeholders): a task one scene skips
    reads less than the same task where it trains. ``partly_run`` names templates
    (``bench/dvc.yaml:bound``) whose runs here all took a shorter path, so it is not
    judged for them."""
    import json

    def within(key: str, section: str) -> bool:
        return key == section or key.startswith(section + ".") or section == "*"

    def template(key: str, args: tuple[str, ...]) -> str:
        return ".".join(f"{{{args.index(part)}}}" if part in args else part
                        for part in key.split("."))

    reads: dict[tuple[str, ...], set[str]] = {}
    for path in Path(trace_dir).glob("params-read-*.json"):
        trace = json.loads(path.read_text())
        script = Path(trace["argv"][0])  # python -m stages.X: argv[0] is …/stages/X.py
        if script.parent.name == "stages":
            reads.setdefault((f"stages.{script.stem}", *trace["argv"][1:]),
                             set()).update(trace["reads"])
    assert reads, f"no params traces in {trace_dir}"
    problems = []
    groups: dict[str, tuple[list[str], set[str], set[str]]] = {}
    for address, words, stage in project_stages(project):
        command, args = (words[2], *words[3:]), tuple(words[3:])
        if command not in reads:
            continue  # not run by this test
        keys = [key for dep in stage.deps if type(dep).__name__ == "ParamsDependency"
                for key in dep.params]
        read = reads[command]
        missing = sorted(r for r in read if not any(within(r, k) for k in keys))
        if missing:
            problems.append(f"{address}: reads {missing}, which it does not declare")
        # the template: bench/dvc.yaml:bound for bench/dvc.yaml:bound@<scene>
        name = address.split("@")[0]
        if name in partly_run:
            continue
        addresses, declared, group_reads = groups.setdefault(name, ([], set(), set()))
        addresses.append(stage.name)
        declared.update(template(k, args) for k in keys)
        group_reads.update(template(r, args) for r in read)
    assert groups, f"no traced process ran a stage of {project}"
    for name, (addresses, declared, group_reads) in groups.items():
        unused = sorted(k for k in declared
                        if not any(within(r, k) or within(k, r) for r in group_reads))
        if unused:
            problems.append(f"{name} ({', '.join(addresses)}): declare {unused}, which none "
                            "of them reads")
    return problems


# ------------------------------------------------------------------ imports point one way

def test_a_robot_side_stack_imports_neither_mlflow_nor_dvc():
    """Loading and running a stack (deploy/) pulls in no tracking: a robot needs neither."""
    import subprocess
    import sys

    code = ("import sys; import eskin.deploy.stack, eskin.deploy.live, eskin.deploy.view; "
            "print(sorted(m for m in ('mlflow', 'dvc') if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=120, check=True)
    assert done.stdout.strip() == "[]", done.stdout
    for module in ("eskin.deploy.stack", "eskin.deploy.live", "eskin.deploy.export"):
        reached = {module_name(p) for p in closure(module)}
        wrong = sorted(m for m in reached if m.startswith(("eskin.tracking", "eskin.evaluation"))
                       or m == "eskin.learning.train")
        assert not wrong, f"{module} imports {wrong}"


def test_params_schema_imports_no_device_or_acquisition_code():
    """A physics edit reruns acquisition and what follows from its data, not training."""
    schemas = [module_name(p) for p in (ROOT / "eskin" / "config").glob("*.py")
               if p.name != "__init__.py"]
    assert "eskin.config.params" in schemas
    for schema in schemas:
        reached = {module_name(p) for p in closure(schema)}
        wrong = sorted(m for m in reached if m.startswith(("eskin.device", "eskin.acquisition")))
        assert not wrong, f"{schema} imports {wrong}"


def test_a_params_section_schema_imports_no_other_section():
    """A stage depends on the schemas of the sections it reads, not on every section's:
    each section module imports only the loader (and the vocabulary), so that a schema
    edit reruns only the stages that read that section."""
    for path in (ROOT / "eskin" / "config").glob("*.py"):
        if path.name in ("__init__.py", "params.py", "base.py"):
            continue
        reached = {module_name(p) for p in closure(module_name(path))}
        others = sorted(m for m in reached if m.startswith("eskin.config.")
                        and m not in (module_name(path), "eskin.config.base"))
        assert not others, f"{module_name(path)} imports {others}"


def test_no_two_packages_import_each_other():
    """The layout is the pipeline: each package of eskin builds on those below it, and
    none imports one that imports it back (acquisition writes the raw log that data
    reads; evaluation scores what learning trains)."""
    packages = sorted(p.name for p in (ROOT / "eskin").iterdir()
                      if (p / "__init__.py").is_file())
    imports: dict[str, set[str]] = {name: set() for name in packages}
    for name in packages:
        for path in (ROOT / "eskin" / name).rglob("*.py"):
            for module in imported_modules(path):
                parts = module.split(".")
                if parts[0] == "eskin" and len(parts) > 1 and parts[1] in imports \
                        and parts[1] != name:
                    imports[name].add(parts[1])
    mutual = sorted({tuple(sorted((a, b))) for a in packages for b in imports[a]
                     if a in imports[b]})
    assert not mutual, f"packages that import each other: {mutual}"


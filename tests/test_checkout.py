"""The checkout as editors and code tools see it (docs/contributing.md).

The stage folders rig/, sim/ and scenes/ are linked into the package (jiggle/rig -> ../rig, jiggle/sim -> ../sim,
jiggle/scenes -> ../scenes), so every import of the project's own modules (``jiggle.sim.jiggle.solver``) names a file
on disk: Python finds a module added under a stage folder without a reinstall, and pyright (the type checker behind
VS Code's Python support; ./dev.sh installs it into tests/js/node_modules, pinned in tests/js/package-lock.json, and
pyproject.toml's [tool.pyright] configures it) resolves every import of them.
"""
from __future__ import annotations

import ast
import contextlib
import json
import os
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("rig", "sim", "scenes")
PYRIGHT = ROOT / "tests" / "js" / "node_modules" / "pyright" / "index.js"


def pyright(*files: str) -> dict:
    """Pyright's JSON report (--outputjson) over the files, or over pyproject.toml's [tool.pyright] include when none
    are given, with the running interpreter's packages."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("Node.js not found: ./dev.sh installs it and pyright (JIGGLE_JS=0 leaves them out)")
    if not PYRIGHT.is_file():
        pytest.skip("pyright is not in tests/js/node_modules: ./dev.sh install puts it there (npm ci in tests/js)")
    r = subprocess.run([node, str(PYRIGHT), "--outputjson", "--pythonpath", sys.executable, *files], cwd=ROOT,
                       capture_output=True, text=True, timeout=1200)
    assert r.returncode in (0, 1), f"pyright failed (exit {r.returncode}):\n{r.stderr}\n{r.stdout[-2000:]}"
    return json.loads(r.stdout)        # exit 1: it found errors; the report is on stdout either way


def where(d: dict) -> str:
    return f"{os.path.relpath(d['file'], ROOT)}:{d['range']['start']['line'] + 1}: {d['message'].splitlines()[0]}"


def names_a_project_module(d: dict) -> bool:
    """Whether an attribute diagnostic is about a jiggle module: a name a jiggle module lacks (`jiggle.x.y`), or a
    name `from jiggle.x import y` (or a relative import) cannot find."""
    msg = d["message"]
    if 'of module "jiggle' in msg:
        return True
    if "is unknown import symbol" not in msg:
        return False
    line = d["range"]["start"]["line"] + 1
    tree = ast.parse(Path(d["file"]).read_text(encoding="utf-8"))
    return any(isinstance(n, ast.ImportFrom) and n.lineno <= line <= n.end_lineno
               and (n.level > 0 or (n.module or "").split(".")[0] == "jiggle") for n in ast.walk(tree))


def python_files() -> list[Path]:
    """The project's Python files, each once: jiggle/'s own and the stage folders'."""
    own = [p for p in (ROOT / "jiggle").glob("*.py")]
    return own + [p for top in STAGES for p in (ROOT / top).rglob("*.py") if "__pycache__" not in p.parts]


@contextlib.contextmanager
def new_modules(files: dict[str, str]):
    """Write the files (name -> text) into sim/jiggle/ for the block, then remove them and their bytecode."""
    folder = ROOT / "sim" / "jiggle"
    paths = [folder / name for name in files]
    try:
        for path, text in zip(paths, files.values()):
            path.write_text(text, encoding="utf-8")
        yield paths
    finally:
        for path in paths:
            path.unlink(missing_ok=True)
            for pyc in (folder / "__pycache__").glob(f"{path.stem}.*.pyc"):
                pyc.unlink(missing_ok=True)


def test_the_stage_folders_are_linked_into_the_package():
    for top in STAGES:
        link = ROOT / "jiggle" / top
        assert link.is_symlink() and os.readlink(link) == f"../{top}", \
            f"jiggle/{top} must be the relative link to ../{top} (a clone without symbolic links breaks it: " \
            f"git config core.symlinks true, then check jiggle/{top} out again)"
        assert link.resolve() == (ROOT / top).resolve()


def test_a_module_added_under_sim_imports_without_a_reinstall(tmp_path):
    tag = uuid.uuid4().hex[:8]
    name = f"_checkout_new_{tag}"
    with new_modules({f"{name}.py": '"""A module added while tests/test_checkout.py runs."""\nANSWER = 42\n'}):
        # from outside the checkout: through the installed package (./dev.sh's editable install), not the cwd
        r = subprocess.run([sys.executable, "-c", f"import jiggle.sim.jiggle.{name} as m; print(m.ANSWER)"],
                           cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.split() == ["42"], r.stderr


@pytest.mark.slow
def test_pyright_resolves_every_import_of_the_project():
    """0 unresolved imports and 0 names missing from the project's modules over jiggle/, rig/, sim/ and scenes/ (~80 s
    on 2 cores). Warp's kernel annotations are configured away by rule (pyproject.toml); pyright's other findings
    (NumPy's and Warp's stubs against the code) are not this test's."""
    expected = python_files()
    report = pyright()
    diags = report["generalDiagnostics"]
    assert report["summary"]["filesAnalyzed"] == len(expected), \
        f"pyright analysed {report['summary']['filesAnalyzed']} files, the project has {len(expected)}: " \
        "[tool.pyright] include in pyproject.toml must list jiggle/ and its linked stage folders"
    missing = [where(d) for d in diags if d.get("rule") == "reportMissingImports"]
    assert not missing, f"{len(missing)} unresolved imports:\n" + "\n".join(missing)
    unknown = [where(d) for d in diags if d.get("rule") == "reportAttributeAccessIssue" and names_a_project_module(d)]
    assert not unknown, f"{len(unknown)} names the project's modules lack:\n" + "\n".join(unknown)


def test_pyright_reports_an_import_of_a_module_that_does_not_exist():
    tag = uuid.uuid4().hex[:8]
    new, user = f"_checkout_new_{tag}", f"_checkout_user_{tag}"
    files = {
        f"{new}.py": '"""A module added while tests/test_checkout.py runs."""\nANSWER = 42\n',
        f"{user}.py": (f'"""Imports a module added a moment ago, a module that does not exist and a name that does '
                       f'not."""\nfrom jiggle.sim.jiggle.{new} import ANSWER\n'
                       f"from jiggle.sim.jiggle.no_such_module_{tag} import nothing\n"
                       f"from jiggle.sim.jiggle.simulate import no_such_name_{tag}\n\n"
                       f"print(ANSWER, nothing, no_such_name_{tag})\n"),
    }
    with new_modules(files) as paths:
        report = pyright(str(paths[1].relative_to(ROOT)))
    got = sorted((d.get("rule"), d["message"]) for d in report["generalDiagnostics"] if d["severity"] == "error")
    assert got == [("reportAttributeAccessIssue", f'"no_such_name_{tag}" is unknown import symbol'),
                   ("reportMissingImports", f'Import "jiggle.sim.jiggle.no_such_module_{tag}" could not be resolved')], got

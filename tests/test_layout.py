"""The layout shows the pipeline: imports run one way between the stage packages, and no module
imports itself back through others (no cycle).

The rule, as the test states it: every module belongs to a stage package (the first two parts of its
name, e.g. ``rig.muscle`` for ``rig.muscle.fit``, ``rig.skin`` for ``rig.skin.shell.kernels``). Each
stage has a rank (LAYERS); a module may import a module of its own stage or of a stage of LOWER
rank, never one of the same rank in another stage (peers such as sim.jiggle and sim.drive stay
independent) nor of a higher one. Every import counts: at the top of a file or inside a function.
The library (rig, sim) imports no scene module: scenes are data it loads.

The stage folders install under the public package `jiggle` (jiggle.rig, jiggle.sim, jiggle.scenes: setup.py), so
imports name them `jiggle.rig...`; the public API (jiggle/api.py) sits above every stage, and no stage imports it
(jiggle._version, the version alone, is below them all).
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("rig", "sim")
LAYERS = {
    "jiggle._version": -1,
    "rig.base": 0,
    "rig.motion": 1,
    "rig.character": 2,
    "rig.muscle": 3,
    "rig.anatomy": 4,
    "rig.skin": 5,
    "sim.jiggle": 6,
    "sim.drive": 6,
    "sim.fem": 6,
    "sim.chain": 6.5,
    "sim.bake": 7,
    "sim.app": 8,
    "jiggle.api": 9,
}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def modules() -> dict[str, Path]:
    out = {module_name(p): p for top in PACKAGES for p in sorted((ROOT / top).rglob("*.py"))}
    return out | {f"jiggle.{p.stem}": p for p in (ROOT / "jiggle" / "api.py", ROOT / "jiggle" / "_version.py")}


def unprefixed(module: str) -> str:
    """An imported module's name in the repository's terms: jiggle.rig.x is the folder rig/'s x."""
    parts = module.split(".")
    return ".".join(parts[1:]) if parts[0] == "jiggle" and len(parts) > 1 and parts[1] in (*PACKAGES, "scenes") \
        else module


def imports_of(name: str, path: Path, known: set[str]) -> list[tuple[str, int]]:
    """(imported module, line) for every import of a jiggle module in the file, relative ones resolved;
    `from pkg import mod` counts as importing pkg.mod."""
    is_pkg = path.name == "__init__.py"
    package = name if is_pkg else name.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            mod = unprefixed(mod)
            subs = [f"{mod}.{a.name}" for a in node.names if f"{mod}.{a.name}" in known]
            out += [(s, node.lineno) for s in subs] or [(mod, node.lineno)]
    out = [(unprefixed(m), line) for m, line in out]
    return [(m, line) for m, line in out if m.split(".")[0] in (*PACKAGES, "scenes", "jiggle")]


def stage(module: str) -> str:
    return ".".join(module.split(".")[:2])


def graph() -> dict[str, list[tuple[str, int]]]:
    mods = modules()
    return {name: imports_of(name, path, set(mods)) for name, path in mods.items()}


def test_every_module_is_in_a_stage_package():
    loose = [m for m in modules() if m not in PACKAGES and stage(m) not in LAYERS]
    assert not loose, f"modules outside the stage packages {sorted(LAYERS)}: {loose}"


def test_imports_run_down_the_stages():
    bad = []
    for name, deps in graph().items():
        if name in PACKAGES:
            continue
        here = stage(name)
        for dep, line in deps:
            if dep.split(".")[0] == "scenes":
                bad.append(f"{name} (line {line}) imports the scene module {dep}: scenes are data the library loads")
                continue
            there = stage(dep)
            if there == here or there in PACKAGES and dep == there:
                continue
            if there not in LAYERS:
                bad.append(f"{name} (line {line}) imports {dep}, which is in no stage package")
            elif LAYERS[there] >= LAYERS[here]:
                bad.append(f"{name} (line {line}) imports {dep}: {there} (rank {LAYERS[there]}) is not below "
                           f"{here} (rank {LAYERS[here]})")
    assert not bad, "imports against the pipeline's direction:\n" + "\n".join(bad)


def find_cycle(edges: dict[str, set[str]]) -> list[str] | None:
    """One cycle of the directed graph as [a, b, ..., a], or None."""
    colour: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        colour[n] = 1
        stack.append(n)
        for m in sorted(edges.get(n, ())):
            if colour.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in colour and (found := visit(m)):
                return found
        stack.pop()
        colour[n] = 2
        return None

    for n in sorted(edges):
        if n not in colour and (found := visit(n)):
            return found
    return None


def test_no_import_cycle():
    g = graph()
    edges = {name: {d for d, _ in deps if d in g and d != name} for name, deps in g.items()}
    cycle = find_cycle(edges)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_checks_catch_an_upward_import_and_a_cycle():
    # the checker itself: a made-up graph with a cycle, and a rank pair the rule refuses
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None
    assert LAYERS["rig.skin"] > LAYERS["rig.muscle"] > LAYERS["rig.character"] > LAYERS["rig.motion"]
    assert LAYERS["sim.app"] > LAYERS["sim.bake"] > LAYERS["sim.jiggle"] == LAYERS["sim.drive"] > LAYERS["rig.skin"]


@pytest.mark.parametrize("package", sorted(k for k in LAYERS if not k.startswith("jiggle")))
def test_each_stage_says_what_it_takes_and_gives(package):
    init = ROOT / package.replace(".", "/") / "__init__.py"
    assert init.is_file(), f"{package} has no __init__.py"
    doc = ast.get_docstring(ast.parse(init.read_text(encoding="utf-8")))
    assert doc and len(doc.split()) >= 20, f"{package}/__init__.py needs a docstring saying what the stage takes in and gives out"


def test_every_module_has_a_docstring():
    missing = [name for name, path in modules().items()
               if path.name != "__init__.py" and not ast.get_docstring(ast.parse(path.read_text(encoding="utf-8")))]
    assert not missing, f"modules without a docstring: {missing}"


@pytest.mark.parametrize("path", sorted((ROOT / "benchmarks").glob("bench_*.py")), ids=lambda p: p.stem)
def test_benchmarks_import(path, monkeypatch):
    """Every benchmark's imports resolve in the current layout (its main() is not run: each has a
    __main__ guard), so a module or test helper that moves cannot silently break a benchmark."""
    import importlib.util
    import sys
    # as `python benchmarks/bench_x.py` runs it: its folder first on the path (the benchmark's own
    # sys.path additions are undone afterwards)
    monkeypatch.setattr(sys, "path", [str(path.parent), *sys.path])
    spec = importlib.util.spec_from_file_location(f"_bench_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)     # dataclasses look their module up there
    spec.loader.exec_module(module)
    assert callable(getattr(module, "main", None)), f"{path.name} has no main()"
    # imports inside functions run only with main(): each must at least be findable
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                 else [node.module] if isinstance(node, ast.ImportFrom) and node.module and not node.level else [])
        for name in names:
            assert importlib.util.find_spec(name) is not None, f"{path.name} line {node.lineno}: no module {name}"


MOST_LINES = 100
"""The longest a plain Python function (Warp kernels and funcs aside) may be in jiggle/, rig/, sim/ and scenes/."""
SPINE = {("sim/bake/setup.py", "prepare"), ("rig/muscle/fit.py", "fit_musculature"), ("sim/jiggle/simulate.py", "run"),
         ("sim/bake/baker.py", "bake"), ("sim/bake/baker.py", "Baker.chunk"),
         ("sim/app/report/compare.py", "compare")}
"""The bake's spine: each reads as the list of what it does (docs/contributing.md), at most SPINE_LINES long."""
SPINE_LINES = 60


def function_lengths(source: str) -> dict[str, int]:
    """{qualified name: lines from its `def` to its last line} of every plain function of a module's source (methods as
    Class.name), leaving out Warp kernels and funcs (their bodies are device code, read as one piece)."""
    out = {}

    def visit(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                warp = any(ast.unparse(d).startswith(("wp.kernel", "wp.func")) for d in child.decorator_list)
                if not warp:
                    out[prefix + child.name] = child.end_lineno - child.lineno + 1
                visit(child, prefix + child.name + ".")
            elif isinstance(child, ast.ClassDef):
                visit(child, prefix + child.name + ".")
    visit(ast.parse(source), "")
    return out


def test_functions_read_as_their_steps():
    """No plain function is longer than MOST_LINES, and none of the bake's spine longer than SPINE_LINES (issue 58):
    a long body threads its locals through hundreds of lines, where a new step has nowhere to go."""
    long, spine = [], {}
    for folder in ("jiggle", "rig", "sim", "scenes"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            inside = path.relative_to(ROOT)
            if any((ROOT / p).is_symlink() for p in (inside, *inside.parents)):
                continue                # jiggle/rig etc. are the stage folders again
            rel = inside.as_posix()
            for name, n in function_lengths(path.read_text(encoding="utf-8")).items():
                if n > MOST_LINES:
                    long.append(f"{rel}: {name} ({n} lines)")
                if (rel, name) in SPINE:
                    spine[(rel, name)] = n
    assert not long, f"functions longer than {MOST_LINES} lines: {long}"
    assert set(spine) == SPINE, f"the spine's functions moved: {sorted(SPINE - set(spine))}"
    over = {f"{r}: {n}": k for (r, n), k in spine.items() if k > SPINE_LINES}
    assert not over, f"the bake's spine, longer than {SPINE_LINES} lines: {over}"


def test_function_lengths_count_def_to_end_and_skip_kernels():
    src = ("import warp as wp\n@wp.kernel\ndef k():\n" + "    x = 1\n" * 150 + "class C:\n    def m(self):\n"
           + "        y = 2\n" * 120 + "def f():\n    return 1\n")
    assert function_lengths(src) == {"C.m": 121, "f": 2}

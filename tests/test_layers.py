"""The package's layers, read from its sources: which folder may import which, and the flight loop's model
standing apart from the diagnosis (docs/interfaces.md, "Layers")."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("bridge", "hw", "model", "sitl")
# who may import whom across folders: the model imports nothing of the project, the drivers nothing of the
# running program, and the simulation may start the bridge as a whole, as a user would
MAY_IMPORT = {"bridge": {"hw", "model"}, "hw": {"model"}, "model": set(), "sitl": {"bridge", "hw", "model"}}
DIAGNOSIS = "warpbridge.model.diagnosis"
# the one import inside a function in model/: numba, only when the kernels are compiled (the running bridge
# interprets them and must not pay numba's import)
LAZY_IN_MODEL = {("warpbridge.model._jit", "numba")}


def module_name(f: Path) -> str:
    parts = list(f.relative_to(ROOT).with_suffix("").parts)
    return "warpbridge." + ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(f): f for d in FOLDERS for f in sorted((ROOT / d).rglob("*.py"))}


def imported(node: ast.Import | ast.ImportFrom, module: str, is_package: bool) -> list[str]:
    """The absolute names an import statement may load (a ``from`` import's base and each base.name)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    base = node.module or ""
    if node.level:
        pkg = module.split(".") if is_package else module.split(".")[:-1]
        base = ".".join(pkg[:len(pkg) - node.level + 1] + ([base] if base else []))
    return [base, *(f"{base}.{a.name}" for a in node.names)]


def project_module(name: str) -> str | None:
    """The project module an imported name lies in (a function or class name maps to its module)."""
    while name not in MODULES and "." in name:
        name = name.rsplit(".", 1)[0]
    return name if name in MODULES else None


def inside_functions(tree: ast.AST) -> set[int]:
    """ids of the nodes inside a function's body: run when it is called, not when its module is imported."""
    return {id(s) for fn in ast.walk(tree) if isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef)
            for s in ast.walk(fn) if s is not fn}


def imports(module: str, *, top_level_only: bool = False) -> dict[str, list[int]]:
    """Project modules ``module`` imports, with the lines, every statement or (``top_level_only``) those run
    when it is imported (not inside a function)."""
    f = MODULES[module]
    tree = ast.parse(f.read_text(encoding="utf-8"))
    inner = inside_functions(tree) if top_level_only else set()
    out: dict[str, list[int]] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import | ast.ImportFrom) and id(node) not in inner:
            for name in imported(node, module, f.name == "__init__.py"):
                m = project_module(name) if name.startswith("warpbridge") else None
                if m and m != module:
                    out.setdefault(m, []).append(node.lineno)
    return out


def folder(module: str) -> str:
    return module.split(".")[1]


def test_the_sources_are_found():
    assert {folder(m) for m in MODULES} == set(FOLDERS)
    assert "warpbridge.model.boucwen" in MODULES and DIAGNOSIS in MODULES


@pytest.mark.parametrize("name", FOLDERS)
def test_each_folder_imports_only_the_layers_below_it(name):
    crossing = [f"{m}:{lines[0]} imports {n}" for m in MODULES if folder(m) == name
                for n, lines in imports(m).items() if folder(n) != name and folder(n) not in MAY_IMPORT[name]]
    assert crossing == []


def test_the_flight_loops_model_never_imports_the_diagnosis():
    """The diagnosis imports the model (Bouc-Wen, kernels, effects, identification); nothing outside it in
    model/ imports the diagnosis, so the flight loop never loads it."""
    outside = [m for m in MODULES if m.startswith("warpbridge.model") and not m.startswith(DIAGNOSIS)]
    found = [f"{m}:{lines[0]} imports {n}" for m in outside for n, lines in imports(m).items()
             if n.startswith(DIAGNOSIS)]
    assert found == []
    assert any(n.startswith("warpbridge.model.") and not n.startswith(DIAGNOSIS)
               for m in MODULES if m.startswith(DIAGNOSIS) for n in imports(m))


def circles(graph: dict[str, set[str]]) -> list[str]:
    """Every import circle a depth-first walk of ``graph`` meets, as "a -> b -> a"."""
    found = []
    state: dict[str, int] = {}  # 1 on the path, 2 done

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for n in sorted(graph.get(m, ())):
            # a module loading its own package (``from warpbridge.model import kernels``) runs that package's
            # __init__ first, which is done before the module: not a circle
            if n not in graph or m.startswith(n + "."):
                continue
            if state.get(n) == 1:
                found.append(" -> ".join(path[path.index(n):] + [n]))
            elif n not in state:
                visit(n, path + [n])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
    return found


def test_model_has_no_import_circle():
    assert circles({m: set(imports(m, top_level_only=True)) for m in MODULES if folder(m) == "model"}) == []


def test_model_imports_nothing_inside_a_function_but_the_compiled_modes_numba():
    found = []
    for m, f in MODULES.items():
        if folder(m) != "model":
            continue
        tree = ast.parse(f.read_text(encoding="utf-8"))
        inner = inside_functions(tree)
        for s in ast.walk(tree):
            if isinstance(s, ast.Import | ast.ImportFrom) and id(s) in inner:
                names = [a.name for a in s.names] if isinstance(s, ast.Import) else [s.module or "."]
                found += [f"{m}:{s.lineno} {n}" for n in names if (m, n) not in LAZY_IN_MODEL]
    assert found == []


def test_an_added_crossing_is_caught(tmp_path, monkeypatch):
    """The checks read what they claim to: a model module importing the bridge, and one importing the
    diagnosis inside a function, are both found."""
    bad = tmp_path / "model" / "bad.py"
    bad.parent.mkdir()
    bad.write_text("from warpbridge.bridge import config\n\n\ndef f():\n"
                   "    from warpbridge.model.diagnosis import diagnose\n    return diagnose\n", encoding="utf-8")
    monkeypatch.setitem(MODULES, "warpbridge.model.bad", bad)
    assert set(imports("warpbridge.model.bad")) == {"warpbridge.bridge", "warpbridge.bridge.config", DIAGNOSIS}
    assert set(imports("warpbridge.model.bad", top_level_only=True)) == {"warpbridge.bridge",
                                                                          "warpbridge.bridge.config"}
    assert circles({"p.a": {"p.b"}, "p.b": {"p.c"}, "p.c": {"p.a"}, "p.d": {"p"}, "p": {"p.d"}}) == [
        "p.a -> p.b -> p.c -> p.a"]


FILE_CALLS = {"open", "read_text", "write_text", "read_bytes", "write_bytes", "load", "save", "savez", "loadtxt",
              "savetxt", "genfromtxt", "mkdir", "unlink", "rmtree", "remove", "rename", "replace", "glob"}
FILE_MODULES = {"np", "numpy", "os", "shutil", "pathlib", "Path", "json", "pickle", "io"}


def file_calls(f: Path) -> list[str]:
    """Calls in ``f`` that touch files: ``open(...)``, or a file method or function of a module or object named
    like one that reads or writes (``Path.read_text``, ``np.load``, ``shutil.rmtree``, ``x.write_text``)."""
    found = []
    for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
        if not isinstance(node, ast.Call):
            continue
        fn = node.func
        if isinstance(fn, ast.Name) and fn.id == "open":
            found.append(f"{node.lineno} open")
        elif isinstance(fn, ast.Attribute) and fn.attr in FILE_CALLS:
            owner = fn.value.id if isinstance(fn.value, ast.Name) else None
            # str.replace and dataclasses.replace are not file calls: a path method on an unknown object is
            if fn.attr in {"replace", "load", "save", "remove"} and owner not in FILE_MODULES:
                continue
            found.append(f"{node.lineno} {ast.unparse(fn)}")
    return found


def test_model_touches_no_file_but_the_compile_cache():
    """``model/`` is pure numerics: its only file access is ``model._jit``'s, naming numba's compile cache."""
    found = [f"{m}:{c}" for m, f in MODULES.items() if folder(m) == "model" and m != "warpbridge.model._jit"
             for c in file_calls(f)]
    assert found == []
    assert file_calls(MODULES["warpbridge.model._jit"])  # the check sees what it looks for


def test_a_file_call_is_caught(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("import numpy as np\nfrom dataclasses import replace\n\ndef f(p, q):\n"
                 "    x = replace(q, a=1)\n    y = 'a'.replace('a', 'b')\n    np.save(p, x)\n"
                 "    return p.read_text(), open(p), y\n", encoding="utf-8")
    assert sorted(c.split(" ", 1)[1] for c in file_calls(f)) == ["np.save", "open", "p.read_text"]

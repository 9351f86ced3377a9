"""The layout of the runtime package (bondc/runtime/): one job per module, sizes bounded, every
name importable as ``bondc.runtime.X``, and the modules fit to be carried as one namespace by a
standalone generated module (see the package docstring)."""

import ast
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "bondc" / "runtime"
MAX_MODULE_LINES = 1000
MAX_CLASS_LINES = 600


def _modules():
    from bondc.runtime import MODULES

    return MODULES


def _tree(name):
    return ast.parse((PACKAGE / f"{name}.py").read_text(encoding="utf-8"))


def _defined(tree):
    """The names a module defines at its top level (functions, classes, assigned names)."""
    names = set()
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            for target in (node.targets if isinstance(node, ast.Assign) else [node.target]):
                names |= {n.id for n in ast.walk(target) if isinstance(n, ast.Name)}
    return names


def test_every_module_of_the_package_is_listed_once_in_order():
    modules = _modules()
    assert len(set(modules)) == len(modules)
    files = {p.stem for p in PACKAGE.glob("*.py")} - {"__init__"}
    assert set(modules) == files


@pytest.mark.parametrize("name", ["__init__", *_modules()])
def test_no_module_over_a_thousand_lines_and_no_class_over_six_hundred(name):
    text = (PACKAGE / f"{name}.py").read_text(encoding="utf-8")
    assert text.count("\n") <= MAX_MODULE_LINES, f"{name}.py has {text.count(chr(10))} lines"
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.ClassDef):
            size = node.end_lineno - node.lineno + 1
            assert size <= MAX_CLASS_LINES, f"class {node.name} of {name}.py has {size} lines"


def test_each_module_imports_only_earlier_modules_at_its_top():
    """A standalone module carries the modules in order with these imports commented out: each
    name a module imports from another must already be defined there, and only top-level imports
    can be commented out (an import of bondc.runtime inside a function would fail without bondc)."""
    modules = _modules()
    for i, name in enumerate(modules):
        tree = _tree(name)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("bondc") or \
                    isinstance(node, ast.Import) and any(a.name.startswith("bondc") for a in node.names):
                assert node in tree.body, f"{name}.py imports bondc inside a function (line {node.lineno})"
                assert isinstance(node, ast.ImportFrom) and node.module.startswith("bondc.runtime."), name
                source = node.module.rsplit(".", 1)[1]
                assert source in modules[:i], f"{name}.py imports {source}, which is not before it"
                assert {a.name for a in node.names} <= _defined(_tree(source)), (name, source)


def test_no_two_modules_define_one_name_and_none_rebinds_another_modules_global():
    """One namespace in a standalone module: a name defined twice would be the last module's
    everywhere, and a ``global`` rebinding of another module's name would change only the
    rebinding module's copy in the package."""
    owner = {}
    for name in _modules():
        tree = _tree(name)
        for defined in _defined(tree):
            assert defined not in owner, f"{defined} is defined in {owner.get(defined)}.py and {name}.py"
            owner[defined] = name
        for node in ast.walk(tree):
            if isinstance(node, ast.Global):
                assert set(node.names) <= _defined(tree), f"{name}.py rebinds another module's {node.names}"


def test_every_name_of_every_module_is_importable_from_the_package():
    """Each name is the module's own object (a name its module rebinds with ``global``, a cache
    such as ``_SUNDIALS_FOUND``, is there as imported: read it from its module)."""
    import bondc.runtime as runtime

    for name in _modules():
        module, tree = getattr(runtime, name), _tree(name)
        rebound = {n for node in ast.walk(tree) if isinstance(node, ast.Global) for n in node.names}
        for defined in _defined(tree):
            assert hasattr(runtime, defined), f"bondc.runtime.{defined}"
            if defined not in rebound:
                assert getattr(runtime, defined) is getattr(module, defined), f"bondc.runtime.{defined}"


def test_importing_the_runtime_imports_no_scipy_sympy_or_cffi():
    """``bondc check`` reads data files through the runtime: the package itself needs only numpy."""
    code = ("import sys, bondc.runtime\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('scipy', 'sympy', 'cffi', 'lark')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]"


def test_the_carried_runtime_runs_where_annotations_are_strings_and_no_module_holds_it():
    """A standalone module exec'd by code compiled with ``from __future__ import annotations``
    (the flag is inherited) in a namespace that is no module of sys.modules: the runtime's
    dataclasses still work, and a failure reads as the dict it always was."""
    code = textwrap.dedent("""
        from __future__ import annotations
        from bondc.codegen.emit import runtime_source
        namespace = {"__name__": "no_such_module"}
        exec(compile(runtime_source(), "<runtime>", "exec"), namespace)
        failure = namespace["RunFailure"](message="m", time=1.0, kind="events", when="when h < 0")
        print(failure.replace(time=2.0).as_dict())
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == str({"message": "m", "time": 2.0, "variable": None, "law": None, "cause": None,
                                      "hint": None, "kind": "events", "when": "when h < 0"})

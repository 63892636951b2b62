"""The code stays the shape the next engineer can read: small modules, short functions, the MPC's configuration
in typed groups, and the packages' dependencies going down the data flow (robots -> ... -> control -> scenarios)."""

import ast
import dataclasses
import re
from pathlib import Path

import pytest

import wbmpc
from wbmpc.control import MpcConfig

SRC = Path(wbmpc.__file__).parent
# packages held to the limits (solvers/: its Python and the C of its shims, solvers/csrc/)
LIMITED = ("control", "scenarios", "hardware", "solvers", "operator")
MAX_FILE_LINES, MAX_FUNCTION_LINES = 500, 60


def _modules(package: str):
    return sorted((SRC / package).rglob("*.py"))


@pytest.mark.parametrize("package", LIMITED)
def test_no_file_over_500_lines_and_no_function_over_60(package):
    long_files, long_functions = [], []
    for path in _modules(package):
        text = path.read_text()
        if len(text.splitlines()) > MAX_FILE_LINES:
            long_files.append(f"{path.relative_to(SRC)} ({len(text.splitlines())} lines)")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = node.end_lineno - node.lineno + 1
                if length > MAX_FUNCTION_LINES:
                    long_functions.append(f"{path.relative_to(SRC)}:{node.lineno} {node.name} ({length} lines)")
    assert not long_files and not long_functions, long_files + long_functions


def _c_functions(text: str):
    """(first line, length) of each function body of a C/C++ source: braces opened outside any other block and
    not by a namespace, extern "C", struct, class, union or enum (comments and strings removed first)."""
    text = re.sub(r"/\*.*?\*/", lambda m: "\n" * m.group(0).count("\n"), text, flags=re.S)
    text = re.sub(r'//[^\n]*|"(?:\\.|[^"\\\n])*"', "", text)
    lines, stack = text.split("\n"), []
    for number, line in enumerate(lines):
        for char in line:
            if char == "{":
                head = line[: line.index("{")].strip() or (lines[number - 1].strip() if number else "")
                stack.append((number, head))
            elif char == "}" and stack:
                start, head = stack.pop()
                outer = [h for _, h in stack if not h.startswith(("namespace", "extern", "struct", "class"))]
                if not outer and not head.startswith(("namespace", "extern", "struct", "class", "typedef",
                                                      "union", "enum", "static const", "const")):
                    yield start + 1, number - start + 1


def test_no_c_source_over_500_lines_and_no_c_function_over_60():
    long = []
    for path in sorted((SRC / "solvers" / "csrc").glob("*.[ch]*")):
        text = path.read_text()
        if len(text.splitlines()) > MAX_FILE_LINES:
            long.append(f"{path.name} ({len(text.splitlines())} lines)")
        long += [f"{path.name}:{line} ({length} lines)" for line, length in _c_functions(text)
                 if length > MAX_FUNCTION_LINES]
    assert not long, long


def test_the_c_function_scan_finds_long_functions():
    body = "\n".join(["  x = 1;"] * 70)
    assert [length for _, length in _c_functions(f"int f(void) {{\n{body}\n}}\nint g(void) {{ return 0; }}\n")] \
        == [72, 1]


def _imports(package: str, prefix: str) -> list[str]:
    pattern = re.compile(rf"^\s*(from|import) {re.escape(prefix)}\b")
    return [f"{path.relative_to(SRC)}:{k + 1}" for path in _modules(package)
            for k, line in enumerate(path.read_text().splitlines()) if pattern.match(line)]


def test_dependencies_go_down_the_data_flow():
    """The robot interface does not go through the simulated scenarios; robots and plots do not reach into the
    solvers (the cache directory is wbmpc.cache's)."""
    assert _imports("hardware", "wbmpc.scenarios") == []
    assert _imports("robots", "wbmpc.solvers") == [] and _imports("viz", "wbmpc.solvers") == []
    assert _imports("control", "wbmpc.scenarios") == [] and _imports("control", "wbmpc.sim") == []


def test_mpc_config_top_level_stays_small():
    assert len(dataclasses.fields(MpcConfig)) <= 15


# test folders whose tests use the public API only (issue 33): no `obj._name` outside the test's own classes,
# no monkeypatching of `_name`, no import of private names from wbmpc
PUBLIC_API_TESTS = ("solvers",)


def _private_accesses(path: Path) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__") \
                and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")):
            found.append(f"{path.name}:{node.lineno} .{node.attr}")
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "setattr" \
                and len(node.args) > 1 and isinstance(node.args[1], ast.Constant) \
                and str(node.args[1].value).startswith("_"):
            found.append(f"{path.name}:{node.lineno} setattr {node.args[1].value!r}")
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("wbmpc"):
            found += [f"{path.name}:{node.lineno} import {a.name}" for a in node.names if a.name.startswith("_")]
    return sorted(found, key=lambda hit: int(hit.split(":")[1].split()[0]))


@pytest.mark.parametrize("package", PUBLIC_API_TESTS)
def test_tests_use_the_public_api(package):
    tests = Path(__file__).parent / package
    assert [hit for path in sorted(tests.glob("*.py")) for hit in _private_accesses(path)] == []


def test_the_private_access_scan_finds_them(tmp_path):
    sample = tmp_path / "test_sample.py"
    sample.write_text("from wbmpc.solvers.nlp import _helper\n"
                      "def test(solver, monkeypatch):\n"
                      "    solver._capped.clear()\n"
                      "    monkeypatch.setattr(solver, '_recover', None)\n"
                      "    self._fine = solver.__class__\n")
    assert _private_accesses(sample) == ["test_sample.py:1 import _helper", "test_sample.py:3 ._capped",
                                         "test_sample.py:4 setattr '_recover'"]

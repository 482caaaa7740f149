"""The codebase's shape: modules of one concept, no import cycles, documents about the product.

These hold the layout a newcomer relies on: every library module fits in one reading (at most
`MAX_MODULE_LINES`), the import graph is a DAG (imports inside functions included: they hide a
cycle, they do not remove it), and no tracked text narrates how the software was built.
"""

from __future__ import annotations

import ast
import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("dream", "synth", "train", "export", "plan", "batch")
MAX_MODULE_LINES = 450

# Development narration: ordinal work periods, issue numbers, lent hardware. pytest's fixture
# scope ("session") is product code, not narration.
_ORDINALS = (r"first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh|"
             r"twelfth|thirteenth|fourteenth|fifteenth|sixteenth|seventeenth|eighteenth|"
             r"nineteenth|twentieth|\d+(st|nd|rd|th)")
NARRATION = [
    re.compile(rf"\b({_ORDINALS})[- ]sessions?\b", re.IGNORECASE),
    re.compile(r"\bsessions?\b(?!['\"])(?! ends)(?! scope)", re.IGNORECASE),
    re.compile(r"\bissues? #?\d+\b", re.IGNORECASE),
    re.compile(r"(^|[\s(])#\d{1,3}\b"),
    re.compile(r"\blent (a )?GPU\b", re.IGNORECASE),
]
_NARRATION_ALLOWED = re.compile(r"scope=.session.|pytest_sessionfinish|test session|"
                                r"session fixture", re.IGNORECASE)
_TEXT_SUFFIXES = {".py", ".md", ".yaml", ".yml", ".toml", ".sh", ".txt", ".cfg", ""}


def library_modules() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (REPO / pkg).rglob("*.py"))


def module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _resolve(name: str, known: set[str]) -> str | None:
    """The longest known module that `name` is or lies in."""
    while name:
        if name in known:
            return name
        name = name.rpartition(".")[0]
    return None


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def imported_modules(path: Path, known: set[str]) -> set[str]:
    """Our modules that `path` imports anywhere in its body (type-checking blocks excepted)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = module_name(path) if path.name == "__init__.py" else module_name(path).rpartition(
        ".")[0]
    skip = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If) and _is_type_checking(node)
            for child in node.body for n in ast.walk(child)}
    out: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            # `from pkg import submodule` imports the submodule; any other name is pkg's own
            names = [f"{base}.{alias.name}" for alias in node.names]
            targets = names + ([base] if any(n not in known for n in names) else [])
        else:
            continue
        out.update(m for m in (_resolve(t, known) for t in targets) if m)
    out.discard(module_name(path))
    return out


def import_graph() -> dict[str, set[str]]:
    modules = library_modules()
    known = {module_name(p) for p in modules}
    return {module_name(p): imported_modules(p, known) for p in modules}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def tracked_text_files() -> list[Path]:
    try:
        out = subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True,
                             check=True).stdout.split()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return [REPO / f for f in out if Path(f).suffix in _TEXT_SUFFIXES and (REPO / f).is_file()]


def test_cycle_finder_finds_a_cycle() -> None:
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_modules_fit_one_reading() -> None:
    long = {str(p.relative_to(REPO)): n for p in library_modules()
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES}
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"


def test_no_import_cycles() -> None:
    assert cycles(import_graph()) == []


def test_no_development_narration() -> None:
    hits = []
    for path in tracked_text_files():
        if path.resolve() == Path(__file__).resolve():
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8",
                                                     errors="replace").splitlines(), 1):
            if _NARRATION_ALLOWED.search(line):
                continue
            if any(p.search(line) for p in NARRATION):
                hits.append(f"{path.relative_to(REPO)}:{number}: {line.strip()[:90]}")
    assert not hits, f"{len(hits)} lines narrate the development:\n" + "\n".join(hits[:40])


def test_readme_is_a_user_document() -> None:
    assert len((REPO / "README.md").read_text(encoding="utf-8").splitlines()) <= 320

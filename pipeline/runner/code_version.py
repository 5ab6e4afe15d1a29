"""A stage's code version: a hash of the code of every ``pipeline`` module it can run.

A stage's artifacts are stale when its code changed, not only its inputs or config. The
modules a stage runs are found statically, from its step module
(``pipeline/runner/steps/<stage>.py``) through every ``import pipeline...`` /
``from pipeline... import`` it contains, including the imports inside functions (the
heavy backends are imported lazily), transitively. Each module contributes its syntax
tree without docstrings, so a comment, a docstring or a reformatting does not make a
stage stale, and any change to what the code does does.

An upstream stage's change reaches a downstream stage through the artifacts it writes
(their hashes are the downstream stage's inputs), so each stage hashes only its own code.
"""

from __future__ import annotations

import ast
import hashlib
from functools import cache
from pathlib import Path

PACKAGE = "pipeline"
_ROOT = Path(__file__).resolve().parents[1]  # the ``pipeline`` package folder


@cache
def _source_path(module: str) -> Path | None:
    """File of a ``pipeline`` module or package (its ``__init__.py``), found on disk without
    importing anything (importing would run heavy backends); None if there is none."""
    parts = module.split(".")
    if parts[0] != PACKAGE:
        return None
    base = _ROOT.joinpath(*parts[1:])
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def _imports(tree: ast.Module, module: str, is_package: bool) -> set[str]:
    """``pipeline`` modules imported anywhere in ``tree`` (relative imports resolved)."""
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.split(".")[0] == PACKAGE)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = module.split(".")
                parts = parts if is_package else parts[:-1]
                parts = parts[: len(parts) - (node.level - 1)]
                base = ".".join(parts + ([base] if base else []))
            if base.split(".")[0] != PACKAGE:
                continue
            out.add(base)
            # ``from pipeline.x import y`` may name a submodule y.
            out.update(f"{base}.{a.name}" for a in node.names if _source_path(f"{base}.{a.name}") is not None)
    return out


def _strip_docstrings(tree: ast.Module) -> ast.Module:
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            first = body[0] if body else None
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
                node.body = body[1:] or [ast.Pass()]
    return tree


@cache
def _module_digest(module: str) -> tuple[str, frozenset[str]]:
    """(sha256 of the module's docstring-free syntax tree, the pipeline modules it imports)."""
    path = _source_path(module)
    if path is None:
        return "", frozenset()
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    deps = _imports(tree, module, path.name == "__init__.py")
    # A submodule's package __init__ runs first: it belongs to the closure too.
    parts = module.split(".")
    deps.update(".".join(parts[:i]) for i in range(1, len(parts)))
    digest = hashlib.sha256(ast.dump(_strip_docstrings(tree)).encode()).hexdigest()
    return digest, frozenset(d for d in deps if d != module)


def module_closure(root: str) -> tuple[str, ...]:
    """Every ``pipeline`` module reachable from ``root`` by imports, sorted (``root`` included)."""
    seen: set[str] = set()
    todo = [root]
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        todo.extend(_module_digest(m)[1] - seen)
    return tuple(sorted(m for m in seen if _source_path(m) is not None))


@cache
def stage_code_hash(stage: str) -> str:
    """Hex digest (16 characters) of the code of every module stage ``stage`` can run."""
    h = hashlib.sha256()
    for m in module_closure(f"{PACKAGE}.runner.steps.{stage}"):
        h.update(f"{m}:{_module_digest(m)[0]}\n".encode())
    return h.hexdigest()[:16]

"""numba's on-disk cache is keyed by every source the compiled kernels read
(:mod:`softsensor.jit_cache`): a module they inline or whose constants they freeze, left out
of the key, would let an edit reuse kernels compiled from the old source."""

from __future__ import annotations

import ast
import shutil
from pathlib import Path

from softsensor import jit_cache

PACKAGE = Path(jit_cache.__file__).resolve().parent
#: Imported by compiled modules but never read inside a kernel: exception classes, raised by
#: the Python wrappers around the kernels (``mol.simulate_mol``), not by compiled code.
NOT_COMPILED = {"softsensor.errors"}


def _is_compiled(node: ast.AST) -> bool:
    """A function decorated ``@njit(...)``, ``@numba.njit``, ``@register_jitable`` or
    ``@jit``."""
    if not isinstance(node, ast.FunctionDef):
        return False
    for d in node.decorator_list:
        target = d.func if isinstance(d, ast.Call) else d
        name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
        if name in ("njit", "jit", "register_jitable"):
            return True
    return False


def _softsensor_imports(tree: ast.Module) -> set[str]:
    """The softsensor modules a module imports (``from softsensor.x import y`` may name a
    module ``softsensor.x.y`` or a name in ``softsensor.x``: both are returned)."""
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("softsensor"):
            found.add(node.module)
            found.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name.startswith("softsensor"))
    return found


def _module_path(name: str) -> Path | None:
    rel = Path(*name.split(".")[1:])
    for p in (PACKAGE / rel.with_suffix(".py"), PACKAGE / rel / "__init__.py"):
        if p.is_file():
            return p
    return None


def test_every_module_a_kernel_module_imports_is_in_the_cache_key():
    hashed = {p.resolve() for p in jit_cache.compiled_sources()}
    compiled = []
    for p in sorted(hashed):
        tree = ast.parse(p.read_text())
        if not any(_is_compiled(n) for n in ast.walk(tree)):
            continue
        compiled.append(p.name)
        for name in _softsensor_imports(tree) - NOT_COMPILED:
            path = _module_path(name)
            if path is None or path.name == "__init__.py":
                continue  # a name inside a module, or a package: its modules are checked
            assert path.resolve() in hashed, (
                f"{p.relative_to(PACKAGE)} imports {name}, which the numba cache key leaves "
                "out: add it to jit_cache.COMPILED_MODULES")
    # the kernels' own modules are among those checked (the walk found the compiled code)
    assert {"kernels.py", "cell_physics.py", "cell_solver.py", "march.py"} <= set(compiled)


def test_an_edit_of_any_hashed_source_changes_the_cache_folder(tmp_path):
    root = tmp_path / "softsensor"
    for p in jit_cache.compiled_sources():
        dest = root / p.relative_to(PACKAGE)
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(p, dest)
    before = jit_cache.sources_digest(root)
    assert before == jit_cache.sources_digest(PACKAGE)
    for rel in ("model/cell_physics.py", "signals.py", "plantconfig.py"):
        path = root / rel
        text = path.read_text()
        path.write_text(text + "\n# edited\n")
        assert jit_cache.sources_digest(root) != before, rel
        path.write_text(text)
    assert jit_cache.sources_digest(root) == before

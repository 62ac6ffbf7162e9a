"""Scripts outside the package (``benchmarks/*.py``, ``docs/_ext/*.py``), imported by the tests
as modules."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType


def load_script(path: Path) -> ModuleType:
    """``path`` as a module named after its stem, loaded once (its folder put on the path
    first: a benchmark imports its siblings, such as ``peers``)."""
    name = path.stem
    if name in sys.modules:
        loaded = sys.modules[name]
        # a sibling imported by name is the same file; another file of the same stem is not
        if Path(getattr(loaded, "__file__", "") or "").resolve() != path.resolve():
            raise ImportError(f"{path}: a module {name!r} from another file is loaded "
                              f"({getattr(loaded, '__file__', None)})")
        return loaded
    if str(path.parent) not in sys.path:
        sys.path.insert(0, str(path.parent))
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


__all__ = ["load_script"]

"""One helper the tests share: a script that is not part of the package (benchmarks/*.py,
docs/hooks/*.py) loaded as a module, to call its functions."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType


def load_script(path: Path) -> ModuleType:
    """The Python file at `path`, executed as a fresh module named ``_script_<stem>`` (not put in
    `sys.modules`: each call loads it anew)."""
    spec = importlib.util.spec_from_file_location(f"_script_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module

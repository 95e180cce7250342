"""Load a file of scripts/ as a module (the scripts are not a package; tests call their functions)."""

from __future__ import annotations

import importlib.util
import sys
from types import ModuleType

from polarref.core.data import REPO_ROOT


def load_script(name: str) -> ModuleType:
    """``scripts/<name>.py`` as module ``name`` (registered in sys.modules: dataclasses look
    their module up there)."""
    spec = importlib.util.spec_from_file_location(name, REPO_ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module

"""Loading a module of weak forms by path, so that editing a form needs no reinstall."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

from fempm.errors import InputError

__all__ = ["FORMS_DIR", "load_forms"]

FORMS_DIR = Path(__file__).resolve().parents[1] / "forms"


def load_forms(path: str | Path, required: tuple[str, ...] = ()) -> ModuleType:
    """Import the Python file ``path`` (or ``forms/<path>.py`` for a bare name) as a module.

    Raises:
        InputError: the file does not exist or lacks one of the ``required`` functions.
    """
    path = Path(path)
    if not path.suffix and not path.exists():
        path = FORMS_DIR / f"{path}.py"
    if not path.is_file():
        raise InputError(f"forms file {str(path)!r} does not exist")
    spec = importlib.util.spec_from_file_location(f"fempm_forms_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    missing = [name for name in required if not callable(getattr(module, name, None))]
    if missing:
        raise InputError(f"forms file {str(path)!r} does not define {', '.join(missing)}")
    return module

"""A script of ``scripts/`` imported as a module, so a test can run its ``main(argv)`` in the test
process: the same code as the command line (argument parsing, the package call, the files it
writes, the exit status of a refused argument as ``SystemExit``) without starting another Python
process, and with the process's compiled programs shared."""

import importlib.util
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def load_script(name: str) -> types.ModuleType:
    """``scripts/<name>`` (e.g. ``"lfd_franka.py"``) imported as module ``script_<stem>``."""
    spec = importlib.util.spec_from_file_location(f"script_{Path(name).stem}",
                                                  ROOT / "scripts" / name)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module

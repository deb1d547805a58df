"""The one place that imports user code by name: ``MODULE:Class`` node targets, other ``MODULE:name`` objects a node
is told to use, and the message modules.

Message modules are found through the ``palpa.messages`` entry-point group (a package declares its message module
in its ``pyproject.toml``; this project declares ``messages``) plus ``PALPA_MESSAGES`` for modules that are not
installed, so the runtime names no domain package. A launch file, ``palpa run``, the in-process composition and the
tools all load a node class through :func:`load_node_class`, so every one of them says the same thing about a
target that does not load.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
from importlib.metadata import entry_points
from types import ModuleType

from palpa import env as palpa_env
from palpa.errors import PalpaError
from palpa.node.node import Node
from yamlstruct.convert import did_you_mean

__all__ = ["MESSAGES_GROUP", "TargetError", "import_message_modules", "load_node_class", "load_object",
           "message_modules"]

MESSAGES_GROUP = "palpa.messages"
"""The entry-point group a package uses to declare its message module(s): ``name = "package.module"``."""


class TargetError(PalpaError):
    """A ``MODULE:Class`` target that does not name a loadable node class: ``reason`` says which part failed
    (a launch file puts it after the line and column of the target; the CLI after the target itself)."""

    def __init__(self, target: str, reason: str) -> None:
        super().__init__(reason if reason.startswith(repr(target)) else f"{target!r}: {reason}")
        self.target = target
        self.reason = reason


def message_modules() -> list[str]:
    """The message modules to import: the installed ``palpa.messages`` entry points, then ``PALPA_MESSAGES``."""
    declared = _declared_message_modules()
    return [*declared, *(m for m in palpa_env.listed(palpa_env.MESSAGES) if m not in declared)]


@functools.cache
def _declared_message_modules() -> tuple[str, ...]:
    # read once a process: scanning the installed distributions' entry points takes ~5 ms, and a recorder asks
    # at every new topic
    return tuple(sorted({ep.value for ep in entry_points(group=MESSAGES_GROUP)}))


_imported: set[str] = set()


def import_message_modules() -> None:
    """Import every message module (once each) so its types are in the registry. One that does not import is
    skipped: its topics then show without a schema, as they would on a machine without that package."""
    for name in message_modules():
        if name not in _imported:
            _imported.add(name)
            with contextlib.suppress(ImportError):
                importlib.import_module(name)


def _import_target(target: str, expected: str) -> tuple[ModuleType, str, str]:
    """The module ``target`` (``package.module:name``) names, with its two parts; a :class:`TargetError` if the
    target is malformed or the module does not import (its own error, or not found where it was looked for)."""
    module_name, sep, name = target.partition(":")
    if not sep or not module_name or not name:
        raise TargetError(target, f"expected {expected}")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name is not None and module_name.startswith(exc.name):
            raise TargetError(target, f"cannot import module {module_name!r}: is it installed, in the working "
                                      "directory, on PYTHONPATH, or in the launch file's python_path?") from None
        raise TargetError(target, f"importing {module_name!r} failed: {exc}") from None
    except Exception as exc:  # any error raised by the module's own code at import time
        raise TargetError(target, f"importing {module_name!r} failed: {type(exc).__name__}: {exc}") from None
    return module, module_name, name


def load_object(target: str) -> object:
    """Import ``package.module:name`` and return that attribute (an object a node is told to use by name, such as
    a driver's stand-in); a :class:`TargetError` says what failed, with the closest names."""
    module, module_name, name = _import_target(target, "package.module:name")
    if not hasattr(module, name):
        names = [n for n in vars(module) if not n.startswith("_")]
        raise TargetError(target, f"module {module_name!r} has no {name!r}{did_you_mean(name, names)}")
    return getattr(module, name)


def load_node_class(target: str) -> type[Node]:
    """Import ``package.module:Class`` and check it is a Node subclass; a :class:`TargetError` says what failed
    (the module's own import error, a class that is not there with the closest names, or not a node)."""
    module, module_name, class_name = _import_target(target, "package.module:Class")
    cls = getattr(module, class_name, None)
    if cls is None:
        names = [n for n, v in vars(module).items() if isinstance(v, type) and issubclass(v, Node) and v is not Node]
        raise TargetError(target, f"module {module_name!r} has no {class_name!r}{did_you_mean(class_name, names)}")
    if not (isinstance(cls, type) and issubclass(cls, Node)):
        raise TargetError(target, f"{target!r} is not a palpa.Node subclass")
    return cls

"""Public names of a package loaded on first use (PEP 562), from one declared map.

A package that keeps ``import package`` cheap declares its public names as a literal dict
``{name: "module:attribute"}`` and passes it to :func:`lazy_exports`::

    _LAZY = {"measure": "dropvision.api:measure"}
    __getattr__, __dir__ = lazy_exports(__name__, globals(), _LAZY)

tests/project/test_layers.py reads such maps (the literal dict given to ``lazy_exports``) and counts each
target module as an import of the declaring package, so laziness hides no edge from the layer test.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable  # already loaded at start-up (typing is not: ~1.5 ms)

__all__ = ["lazy_exports"]


def lazy_exports(module_name: str, module_globals: dict, exports: dict[str, str]
                 ) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """Module-level ``__getattr__`` and ``__dir__`` loading ``exports`` on first access.

    Parameters
    ----------
    module_name : str
        ``__name__`` of the declaring module (for the AttributeError message).
    module_globals : dict
        ``globals()`` of the declaring module (listed by ``__dir__``). Names are looked up
        in their module at every access (nothing cached), so a patched module is seen.
    exports : dict of str to str
        Public name -> ``"package.module:attribute"``.

    Returns
    -------
    (__getattr__, __dir__)
        To be assigned to the module's ``__getattr__`` and ``__dir__``.

    Raises
    ------
    ValueError
        A target not of the form ``"module:attribute"``.
    """
    for name, target in exports.items():
        mod, sep, attr = target.partition(":")
        if not (sep and mod and attr):
            raise ValueError(f"{module_name}: lazy export {name!r} -> {target!r} must be 'module:attribute'")

    def __getattr__(name: str):
        target = exports.get(name)
        if target is None:
            raise AttributeError(f"module {module_name!r} has no attribute {name!r}")
        mod, _, attr = target.partition(":")
        return getattr(importlib.import_module(mod), attr)

    def __dir__() -> list[str]:
        return sorted(set(module_globals) | set(exports))

    return __getattr__, __dir__

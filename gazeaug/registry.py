"""Registries of named factories: gaze models, renderers and dataset readers, one style for all three.

Each is a module-level :class:`Registry` with a ``register_*`` function (also a
decorator) and a function that builds by name:

- ``gazeaug.models.MODELS``: ``register_model(name)``, ``create_model(name, **options)``;
  the command line's ``--model``.
- ``gazeaug.render.RENDERERS``: ``register_renderer(name, benchmark_only=False)``,
  ``create_renderer(name, **options)``; ``--renderer``.
- ``gazeaug.datasets.DATASETS``: ``register_dataset(name, detect=...)``,
  ``open_dataset(path, format=None)``, ``detect_format(path)``; ``--format``.

A name maps to its factory or to the string ``"package.module:attribute"``,
imported the first time the factory is asked for. So listing the names (the
command line's choices, ``name in REGISTRY``, ``sorted(REGISTRY)``) imports
neither PyTorch, Open3D nor MediaPipe. Names keep their registration order
(``list(REGISTRY)``), which is the order dataset formats are detected in.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from facemesh.types import FaceMeshError

from .errors import GazeAugError

__all__ = ["Registry", "Entry", "resolve"]

#: A factory, or ``"package.module:attribute"`` naming one (imported on first use).
Target = Callable[..., Any] | str


def resolve(target: Target) -> Callable[..., Any]:
    """The object ``target`` names: ``"package.module:attribute"`` is imported now; a callable is itself.

    Raises:
        ValueError: a string that is not ``"package.module:attribute"``.
        ImportError, AttributeError: the module or the attribute does not exist.
    """
    if not isinstance(target, str):
        return target
    module, sep, attr = target.partition(":")
    if not (sep and module and attr):
        raise ValueError(f"expected 'package.module:attribute', got {target!r}")
    obj: Any = importlib.import_module(module)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj  # type: ignore[no-any-return]


@dataclass(frozen=True)
class Entry:
    """One registered name: its factory (or the string naming it) and what was registered with it.

    Attributes:
        name: the registered name.
        target: the factory, or ``"package.module:attribute"`` until first used.
        options: what the registry's ``register_*`` records beside it (a dataset's ``detect``, a
            renderer's ``benchmark_only``).
    """

    name: str
    target: Target
    options: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))


class Registry(Mapping[str, Callable[..., Any]]):
    """Names -> factories, in registration order; a factory is imported when first asked for.

    ``registry[name]`` is the factory (imported now; KeyError for an unknown name);
    ``name in registry``, ``list(registry)``, ``sorted(registry)``, :meth:`names` and
    :meth:`options` never import anything. :meth:`factory` and :meth:`create` raise the
    registry's typed error for an unknown name, listing the known ones.

    Args:
        kind: what a name names, as the error message says it (``"model"``, ``"renderer"``, ``"format"``).
        error: the typed error for an unknown name.
    """

    def __init__(self, kind: str, error: type[FaceMeshError] = GazeAugError) -> None:
        self.kind = kind
        self.error = error
        self._entries: dict[str, Entry] = {}

    def register(self, name: str, target: Target | None = None, **options: Any) -> Any:
        """Register ``target`` under ``name`` (returned as is); without ``target``, a decorator that does.

        A name registered again is replaced in place: it keeps its position in the order and the
        options it was registered with before, unless given again.
        """

        def add(obj: Any) -> Any:
            old = self._entries.get(name)
            merged = {**(old.options if old is not None else {}), **options}
            self._entries[name] = Entry(name, obj, MappingProxyType(merged))
            return obj

        return add if target is None else add(target)

    def __getitem__(self, name: str) -> Callable[..., Any]:
        entry = self._entries[name]
        obj = resolve(entry.target)
        if self._entries.get(name) is entry:  # importing it may have registered it again: keep that
            self._entries[name] = Entry(name, obj, entry.options)
        return obj

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(list(self._entries))

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}, {list(self._entries)})"

    def names(self, **options: Any) -> list[str]:
        """The sorted names, or those registered with these option values (``names(benchmark_only=False)``)."""
        return sorted(n for n, e in self._entries.items() if all(e.options.get(k) == v for k, v in options.items()))

    def options(self, name: str) -> Mapping[str, Any]:
        """What was registered with ``name`` besides its factory (KeyError for an unknown name)."""
        return self._entries[name].options

    def factory(self, name: str) -> Callable[..., Any]:
        """The factory of ``name``.

        Raises:
            FaceMeshError: (the registry's ``error``) an unknown name; the message lists the known ones.
        """
        if name not in self._entries:
            raise self.error(f"{self.kind}: expected one of {sorted(self._entries)}, got {name!r}")
        return self[name]

    def create(self, name: str, *args: Any, **kwargs: Any) -> Any:
        """``factory(name)(*args, **kwargs)``."""
        return self.factory(name)(*args, **kwargs)

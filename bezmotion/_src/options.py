"""Command lines generated from frozen option dataclasses: each option is declared once.

An experiment, a benchmark or a command declares its options as one class whose fields
are the flags, and parses them into an instance of it::

    @options
    class TrainOptions:
        out: str = option(help="output JSON")                  # no default: required
        steps: int = option(6000, help="training steps")       # --steps N
        seeds: tuple[int, ...] = option((0,), help="seeds")    # --seeds 0 1 2
        config: str = option("cpu", choices=presets(BMMConfig), help="model size")
        mode: Literal["fast", "exact"] = "exact"               # --mode {fast,exact}
        no_progress: bool = False                              # a switch: --no-progress
        overwrite: bool = True                                 # --overwrite / --no-overwrite

    args = parse_options(TrainOptions, argv, description=__doc__)

Field → flag: the name in kebab case (``batch_size`` → ``--batch-size``); the type from
the annotation — ``int``, ``float``, ``str``, ``Path``, ``Literal[...]`` (its values are
the choices), ``tuple[T, ...]`` (one or more values), ``tuple[T, T, T]`` (exactly three),
``X | None`` (for a default of ``None``), ``bool`` (``--x`` / ``--no-x``; a field named
``no_…`` is the plain switch ``--no-…`` and defaults to ``False``); the default from the
field (no default: the flag is required); the help text, explicit choices and metavar
from :func:`option`. ``option(positional=True)`` makes a field a positional argument
(optional when it has a default), and ``option(repeat=True)`` lets a ``tuple[T, ...]``
flag be given several times, collecting every value (``--handle A --handle B C``). The class's ``__post_init__`` may check values and fill derived
defaults (``object.__setattr__``, as frozen dataclasses do); a ``ValueError`` it raises
is reported by argparse like a malformed value: usage, the message, exit status 2.

A model config's size presets are its classmethods ``cpu``, ``paper`` and ``tiny``
(each ``(*args, **overrides) -> config``); :func:`presets` collects them by name, so an
option chooses one with ``choices=presets(Config)`` and the script builds it with
``presets(Config)[args.config](**overrides)``.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import types
import typing
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, ClassVar, Literal, TypeVar

T = TypeVar("T")

PRESET_NAMES = ("cpu", "paper", "tiny")
"""The size presets a model config may define as classmethods, in the order they are listed."""

# The only names an option's annotation may use: the supported types (and ClassVar for
# class constants). Annotations are evaluated here rather than by `typing.get_type_hints`,
# which needs the class's module in `sys.modules`; a script a test loads by path is not.
_ANNOTATION_NAMES: dict[str, Any] = {
    "__builtins__": {},
    "int": int,
    "float": float,
    "str": str,
    "bool": bool,
    "Path": Path,
    "Literal": Literal,
    "tuple": tuple,
    "None": None,
    "ClassVar": ClassVar,
}
_SCALARS = (int, float, str, Path)
_SUPPORTED = "int, float, str, bool, Path, Literal[...], tuple[T, ...], tuple[T, T, …] or X | None"


def option(
    default: Any = dataclasses.MISSING,
    *,
    help: str | None = None,
    choices: Iterable[Any] | None = None,
    metavar: str | tuple[str, ...] | None = None,
    positional: bool = False,
    repeat: bool = False,
) -> Any:
    """A field of an options class with its help text (no ``default``: the flag is required).

    Args:
      default: the value when the flag is absent; immutable (a tuple, not a list).
      help: the flag's line in ``--help``.
      choices: the allowed values, where the annotation is a plain type (a ``Literal``
        annotation lists its own); a mapping's keys (e.g. :func:`presets`) work too.
      metavar: the value's name in ``--help`` (a tuple names each of a fixed count).
      positional: a positional argument rather than a flag (a single value; optional when
        the field has a default).
      repeat: for a ``tuple[T, ...]`` field: the flag may be given several times, each
        with one or more values, and the values of every occurrence are collected in order.
    """
    if isinstance(default, list | dict | set):
        raise ValueError(f"an option's default must be immutable (a tuple for several values), got {default!r}")
    metadata = {
        "help": help, "choices": None if choices is None else tuple(choices), "metavar": metavar,
        "positional": positional, "repeat": repeat,
    }  # fmt: skip
    return dataclasses.field(default=default, metadata=metadata)


def options(cls: type[T]) -> type[T]:
    """Class decorator: a frozen, keyword-only dataclass of command-line options.

    Raises:
      TypeError: a field's annotation is not one of the supported types.
    """
    annotations = cls.__dict__.get("__annotations__", {})
    for name, annotation in annotations.items():
        if isinstance(annotation, str):
            try:
                annotations[name] = eval(annotation, dict(_ANNOTATION_NAMES))  # noqa: S307 (closed namespace)
            except Exception:
                raise TypeError(f"option {cls.__name__}.{name}: unsupported type {annotation!r}; use {_SUPPORTED}") from None
    cls = dataclasses.dataclass(frozen=True, kw_only=True)(cls)
    for field in dataclasses.fields(cls):
        _argument(cls, field)  # fail at the declaration, not at the first parse
    return cls


def presets(config_cls: type, /, *args: Any, **fixed: Any) -> dict[str, Callable[..., Any]]:
    """``{name: config_cls.<name>}`` for the size presets the config defines (:data:`PRESET_NAMES`).

    Args:
      config_cls: a model config class with classmethods among ``cpu``, ``paper``, ``tiny``.
      *args, **fixed: bound into every preset (e.g. a corpus's fixed settings); the
        caller's overrides still win over ``fixed``.

    Raises:
      ValueError: the class defines none of the presets.
    """
    found = {name: getattr(config_cls, name) for name in PRESET_NAMES if callable(getattr(config_cls, name, None))}
    if not found:
        raise ValueError(f"{config_cls.__name__} defines no size preset (classmethods {', '.join(PRESET_NAMES)})")
    if args or fixed:
        return {name: functools.partial(make, *args, **fixed) for name, make in found.items()}
    return found


def add_options(parser: argparse.ArgumentParser, cls: type) -> argparse.ArgumentParser:
    """Add a flag for every field of the options class ``cls`` to ``parser`` (e.g. a subcommand's)."""
    for field in dataclasses.fields(cls):
        if field.init:
            flag, kwargs = _argument(cls, field)
            parser.add_argument(flag, **kwargs)
    return parser


def options_parser(cls: type, *, description: str | None = None, prog: str | None = None) -> argparse.ArgumentParser:
    """The argument parser of the options class ``cls``.

    Args:
      description: the text above the flags; its first paragraph is used (e.g. a
        script's ``__doc__``). Default: the class's docstring.
    """
    text = description if description is not None else _own_docstring(cls)
    first = text.strip().split("\n\n")[0] if text else None
    return add_options(argparse.ArgumentParser(prog=prog, description=first), cls)


def options_from(parser: argparse.ArgumentParser, cls: type[T], namespace: argparse.Namespace) -> T:
    """The ``cls`` instance of parsed flags; its checks' ``ValueError`` exits through ``parser.error``."""
    values = {}
    for field in dataclasses.fields(cls):
        if field.init:
            value = getattr(namespace, field.name)
            if value is None and field.metadata.get("repeat"):  # never given: argparse left it unset
                value = field.default
            values[field.name] = tuple(value) if isinstance(value, list) else value
    try:
        return cls(**values)
    except ValueError as error:
        parser.error(str(error))


def parse_options(cls: type[T], argv: Sequence[str] | None = None, *, description: str | None = None) -> T:
    """Parse ``argv`` (default ``sys.argv[1:]``) into an instance of the options class ``cls``.

    Bad values, unknown flags and failed checks exit with status 2 and argparse's message.
    """
    parser = options_parser(cls, description=description)
    return options_from(parser, cls, parser.parse_args(argv))


def _own_docstring(cls: type) -> str | None:
    doc = cls.__doc__
    # dataclasses writes the signature into a class without a docstring: not a description.
    return None if doc is None or doc.startswith(cls.__name__ + "(") else doc


def _argument(cls: type, field: dataclasses.Field) -> tuple[str, dict[str, Any]]:
    """``(flag, add_argument keywords)`` of one field."""
    where = f"option {cls.__name__}.{field.name}"
    meta = field.metadata
    kwargs: dict[str, Any] = {"dest": field.name, "help": meta.get("help")}
    if field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
        kwargs["required"] = True
    else:
        kwargs["default"] = field.default if field.default is not dataclasses.MISSING else field.default_factory()
    kind = field.type
    members = typing.get_args(kind)
    if isinstance(kind, types.UnionType) or typing.get_origin(kind) is typing.Union:
        rest = [m for m in members if m is not type(None)]
        if len(rest) != 1 or len(members) != 2:
            raise TypeError(f"{where}: unsupported type {kind!r}; use {_SUPPORTED}")
        kind = rest[0]
    if kind is bool:
        if field.name.startswith("no_"):
            if kwargs.get("default") is not False:
                raise TypeError(f"{where}: a no_… switch defaults to False, got {kwargs.get('default')!r}")
            kwargs["action"] = "store_true"
        else:
            kwargs["action"] = argparse.BooleanOptionalAction
    elif typing.get_origin(kind) is tuple:
        items = typing.get_args(kind)
        if len(items) == 2 and items[1] is Ellipsis:
            kwargs["nargs"] = "+"
        elif items and all(item == items[0] for item in items):
            kwargs["nargs"] = len(items)
        else:
            raise TypeError(f"{where}: a tuple option holds one or more values of one type, got {kind!r}")
        kwargs.update(_scalar(where, items[0]))
    else:
        kwargs.update(_scalar(where, kind))
    if meta.get("choices") is not None:
        kwargs["choices"] = meta["choices"]
    if meta.get("metavar") is not None:
        kwargs["metavar"] = meta["metavar"]
    if meta.get("repeat"):
        if kwargs.get("nargs") != "+":
            raise TypeError(f"{where}: repeat=True needs a tuple[T, ...] field, got {field.type!r}")
        # argparse extends a copy of the default, which a tuple does not allow: options_from fills it in.
        kwargs.update(action="extend", default=None)
    if meta.get("positional"):
        if "action" in kwargs or "nargs" in kwargs:
            raise TypeError(f"{where}: a positional option holds one value, got {field.type!r}")
        del kwargs["dest"]  # a positional argument's name is its dest
        if not kwargs.pop("required", False):
            kwargs["nargs"] = "?"
        return field.name, kwargs
    return "--" + field.name.replace("_", "-"), kwargs


def _scalar(where: str, kind: Any) -> dict[str, Any]:
    """``type`` (and ``choices``) of one value."""
    if typing.get_origin(kind) is Literal:
        values = typing.get_args(kind)
        kinds = {type(v) for v in values}
        if len(kinds) != 1 or not kinds <= set(_SCALARS):
            raise TypeError(f"{where}: Literal values must share one type of {_SCALARS}, got {values!r}")
        return {"type": kinds.pop(), "choices": values}
    if kind in _SCALARS:
        return {"type": kind}
    raise TypeError(f"{where}: unsupported type {kind!r}; use {_SUPPORTED}")

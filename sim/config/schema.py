"""The generic TOML schema: frozen dataclasses that check themselves, and the parser
that builds them from a file's tables.

A field's type (``float``, ``int``, ``bool``, ``str``, ``Literal``, fixed and open
tuples, ``X | None``, a nested dataclass) and its predicate (:func:`checked`) are
enforced whenever an instance is made: parsed, built in code or
``dataclasses.replace``d. The parser adds unknown and missing keys, and names each
key in full (``camera.width``, ``obstacles[2].size``) with the file it came from.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import tomllib
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import field
from pathlib import Path
from typing import Any, Literal, TypeVar

T = TypeVar("T")


def one_line(text: str) -> str:
    """``text`` with anything unprintable (newlines included) escaped."""
    return text if text.isprintable() else text.encode("unicode_escape").decode("ascii")


MISSING = object()  # the value of a key a file leaves out


class ScenarioError(ValueError):
    """An invalid scenario: one line naming file, key, value and what is accepted."""

    def __init__(self, source: str, key: str, value: object, accepted: str,
                 problem: str = "bad value") -> None:
        self.source, self.key, self.value, self.accepted = source, key, value, accepted
        self.problem = problem
        found = problem if value is MISSING else f"{problem} {_shown(value)}"
        super().__init__(f"{one_line(source)}: key '{one_line(key)}': {found}; "
                         f"accepted: {one_line(accepted)}")

    def within(self, source: str, prefix: str, table: Mapping[str, Any]) -> ScenarioError:
        """This error of a field of ``table`` (read from ``source`` at ``prefix``): its key
        in full, and the value as the file wrote it."""
        value = table.get(self.key, self.value)
        key = f"{prefix}.{self.key}" if prefix else self.key
        return ScenarioError(source, key, value, self.accepted, self.problem)


def _shown(value: object) -> str:
    """A value as a message shows it: tuples as lists, one line, at most 200 characters."""
    def plain(v: object) -> object:
        if isinstance(v, tuple | list):
            return [plain(x) for x in v]
        if isinstance(v, Mapping):
            return {k: plain(x) for k, x in v.items()}
        return v

    text = one_line(repr(plain(value)))
    return text if len(text) <= 200 else text[:197] + "..."


# ---------------------------------------------------------------- fields

Check = tuple[Callable[[Any], bool], str]


def checked(predicate: Callable[[Any], bool], accepted: str, default: Any = dataclasses.MISSING,
            default_factory: Any = dataclasses.MISSING, required: bool = False) -> Any:
    """A dataclass field whose value must satisfy ``predicate``; ``required``: a file
    must state it even though Python code may leave it to the default."""
    meta = {"check": (predicate, accepted), "required": required}
    if default_factory is not dataclasses.MISSING:
        return field(default_factory=default_factory, metadata=meta)
    return field(default=default, metadata=meta)


def positive(default: float) -> Any:
    return checked(lambda v: v > 0 and math.isfinite(v), "a number > 0", default)


def probability(default: float | None) -> Any:
    return checked(lambda v: 0 < v < 1, "a number strictly between 0 and 1", default)


def nonnegative(default: float) -> Any:
    return checked(lambda v: v >= 0 and math.isfinite(v), "a number >= 0", default)


_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    """The field types of the dataclass ``cls``, resolved once."""
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


class Checked:
    """A config dataclass whose fields' types and checks run whenever one is made
    (parsed, built in code, or ``dataclasses.replace``d): an invalid value never gets in.
    Subclasses add cross-field checks by extending ``__post_init__``."""

    def __post_init__(self) -> None:
        hints = _hints(type(self))
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            accepted = None if conforms(hints[f.name], value) else type_name(hints[f.name])
            check: Check | None = f.metadata.get("check")
            if accepted is None and check is not None and value is not None \
                    and not check[0](value):
                accepted = check[1]
            if accepted is not None:
                raise ScenarioError(self.source_name(), f.name, value, accepted)

    def source_name(self) -> str:
        """Where this config came from: its ``source`` field, else its class."""
        source = getattr(self, "source", None)
        return source if isinstance(source, str) else f"<{type(self).__name__}>"


# ---------------------------------------------------------------- types


def _open_tuple(args: tuple[Any, ...]) -> bool:
    return len(args) == 2 and args[1] is Ellipsis


def _optional_inner(tp: Any) -> Any:
    inner = [a for a in typing.get_args(tp) if a is not type(None)]
    if len(inner) != 1:
        raise TypeError(f"unsupported field type {tp}")
    return inner[0]


def type_name(tp: Any) -> str:
    """What a value of type ``tp`` looks like in a file."""
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin in (types.UnionType, typing.Union):
        return " or ".join(type_name(a) for a in typing.get_args(tp) if a is not type(None))
    if origin is tuple:
        args = typing.get_args(tp)
        if _open_tuple(args):
            inner = args[0]
            if dataclasses.is_dataclass(inner):
                return f"a list of tables ({', '.join(f.name for f in dataclasses.fields(inner))})"
            return f"a list of {type_name(inner)}s"
        return f"a list of {len(args)} {type_name(args[0])}s"
    if dataclasses.is_dataclass(tp):
        return f"a table with keys {', '.join(f.name for f in dataclasses.fields(tp))}"
    return {float: "number", int: "integer", bool: "boolean", str: "string"}.get(tp, str(tp))


def conforms(tp: Any, value: Any) -> bool:
    """Whether ``value`` (as Python code holds it: tuples, numpy scalars allowed) is of
    the field type ``tp``; numbers must be finite."""
    origin = typing.get_origin(tp)
    if origin is Literal:
        return any(value == a and type(value) is type(a) for a in typing.get_args(tp))
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, tuple):
            return False
        if _open_tuple(args):
            return all(conforms(args[0], v) for v in value)
        return len(value) == len(args) and all(
            conforms(a, v) for a, v in zip(args, value, strict=True))
    if origin in (types.UnionType, typing.Union):
        return value is None or conforms(_optional_inner(tp), value)
    if dataclasses.is_dataclass(tp):
        return isinstance(value, typing.cast(type, tp))
    if tp is float:
        return (isinstance(value, numbers.Real) and not isinstance(value, bool)
                and math.isfinite(value))
    if tp is int:
        return isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if tp is bool or tp is str:
        return isinstance(value, tp)
    raise TypeError(f"unsupported field type {tp}")


def convert(tp: Any, value: Any, key: str, source: str) -> Any:
    """A file's ``value`` at ``key`` as the field type ``tp`` holds it (lists as tuples,
    tables as dataclasses); ScenarioError naming the key if it is not one."""
    def bad() -> ScenarioError:
        return ScenarioError(source, key, value, type_name(tp))

    origin = typing.get_origin(tp)
    if origin is Literal:
        if value not in typing.get_args(tp):
            raise bad()
        return value
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, list):
            raise bad()
        if _open_tuple(args):
            return tuple(convert(args[0], v, f"{key}[{i}]", source) for i, v in enumerate(value))
        if len(value) != len(args):
            raise bad()
        try:
            return tuple(convert(a, v, key, source) for a, v in zip(args, value, strict=True))
        except ScenarioError:
            raise bad() from None  # the whole list, with what it should be
    if origin in (types.UnionType, typing.Union):
        return convert(_optional_inner(tp), value, key, source)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, Mapping):
            raise bad()
        return build(typing.cast(type, tp), value, key, source)
    if tp is float:
        number = isinstance(value, int | float) and not isinstance(value, bool)
        if not number or not math.isfinite(value):
            raise bad()
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad()
        return value
    if tp is bool or tp is str:
        if not isinstance(value, tp):
            raise bad()
        return value
    raise TypeError(f"unsupported field type {tp}")


# ---------------------------------------------------------------- tables and files


def build(cls: type[T], table: Mapping[str, Any], prefix: str, source: str) -> T:
    """An instance of the dataclass ``cls`` from ``table`` (at key ``prefix`` of the file
    ``source``): unknown keys, missing required ones, wrong types and failed checks raise
    ScenarioError naming the key in full; a key in the class's ``RETIRED`` (old key ->
    what replaces it) is refused with that message."""
    hints = _hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)  # type: ignore[arg-type]
              if f.name != "source"}
    retired: dict[str, str] = getattr(cls, "RETIRED", {})
    for key in table:
        if key not in fields:
            name = f"{prefix}.{key}" if prefix else key
            if key in retired:
                raise ScenarioError(source, name, table[key], retired[key],
                                    problem="retired key, with value")
            raise ScenarioError(source, name, table[key], "keys " + ", ".join(fields),
                                problem="unknown key, with value")
    has_source = "source" in {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    kwargs: dict[str, Any] = {"source": source} if has_source else {}
    for name, f in fields.items():
        key = f"{prefix}.{name}" if prefix else name
        if name not in table:
            if f.metadata.get("required") or (f.default is dataclasses.MISSING
                                              and f.default_factory is dataclasses.MISSING):
                raise ScenarioError(source, key, MISSING,
                                    f"{type_name(hints[name])} (required)", problem="missing")
            continue
        kwargs[name] = convert(hints[name], table[name], key, source)
    try:
        return cls(**kwargs)  # the fields' checks and cross-checks (Checked)
    except ScenarioError as exc:
        raise exc.within(source, prefix, table) from None


def merged_tables(under: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """``over``'s keys over ``under``'s: tables merged key by key, any other value
    (lists included) replacing the one below."""
    out = dict(under)
    for key, value in over.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merged_tables(out[key], value)
        else:
            out[key] = value
    return out


def read_toml(path: Path) -> dict[str, Any]:
    """A TOML file's table; ScenarioError if it cannot be read, is not UTF-8 text, or is
    not TOML."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ScenarioError(str(path), "<file>", str(path),
                            f"a readable TOML file ({exc.strerror})") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        found = f"byte 0x{raw[exc.start]:02x} at offset {exc.start}"
        raise ScenarioError(str(path), "<file>", found, "a TOML file in UTF-8",
                            problem="not UTF-8 text:") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(str(path), "<syntax>", str(exc), "valid TOML") from None

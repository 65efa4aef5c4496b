"""Typed configuration: YAML or plain mappings into nested frozen dataclasses.

Every stage of e2sr describes its options as frozen dataclasses with defaults. This module
turns a mapping (usually ``yaml.safe_load`` output) into such a dataclass, recursing into
nested dataclasses and tuples, rejecting unknown keys and wrong types with a message that
names the source file and the dotted key. ``--set a.b=c`` overrides go through
:func:`apply_overrides`, and a CLI's own typed flags through :func:`apply_values`, so they
get the same checks; :func:`load_config` is the one loader the command lines share, and
layers several files (a partial preset over a full config) by a deep merge in order.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import yaml

from esim_lite.core.limits import MAX_CONFIG_BYTES, MAX_CONFIG_NODES

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration value or key is invalid; the message names the source and key."""


def _fail(source: str, key: str, problem: str) -> typing.NoReturn:
    where = f"{source}: " if source else ""
    raise ConfigError(f"{where}{key or '<root>'}: {problem}")


def _convert(tp: Any, value: Any, source: str, key: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, Mapping):
            _fail(source, key, f"expected a mapping for {tp.__name__}, got {value!r}")
        return from_mapping(tp, value, source=source, prefix=key)
    if origin in (typing.Union, types.UnionType):
        return _convert_union(args, value, source, key)
    if origin is typing.Literal:
        if value not in args:
            _fail(source, key, f"{value!r} is not one of {list(args)}")
        return value
    if origin in (tuple, list):
        return _convert_sequence(origin, args, value, source, key)
    if origin in (dict, Mapping):
        if not isinstance(value, Mapping):
            _fail(source, key, f"expected a mapping, got {value!r}")
        kt, vt = args if args else (Any, Any)
        return {_convert(kt, k, source, key): _convert(vt, v, source, f"{key}.{k}")
                for k, v in value.items()}
    return _convert_scalar(tp, value, source, key)


def _convert_union(args: tuple, value: Any, source: str, key: str) -> Any:
    """``value`` as the first member of the union ``args`` that takes it (None if allowed)."""
    if value is None and type(None) in args:
        return None
    for arg in args:
        if arg is type(None):
            continue
        try:
            return _convert(arg, value, source, key)
        except ConfigError:
            pass  # the next member may take it
    _fail(source, key, f"{value!r} matches none of {args}")


def _convert_sequence(origin: type, args: tuple, value: Any, source: str, key: str
                      ) -> tuple | list:
    """A YAML list as ``tuple[...]`` (fixed length or ``...``) or ``list[...]``."""
    if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)):
        _fail(source, key, f"expected a list, got {value!r}")
    if origin is tuple and args and args[-1] is not Ellipsis:
        if len(value) != len(args):
            _fail(source, key, f"expected {len(args)} items, got {len(value)}")
        return tuple(_convert(a, v, source, f"{key}[{i}]")
                     for i, (a, v) in enumerate(zip(args, value)))
    item = args[0] if args else Any
    items = [_convert(item, v, source, f"{key}[{i}]") for i, v in enumerate(value)]
    return tuple(items) if origin is tuple else items


def _convert_scalar(tp: Any, value: Any, source: str, key: str) -> Any:
    """``value`` as a bool, int, float or str (strictly: no bool for a number, no number
    for a string), or checked to be an instance of any other class ``tp``."""
    if tp is bool:
        if not isinstance(value, bool):
            _fail(source, key, f"expected true/false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            _fail(source, key, f"expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, str):  # YAML 1.1 reads 1e-4 (no dot) as a string
            try:
                return float(value)
            except ValueError:
                pass
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            _fail(source, key, f"expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            _fail(source, key, f"expected a string, got {value!r}")
        return value
    if isinstance(tp, type) and not isinstance(value, tp):
        _fail(source, key, f"expected {tp.__name__}, got {value!r}")
    return value


def from_mapping(cls: type[T], data: Mapping[str, Any] | None, *, source: str = "",
                 prefix: str = "") -> T:
    """Build dataclass ``cls`` from ``data``; missing keys take the dataclass defaults.

    Raises:
        ConfigError: unknown key, wrong type, or a value rejected by ``__post_init__``;
            the message names ``source`` (usually the YAML path) and the dotted key.
    """
    data = {} if data is None else data
    if not isinstance(data, Mapping):
        _fail(source, prefix, f"expected a mapping, got {data!r}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - names)
    if unknown:
        _fail(source, f"{prefix}.{unknown[0]}" if prefix else str(unknown[0]),
              f"unknown key (valid keys: {', '.join(sorted(names))})")
    defaults = _field_defaults(cls)
    kwargs = {}
    for name, value in data.items():
        key = f"{prefix}.{name}" if prefix else name
        base = defaults.get(name)
        if dataclasses.is_dataclass(base) and isinstance(value, Mapping):
            # a partial section overrides the field's own default, not its class defaults
            value = _deep_merge(to_mapping(base), value)
        kwargs[name] = _convert(hints[name], value, source, key)
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, ConfigError):
            raise
        _fail(source, prefix, str(exc))


def _field_defaults(cls: type) -> dict[str, Any]:
    out = {}
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            out[f.name] = f.default
        elif f.default_factory is not dataclasses.MISSING:
            out[f.name] = f.default_factory()
    return out


def _deep_merge(base: Mapping[str, Any], update: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in update.items():
        out[k] = _deep_merge(out[k], v) if isinstance(v, Mapping) and isinstance(
            out.get(k), Mapping) else v
    return out


def to_mapping(obj: Any) -> Any:
    """Plain-Python (YAML-safe) form of a config dataclass: dicts, lists and scalars."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_mapping(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_mapping(v) for v in obj]
    if isinstance(obj, Mapping):
        return {k: to_mapping(v) for k, v in obj.items()}
    return obj


def to_yaml(obj: Any) -> str:
    """YAML text of a config dataclass; ``load_yaml_text(type(obj), to_yaml(obj)) == obj``."""
    return yaml.safe_dump(to_mapping(obj), sort_keys=False)


def load_yaml_text(cls: type[T], text: str, *, source: str = "<text>") -> T:
    return from_mapping(cls, parse_yaml(text, source), source=source)


def parse_yaml(text: str, source: str) -> Any:
    """``yaml.safe_load(text)``, bounded: at most :data:`MAX_CONFIG_BYTES` of text and
    :data:`MAX_CONFIG_NODES` values once aliases are expanded (every later step copies the
    expanded tree, so a few lines of nested aliases would otherwise take gigabytes), no
    alias inside itself.

    Raises:
        ConfigError: naming ``source``: not YAML, too large, too deeply nested, or an alias
            expanding past the limit or into itself.
    """
    if len(text) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{source}: {len(text):,} characters, more than a config may hold "
                          f"({MAX_CONFIG_BYTES:,})")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: not valid YAML: {exc}") from exc
    except RecursionError:
        raise ConfigError(f"{source}: nested too deeply to be a config") from None
    _count_values(data, source, {}, set())
    return data


def _count_values(node: Any, source: str, sizes: dict[int, int], path: set[int]) -> int:
    """Values in ``node`` with every alias expanded, counted without expanding: a node
    shared by aliases is counted once per use from its memoised size."""
    if not isinstance(node, (dict, list)):
        return 1
    key = id(node)
    if key in sizes:
        return sizes[key]
    if key in path:
        raise ConfigError(f"{source}: an alias refers to a section that holds it (a config "
                          f"cannot contain itself)")
    if len(path) > 100:
        raise ConfigError(f"{source}: nested more than 100 levels deep")
    path.add(key)
    children = [*node.keys(), *node.values()] if isinstance(node, dict) else node
    total = 1 + sum(_count_values(c, source, sizes, path) for c in children)
    path.discard(key)
    if total > MAX_CONFIG_NODES:
        raise ConfigError(f"{source}: expands to more than {MAX_CONFIG_NODES:,} values "
                          f"(aliases repeating aliases?); a config holds a few hundred")
    sizes[key] = total
    return total


def load_yaml(cls: type[T], path: str | Path, overrides: Sequence[str] | None = None) -> T:
    """Load ``path`` into ``cls``, then apply ``key=value`` overrides (YAML-typed values)."""
    return load_config(cls, path, overrides or ())


def load_config(cls: type[T], path: str | Path | Sequence[str | Path] | None,
                overrides: Sequence[str] = (), values: Mapping[str, Any] | None = None) -> T:
    """What a command line's ``--config PATH [--config PATH ...] --set KEY=VALUE ...``
    stands for.

    The YAML at ``path``, or at each of several paths in order, later files overriding
    earlier ones key by key (a deep merge of their mappings; lists are replaced whole), so
    a partial file such as a sensor preset loads on top of a dataset config (``None`` or
    no paths: the defaults of ``cls``); then the ``key=value`` ``overrides`` (values parsed
    as YAML), then ``values``: dotted keys to typed values (a CLI's own flags, e.g.
    ``{"simulation.camera.scales": [2, 4]}``), which win over both. Every value passes the
    same checks as the file's.

    Raises:
        FileNotFoundError: a path does not exist.
        ConfigError: bad YAML, unknown key or rejected value, naming the key and the file
            that holds it (of several, the first whose layer makes the config invalid),
            or the ``--set`` that carried it.
    """
    paths = [] if path is None else [path] if isinstance(path, (str, Path)) else list(path)
    layers = [(str(p), _read_mapping(Path(p))) for p in paths]
    source = layers[-1][0] if layers else "--set"
    data: dict[str, Any] = {}
    for _, layer in layers:
        data = _deep_merge(data, layer)
    data = apply_overrides(data, overrides, source=source)
    data = apply_values(data, values or {}, source=source)
    try:
        return from_mapping(cls, data, source=source)
    except ConfigError:
        if len(layers) > 1 or overrides:
            _blame_layer(cls, layers, overrides)
        raise


def _read_mapping(path: Path) -> dict[str, Any]:
    """The top-level mapping of the YAML file at ``path`` (empty for an empty file)."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: config file not found")
    if path.stat().st_size > MAX_CONFIG_BYTES:
        raise ConfigError(f"{path}: {path.stat().st_size:,} bytes, more than a config may "
                          f"hold ({MAX_CONFIG_BYTES:,})")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not a readable text file ({exc})") from exc
    data = parse_yaml(text, str(path)) or {}
    if not isinstance(data, Mapping):
        raise ConfigError(f"{path}: the top level must be a mapping of sections (key: "
                          f"value), not a {type(data).__name__}")
    return dict(data)


def _blame_layer(cls: type, layers: Sequence[tuple[str, Mapping[str, Any]]],
                 overrides: Sequence[str] = ()) -> None:
    """Raise the error of the first file whose layer, merged over the files before it, makes
    ``cls`` invalid (named as that file's), else of the first ``--set`` that does (named as
    that ``--set``); return if every prefix of the layers and overrides is valid."""
    data: dict[str, Any] = {}
    for source, layer in layers:
        data = _deep_merge(data, layer)
        from_mapping(cls, data, source=source)
    for item in overrides:
        data = apply_overrides(data, [item], source=f"--set {item}")
        from_mapping(cls, data, source=f"--set {item}")


def apply_overrides(data: Mapping[str, Any], overrides: Sequence[str], *,
                    source: str = "--set") -> dict[str, Any]:
    """Return a copy of ``data`` with each ``a.b.c=value`` applied (value parsed as YAML)."""
    out = _deep_copy(data)
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"{source}: override {item!r} is not of the form key=value")
        dotted, raw = item.split("=", 1)
        value = parse_yaml(raw, f"{source}: override {item!r}: bad value")
        _set_dotted(out, dotted, value, source, repr(item))
    return out


def apply_values(data: Mapping[str, Any], values: Mapping[str, Any], *,
                 source: str = "--set") -> dict[str, Any]:
    """Return a copy of ``data`` with each dotted key of ``values`` set to its value as it is
    (no YAML parsing: the caller's flags are already typed)."""
    out = _deep_copy(data)
    for dotted, value in values.items():
        _set_dotted(out, dotted, value, source, repr(dotted))
    return out


def _set_dotted(out: dict[str, Any], dotted: str, value: Any, source: str, what: str) -> None:
    keys = dotted.strip().split(".")
    if not all(keys):
        raise ConfigError(f"{source}: override {what} has an empty key")
    node = out
    for k in keys[:-1]:
        nxt = node.get(k)
        if nxt is None:
            nxt = node[k] = {}
        elif not isinstance(nxt, dict):
            raise ConfigError(f"{source}: override {what}: {k} is not a section")
        node = nxt
    node[keys[-1]] = value


def _deep_copy(data: Mapping[str, Any]) -> dict[str, Any]:
    return {k: _deep_copy(v) if isinstance(v, Mapping) else v for k, v in data.items()}

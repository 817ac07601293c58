"""The one configuration mechanism of img2dmp: a file, then ``--set key=value`` overrides.

Every command that takes settings (``generate``, ``prepare``, ``import``, ``train``, ``demo``) reads
them the same way:

1. the dataclass defaults (:class:`img2dmp.data.synthetic.SyntheticConfig`,
   :class:`img2dmp.data.prepare.PrepareOptions`, :class:`img2dmp.training.TrainConfig`);
2. a YAML (``.yaml``/``.yml``), TOML (``.toml``) or JSON file, :func:`read_config_file`,
   or by its name one of the configurations shipped inside the package
   (``src/img2dmp/configs/NAME.yaml``: ``paper``, ``conv-wide``, ``real`` ...,
   :func:`shipped_configs`);
3. ``section.key=value`` overrides, values parsed as YAML, :func:`apply_overrides`;
4. :func:`from_mapping`: typed construction from the fields' annotations. Unknown keys
   are rejected, numbers given as text, booleans given as numbers and wrong shapes are
   refused with an error that names the field (``optim.lr must be a number, got 'x'``).

:func:`check_positive` is the one "finite and > 0" check of the package.

Reading is bounded (:data:`MAX_DEPTH`, :data:`MAX_VALUES` with YAML aliases counted,
:data:`MAX_CONFIG_BYTES`, :data:`MAX_DIGITS`) and strict (a key given twice is refused),
and values in errors are cut (:func:`img2dmp.errors.show`). Nothing here imports the rest
of img2dmp but :mod:`img2dmp.errors`, so every layer can use it.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import re
import tomllib
import types
import typing
from importlib import resources
from pathlib import Path

import yaml

from .errors import show


class ConfigError(ValueError):
    """A configuration file, field or override that cannot be used (names which)."""


#: Deepest nesting of a configuration: a section, a field, a list of lists, with room to
#: spare. Deeper ones are refused while they are read (Python's recursion would end in a
#: ``RecursionError`` some thousands of levels down, in the reader or after it).
MAX_DEPTH = 20
#: Most values (mappings, lists and scalars) of one configuration or ``--set`` value, an
#: alias counted as the values it stands for: a YAML alias bomb (nine levels of nine
#: aliases, 9**9 values from a few hundred bytes) is refused long before it is expanded.
MAX_VALUES = 100_000
#: Largest configuration file read.
MAX_CONFIG_BYTES = 1 << 20
#: Most digits of a whole number (Python refuses to convert more than 4,300).
MAX_DIGITS = 100


class _Loader(yaml.SafeLoader):
    """YAML's safe loader, reading ``3e-4`` and ``1E5`` as numbers, bounded and strict.

    YAML 1.1 (PyYAML) takes a float without a dot for a string, so ``lr: 3e-4`` would
    otherwise reach the optimiser as text. While the document is composed, its depth and
    its number of values are counted, each alias as the size of the value it names (never
    expanded to count it), and a document beyond :data:`MAX_DEPTH` or :data:`MAX_VALUES`
    is refused. A key given twice in one mapping is refused (PyYAML keeps the last
    silently; JSON configurations are read here too), and so are whole numbers of more
    than :data:`MAX_DIGITS` digits.
    """

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0  # of the node being composed (the document's root is 1)
        self._reach = 0  # deepest level reached, aliases expanded
        self._values = 0  # values so far, aliases expanded
        self._sizes: dict[int, tuple[int, int]] = {}  # id(node): (values, height)

    def _where(self, event) -> str:
        return f"line {event.start_mark.line + 1}"

    def compose_node(self, parent, index):
        event = self.peek_event()
        if self.check_event(yaml.AliasEvent):
            node = super().compose_node(parent, index)
            if id(node) not in self._sizes:  # an alias inside the value it names
                raise ConfigError(f"alias *{event.anchor} ({self._where(event)}) refers to a "
                                  "value that contains it")  # fmt: skip
            values, height = self._sizes[id(node)]
            self._count(values, self._depth + height, event)
            return node
        self._depth += 1
        reach_before, first = self._reach, self._values
        self._count(1, self._depth, event)
        node = super().compose_node(parent, index)
        self._sizes[id(node)] = (self._values - first, self._reach - self._depth + 1)
        self._depth -= 1
        self._reach = max(reach_before, self._reach)
        return node

    def _count(self, values: int, reach: int, event) -> None:
        self._values += values
        self._reach = max(self._reach, reach)
        if self._reach > MAX_DEPTH:
            raise ConfigError(f"nested more than {MAX_DEPTH} levels deep ({self._where(event)})")
        if self._values > MAX_VALUES:
            raise ConfigError(
                f"holds more than {MAX_VALUES:,} values, aliases counted as the values they "
                f"stand for ({self._where(event)})"
            )

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # "<<": keys merged on purpose
                continue
            key = self.construct_object(key_node, deep=True)
            if isinstance(key, typing.Hashable) and key in seen:
                raise ConfigError(
                    f"key {show(key)} is given twice in one mapping (line "
                    f"{key_node.start_mark.line + 1}); give each key once"
                )
            if isinstance(key, typing.Hashable):
                seen.add(key)
        return super().construct_mapping(node, deep)

    def construct_yaml_int(self, node):
        digits = sum(c.isdigit() for c in node.value)
        if digits > MAX_DIGITS:
            raise ConfigError(
                f"a whole number of {digits:,} digits is too long (line "
                f"{node.start_mark.line + 1}; at most {MAX_DIGITS})"
            )
        return super().construct_yaml_int(node)


_Loader.add_constructor("tag:yaml.org,2002:int", _Loader.construct_yaml_int)
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def parse_yaml(text: str):
    """A YAML document (or a single ``--set`` value) with :class:`_Loader`: bounded in
    depth and size, duplicate keys refused (``ConfigError``, or ``yaml.YAMLError`` for
    text that is no YAML)."""
    return yaml.load(text, Loader=_Loader)  # noqa: S506 - a SafeLoader subclass


def _check_digits(text: str) -> None:
    """``ConfigError`` for a run of more than :data:`MAX_DIGITS` digits in a text."""
    for m in re.finditer(rf"[0-9][0-9_]{{{MAX_DIGITS},}}", text):
        digits = sum(c.isdigit() for c in m.group())
        if digits > MAX_DIGITS:
            line = text.count("\n", 0, m.start()) + 1
            raise ConfigError(
                f"a whole number of {digits:,} digits is too long (line {line}; at most "
                f"{MAX_DIGITS})"
            )


def check_depth(value, where: str) -> None:
    """``ConfigError`` if ``value`` (plain lists and dicts, as TOML gives them) nests more
    than :data:`MAX_DEPTH` levels or holds more than :data:`MAX_VALUES` values; walked
    without recursion."""
    stack, values = [(value, 1)], 0
    while stack:
        v, depth = stack.pop()
        values += 1
        if depth > MAX_DEPTH:
            raise ConfigError(f"{where}: nested more than {MAX_DEPTH} levels deep")
        if values > MAX_VALUES:
            raise ConfigError(f"{where}: holds more than {MAX_VALUES:,} values")
        children = v.values() if isinstance(v, dict) else v if isinstance(v, list) else ()
        stack.extend((c, depth + 1) for c in children)


#: Where the configurations that ship with img2dmp live (package data).
SHIPPED_DIR = "configs"


def shipped_configs() -> list[str]:
    """Names of the configurations shipped inside the package (``paper``, ``conv-wide`` ...),
    each usable as ``--config NAME``."""
    folder = resources.files("img2dmp").joinpath(SHIPPED_DIR)
    return sorted(f.name[:-5] for f in folder.iterdir() if f.name.endswith(".yaml"))


def shipped_config_path(name: str) -> Path:
    """The file of the shipped configuration ``name`` (``ConfigError`` naming the shipped
    ones if there is none of that name)."""
    known = shipped_configs()
    if name not in known:
        raise ConfigError(
            f"no shipped configuration named {show(name)}; the shipped ones are "
            f"{', '.join(known)} (or give a .yaml, .toml or .json file)"
        )
    return Path(str(resources.files("img2dmp").joinpath(SHIPPED_DIR, f"{name}.yaml")))


def config_path(path: str | os.PathLike) -> Path:
    """The file a ``--config`` value means: a bare name without a suffix or a folder
    (``paper``, ``conv-wide``) is a configuration shipped with img2dmp
    (:func:`shipped_configs`), anything else a path."""
    text = os.fspath(path)
    if text and not Path(text).suffix and os.sep not in text and "/" not in text:
        if not Path(text).exists():
            return shipped_config_path(text)
    return Path(text)


def parse_problem(e: Exception) -> str:
    """A parser's error in one line: for YAML, what is wrong and where (its first line
    alone, "while parsing a flow sequence", said neither), else the first line."""
    if isinstance(e, yaml.MarkedYAMLError) and e.problem:

        def at(mark) -> str:
            return f" (line {mark.line + 1}, column {mark.column + 1})" if mark else ""

        context = f"{e.context}{at(e.context_mark)}: " if e.context else ""
        return f"{context}{e.problem}{at(e.problem_mark)}"
    return str(e).splitlines()[0] if str(e) else type(e).__name__


def read_config_file(path: str | os.PathLike) -> dict:
    """A YAML (``.yaml``/``.yml``), TOML (``.toml``) or JSON (``.json``) file as a dict;
    a bare name (``paper``) reads the configuration of that name shipped with img2dmp."""
    p = config_path(path)
    if p.is_dir():
        raise ConfigError(f"config file {p} is a directory")
    if not p.is_file():
        hint = ""
        if p.parent.name == SHIPPED_DIR and p.stem in shipped_configs():
            hint = f"; the configuration {p.stem!r} ships with img2dmp: --config {p.stem}"
        raise FileNotFoundError(f"config file {p} does not exist{hint}")
    if p.suffix not in (".yaml", ".yml", ".toml", ".json"):
        raise ConfigError(f"config file {p} must end in .yaml, .yml, .toml or .json")
    try:
        with open(p, "rb") as f:
            raw = f.read(MAX_CONFIG_BYTES + 1)
        text = raw.decode("utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"config file {p} cannot be read: {e}") from e
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(
            f"config file {p} is larger than {MAX_CONFIG_BYTES >> 20} MiB; a configuration "
            "holds a few kB (is it the right file?)"
        )
    try:
        if p.suffix == ".toml":
            _check_digits(text)  # tomllib has no hook for whole numbers
            d = tomllib.loads(text)
            check_depth(d, "the file")
        else:  # JSON is YAML 1.2; the loader reads it too.
            d = parse_yaml(text) or {}
    except RecursionError:  # tomllib recurses into nested arrays and tables
        raise ConfigError(f"config file {p} cannot be parsed: nested too deeply") from None
    except (yaml.YAMLError, tomllib.TOMLDecodeError, ValueError) as e:
        # ValueError: the loader's bounds, or Python's refusal of a 5,000-digit number
        raise ConfigError(f"config file {p} cannot be parsed: {parse_problem(e)}") from e
    if not isinstance(d, dict):
        raise ConfigError(f"config file {p} must hold a mapping at the top level")
    return d


def apply_overrides(d: dict, overrides: list[str] | None) -> dict:
    """A copy of ``d`` with ``section.key=value`` overrides applied in order.

    Values are parsed as YAML (``[16, 32]``, ``null``, ``3e-4``); the last of two
    overrides of one key wins, overrides of different keys all apply.
    """
    d = copy.deepcopy(d)
    for item in overrides or []:
        if "=" not in item:
            raise ConfigError(f"override {show(item)} must look like section.key=value")
        key, raw = item.split("=", 1)
        parts = key.strip().split(".")
        if not all(parts) or len(parts) > MAX_DEPTH:
            raise ConfigError(f"override {show(item)}: {show(key)} is not a field name")
        node = d
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ConfigError(f"override {show(item)}: {show(p)} is not a config section")
        try:
            node[parts[-1]] = parse_yaml(raw)
        except (yaml.YAMLError, ValueError) as e:
            problem = parse_problem(e)
            raise ConfigError(f"override {show(key)}: value cannot be parsed: {problem}") from e
    return d


def check_positive(name: str, value, *, allow_zero: bool = False) -> float:
    """``value`` as a float if it is a finite number > 0 (>= 0 with ``allow_zero``).

    The package's one such check: the error names ``name`` and the value given.
    """
    bound = ">= 0" if allow_zero else "> 0"
    if isinstance(value, (bool, str, bytes)):
        raise ConfigError(f"{name} must be a number {bound}, got {show(value)}")
    if not isinstance(value, (int, float)):
        try:  # NumPy and torch scalars
            value = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"{name} must be a number {bound}, got {show(value)}") from None
    v = float(value)
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise ConfigError(f"{name} must be a finite number {bound}, got {show(value)}")
    return v


def check_positive_fields(obj, names, *, allow_zero: bool = False) -> None:
    """:func:`check_positive` for each attribute of ``obj`` named in ``names``."""
    for name in names:
        check_positive(name, getattr(obj, name), allow_zero=allow_zero)


def _describe(tp) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _coerce(value, tp, name: str):
    """``value`` checked (and lightly converted) against the annotation ``tp``."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        arms = [a for a in args if a is not type(None)]
        errors = []
        for arm in arms:
            try:
                return _coerce(value, arm, name)
            except ConfigError as e:
                errors.append(e)
        if len(arms) == 1:
            raise errors[0]
        kinds = [_describe(a) for a in arms]
        raise ConfigError(f"{name} must be one of {kinds}, got {show(value)}")
    if tp is typing.Any:
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{name} must be true or false, got {show(value)}")
        return value
    if tp is int:
        if isinstance(value, float) and value.is_integer():
            value = int(value)  # YAML's 1e3
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{name} must be a number (int), got {show(value)}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{name} must be a number, got {show(value)}")
        if not math.isfinite(value):
            raise ConfigError(f"{name} must be a finite number, got {show(value)}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{name} must be text, got {show(value)}")
        return value
    if origin in (list, tuple) or tp in (list, tuple):
        return _coerce_sequence(value, tp, origin or tp, args, name)
    if origin is dict or tp is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{name} must be a mapping, got {show(value)}")
        return value
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, dict):
            raise ConfigError(
                f"{name} must be a mapping of {tp.__name__} fields, got {show(value)}"
            )
        return from_mapping(tp, value, name)
    return value


def _coerce_sequence(value, tp, kind, args, name: str):
    if not isinstance(value, (list, tuple)):
        raise ConfigError(f"{name} must be a list, got {show(value)}")
    if kind is tuple and args and args[-1] is not Ellipsis:
        if len(value) != len(args):
            raise ConfigError(f"{name} must hold {len(args)} values, got {show(value)}")
        return tuple(
            _coerce(v, a, f"{name}[{i}]") for i, (v, a) in enumerate(zip(value, args, strict=True))
        )
    item = args[0] if args else typing.Any
    out = [_coerce(v, item, f"{name}[{i}]") for i, v in enumerate(value)]
    return tuple(out) if kind is tuple else out


def from_mapping(cls, d: dict, section: str = ""):
    """An instance of the dataclass ``cls`` from a mapping, typed by its annotations.

    ``section`` prefixes field names in errors (``"optim"`` gives ``optim.lr``). Unknown
    keys are refused; missing keys take their defaults; a nested dataclass field takes a
    mapping. The class's own ``__post_init__`` then checks ranges and choices.
    """
    where = f"{section}." if section else ""
    if not isinstance(d, dict):
        raise ConfigError(
            f"config section {section or cls.__name__!r} must be a mapping, got {show(d)}"
        )
    hints = typing.get_type_hints(cls)
    _refuse_unknown(cls, d, where)
    kwargs = {k: _coerce(v, hints.get(k, typing.Any), where + k) for k, v in d.items()}
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except (TypeError, ValueError) as e:
        msg = str(e)
        # The classes' own checks name their fields bare; say which section they are in.
        if section and not msg.startswith(where):
            msg = f"{section}: {msg}"
        raise ConfigError(msg) from e


def load(
    cls,
    path: str | os.PathLike | None = None,
    overrides: list[str] | None = None,
    base: dict | None = None,
):
    """``cls`` from ``base`` (a mapping), then the file at ``path``, then ``overrides``."""
    d = copy.deepcopy(base or {})
    if path:
        d = merge(d, read_config_of(cls, path))
    return from_mapping(cls, apply_overrides(d, overrides))


def read_config_of(cls, path: str | os.PathLike) -> dict:
    """The mapping of the configuration file ``path`` (:func:`read_config_file`), its keys
    and its sections' keys checked against the fields of the dataclass ``cls``: a misspelt
    key is the file's, and the one-line error says so (``config file bad.yaml: unknown
    field(s) model.conv_chanels; known: ...``; a ``--set`` key is named alone). Every
    command that takes ``--config`` reads it here; values are left to :func:`from_mapping`."""
    found = read_config_file(path)
    try:
        check_known(cls, found)
    except ConfigError as e:
        raise ConfigError(f"config file {config_path(path)}: {e}") from None
    return found


def check_known(cls, d, section: str = "") -> None:
    """Refuse the keys of mapping ``d`` (and of its sections) that the dataclass ``cls``
    has no field of, as :func:`from_mapping` does; values are left to it."""
    if not isinstance(d, dict):
        return
    _refuse_unknown(cls, d, f"{section}." if section else "")
    hints = typing.get_type_hints(cls)
    for k, v in d.items():
        kind = hints.get(k)
        if isinstance(kind, type) and dataclasses.is_dataclass(kind):
            check_known(kind, v, f"{section}.{k}" if section else str(k))


def _refuse_unknown(cls, d: dict, where: str) -> None:
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    unknown = sorted(str(k) for k in set(d) - set(names))
    if unknown:
        listed = ", ".join(show(where + u, 40).strip("'") for u in unknown[:10])
        more = f" and {len(unknown) - 10:,} more" if len(unknown) > 10 else ""
        raise ConfigError(f"unknown field(s) {listed}{more}; known: {', '.join(names)}")


def merge(base: dict, update: dict) -> dict:
    """``update`` over ``base``, section by section (nested mappings merge, values replace)."""
    out = copy.deepcopy(base)
    for k, v in update.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def to_dict(obj) -> dict:
    """A dataclass as plain lists / dicts / scalars (tuples become lists), for YAML/JSON."""

    def plain(v):
        if dataclasses.is_dataclass(v):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        return v

    return plain(obj)


__all__ = [
    "ConfigError",
    "apply_overrides",
    "check_known",
    "check_positive",
    "check_positive_fields",
    "config_path",
    "from_mapping",
    "load",
    "merge",
    "parse_yaml",
    "read_config_file",
    "read_config_of",
    "shipped_config_path",
    "shipped_configs",
    "to_dict",
]

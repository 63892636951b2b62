"""Options declared once: a config dataclass field carries its command-line flag, help, range and unit.

`option(default, flag=..., help=..., low=..., high=..., unit=...)` is a `dataclasses.field` whose
metadata holds an `Option`. From that one declaration come

- the range and choice check of the Python API (`check_fields`, called in `__post_init__`),
- the argparse flag with its type, choices, metavar and help with the default and range
  (`add_arguments`),
- the config's values from the parsed command line (`values_from_args`), and
- the field -> flag map that lets errors name what the user typed (`field_flags`).

Checks that involve several fields, or a value parsed from text, stay in the dataclass's own
`__post_init__` after `check_fields`.
"""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass
from typing import Any, Callable

from wbmpc.errors import ConfigError, check_number

_KEY = "option"
_UNSET: Any = object()


@dataclass(frozen=True)
class Option:
    """How one config field is checked and set from the command line (see the module docstring)."""

    help: str
    flag: str | None = None  # "--load-kg"; None: a Python/campaign setting without a flag
    low: float | None = None
    high: float | None = None
    low_open: bool = False  # (low, high] instead of [low, high]
    unit: str = ""  # "m/s", "kg": in the range error and the help
    integer: bool = False
    choices: tuple[str, ...] | None = None  # argparse refuses others; the Python API too (unless `parse`)
    scenarios: tuple[str, ...] | None = None  # the scenarios that read it (None: every one); groups the help
    metavar: str | None = None  # default: the unit in capitals ("M/S"), else argparse's
    cli_default: Any = _UNSET  # the flag's default when it is not the field's (e.g. None: "the robot's tuning")
    default_text: str | None = None  # how the help states the default when the value alone does not say it
    parse: Callable[[Any], Any] | None = None  # the parsed flag value -> the field's value (e.g. "on" -> True)
    repeat: bool = False  # the flag may be given several times (argparse "append"); `parse` gets the list
    const: Any = _UNSET  # the flag's value when given without one (`--collision-avoidance` = `--collision-avoidance on`)

    @property
    def dest(self) -> str:
        """The argparse attribute of the flag (as argparse derives it)."""
        assert self.flag is not None
        return self.flag.lstrip("-").replace("-", "_")

    def range_text(self) -> str:
        """The accepted values for the help: "0-1.5 m/s", "> 0 kg", "one of ..."."""
        unit = f" {self.unit}" if self.unit else ""
        if self.low is not None and self.high is not None:
            opening = "(" if self.low_open else "["
            return f"{opening}{self.low:g}, {self.high:g}]{unit}"
        if self.low is not None:
            return f"{'>' if self.low_open else '>='} {self.low:g}{unit}"
        if self.high is not None:
            return f"<= {self.high:g}{unit}"
        return ""


def option(default: Any = _UNSET, *, default_factory: Any = _UNSET, **declaration) -> Any:
    """A dataclass field declared with its `Option` (keyword arguments of `Option`)."""
    metadata = {_KEY: Option(**declaration)}
    if default_factory is not _UNSET:
        return dataclasses.field(default_factory=default_factory, metadata=metadata)
    return dataclasses.field(default=default, metadata=metadata)


def declared_field(cls, name: str) -> Any:
    """`cls`'s declared field `name` as a field of another dataclass (same default and declaration): a config
    that carries another's options flat (`RunConfig` those of `MpcChoices`) declares each of them once."""
    for f in dataclasses.fields(cls):
        if f.name == name and _KEY in f.metadata:
            if f.default_factory is not dataclasses.MISSING:
                return dataclasses.field(default_factory=f.default_factory, metadata=f.metadata)
            return dataclasses.field(default=f.default, metadata=f.metadata)
    raise KeyError(f"{cls.__name__} declares no option '{name}'")


def declared(cls_or_obj) -> list[tuple[dataclasses.Field, Option]]:
    """(field, Option) of every declared field, in declaration order."""
    return [(f, f.metadata[_KEY]) for f in dataclasses.fields(cls_or_obj) if _KEY in f.metadata]


def field_default(f: dataclasses.Field) -> Any:
    """The dataclass default of `f` (a fresh one from its factory; None without a default)."""
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None


def check_fields(obj) -> None:
    """Range, integer and choice checks of every declared field of `obj` (raises `ConfigError.for_field`)."""
    for f, opt in declared(obj):
        value = getattr(obj, f.name)
        allow_none = field_default(f) is None
        if value is None and allow_none:
            continue
        if opt.choices is not None and opt.parse is None:  # with `parse` the choices are the flag's text
            if value not in opt.choices:
                raise ConfigError.for_field(f.name, f"must be {_one_of(opt.choices)} got {value!r}")
        elif opt.integer:
            if isinstance(value, bool) or not isinstance(value, int) or (opt.low is not None and value < opt.low):
                bound = "" if opt.low is None else f" >= {opt.low:g}"
                raise ConfigError.for_field(f.name, f"must be an integer{bound}, got {value!r}")
            check_number(f.name, value, high=opt.high)
        elif opt.low is not None or opt.high is not None:
            check_number(f.name, value, low=opt.low, high=opt.high, low_open=opt.low_open, unit=opt.unit,
                         allow_none=allow_none)


def _one_of(choices: tuple[str, ...]) -> str:
    return f"{' or '.join(choices)}," if len(choices) == 2 else f"one of {', '.join(choices)};"


def field_flags(*classes) -> dict[str, str]:
    """{field: flag} of every declared field with a flag, so that errors name the option typed."""
    return {f.name: opt.flag for cls in classes for f, opt in declared(cls) if opt.flag}


def flag_default(f: dataclasses.Field, opt: Option) -> Any:
    """The flag's default: `Option.cli_default` if declared, else the field's."""
    return field_default(f) if opt.cli_default is _UNSET else opt.cli_default


def help_text(f: dataclasses.Field, opt: Option) -> str:
    """The declared help, the accepted range and the default."""
    text = opt.help
    accepted = opt.range_text()
    if accepted:
        text += f", {accepted}"
    default = flag_default(f, opt)
    if opt.default_text is not None:
        text += f" (default: {opt.default_text})"
    elif default is not None and not isinstance(default, (bool, dict, list)):
        text += f" (default {default:g})" if isinstance(default, float) else f" (default {default})"
    return text.replace("%", "%%")


def add_argument(parser, f: dataclasses.Field, opt: Option) -> None:
    """The flag of one declared field on `parser` (a parser or an argument group)."""
    default = flag_default(f, opt)
    kwargs: dict[str, Any] = {"help": help_text(f, opt)}
    if opt.repeat:
        kwargs.update(action="append")
    elif isinstance(field_default(f), bool):
        kwargs.update(action="store_true")
    else:
        kwargs.update(default=default)
        if opt.const is not _UNSET:
            kwargs.update(nargs="?", const=opt.const)
        if opt.choices is not None:
            kwargs["choices"] = opt.choices
        elif opt.integer:
            kwargs["type"] = int
        elif opt.low is not None or opt.high is not None:
            kwargs["type"] = float
    metavar = opt.metavar or (opt.unit.upper().replace("^", "").replace(" ", "_") if opt.unit else None)
    if metavar and opt.choices is None and kwargs.get("action") != "store_true":
        kwargs["metavar"] = metavar
    parser.add_argument(opt.flag, **kwargs)


def add_arguments(parser, cls, scenarios: tuple[str, ...] | None | object = _UNSET) -> None:
    """The flags of `cls`'s declared fields (those with a flag), optionally only those read by `scenarios`."""
    for f, opt in declared(cls):
        if opt.flag and (scenarios is _UNSET or opt.scenarios == scenarios):
            add_argument(parser, f, opt)


def add_declared(parser, cls, name: str, **overrides) -> None:
    """The flag of `cls`'s field `name` on another command's parser (`wbmpc deploy`, `robot-sim`), with
    `Option` attributes overridden where that command reads it differently (help, cli_default, ...):
    type, range and unit stay the declaration's."""
    for f, opt in declared(cls):
        if f.name == name:
            add_argument(parser, f, dataclasses.replace(opt, **overrides))
            return
    raise KeyError(f"{cls.__name__} declares no option '{name}'")


def declared_help(cls, name: str) -> str:
    """The declared help of `cls`'s field `name` (without range and default)."""
    return next(opt.help for f, opt in declared(cls) if f.name == name)


def scenario_groups(cls) -> list[tuple[str, ...] | None]:
    """The distinct `Option.scenarios` of `cls`'s flags, in declaration order (None first: every scenario)."""
    groups: list[tuple[str, ...] | None] = []
    for _, opt in declared(cls):
        if opt.flag and opt.scenarios not in groups:
            groups.append(opt.scenarios)
    return sorted(groups, key=lambda g: g is not None)


def values_from_args(cls, args: argparse.Namespace) -> dict[str, Any]:
    """{field: value} of `cls`'s flags as parsed in `args`; flags left at None are left out (the field's default)."""
    values = {}
    for f, opt in declared(cls):
        if not opt.flag:
            continue
        value = getattr(args, opt.dest)
        if opt.parse is not None and (value is not None or opt.repeat):
            value = opt.parse(value)
        if value is not None:
            values[f.name] = value
    return values

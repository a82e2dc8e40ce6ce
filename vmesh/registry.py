"""Filter registry: named filters with typed, documented parameters.

Modelled on pymeshlab: every filter is discoverable by name
(:func:`filter_list`, :func:`print_filter_list`), and
:func:`print_filter_parameter_list` prints each parameter's type, default, range
and description. Filters register themselves with :func:`register_filter`.
"""

from __future__ import annotations

import difflib
import inspect
import math
from numbers import Integral, Real
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from .errors import ParameterError

#: Parameter type names and the Python types a value of that type may have.
PARAMETER_TYPES: dict[str, tuple[type, ...]] = {
    "int": (int,),
    "float": (float, int),
    "bool": (bool,),
    "str": (str,),
    "path": (str, Path),
    "length": (str, int, float),
    "float_list": (list, tuple),
    "int_list": (list, tuple),
    "str_list": (list, tuple),
    "dict": (dict,),
}

#: Layers of a run's :class:`~vmesh.context.Context` a filter may read or write.
LAYERS = (
    "surface",
    "coarse_surface",
    "caps",
    "sdf",
    "skeleton",
    "blocks",
    "mesh",
    "quality",
)


def suggest(name: str, candidates) -> str:
    """Return ``" (did you mean 'x'?)"`` for the closest candidate, or ``""``."""
    close = difflib.get_close_matches(str(name), list(candidates), n=1, cutoff=0.5)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _check_length(text: str, label: str) -> None:
    """Refuse a ``length`` text that ``parse_length`` would refuse when the filter runs: a
    positive number with an optional known unit (none = the input's units)."""
    from .geometry.boundary_layer import LENGTH_UNITS, parse_length

    try:
        parse_length(text, "m", label)
    except ParameterError:
        raise ParameterError(f"{label} = {text!r}: expected a positive length such as 0.05mm "
                             f"(units: {', '.join(LENGTH_UNITS)}; none = the input's units)") from None


@dataclass(frozen=True)
class Parameter:
    """One typed, documented filter parameter.

    Parameters
    ----------
    name : str
        snake_case name, unique within the filter.
    type : str
        One of :data:`PARAMETER_TYPES`.
    default : object
        Default value; ``None`` means "unset / automatic" (``optional`` is then implied).
    description : str
        One or two sentences saying what the parameter does.
    unit : str
        Unit of the value (``"mm"``, ``"× radius"``, ``"faces"``...), if any.
    min, max : float, optional
        Inclusive range for numbers (and list items).
    choices : tuple, optional
        Allowed values for ``str`` parameters.
    multiple_of : int, optional
        ``int`` values must be multiples of this (e.g. 2: even).
    """

    name: str
    type: str
    default: Any
    description: str
    unit: str = ""
    min: float | None = None
    max: float | None = None
    choices: tuple | None = None
    multiple_of: int | None = None

    def __post_init__(self):
        if self.type not in PARAMETER_TYPES:
            raise ValueError(f"parameter {self.name}: unknown type {self.type!r}")

    def validate(self, value: Any, where: str) -> Any:
        """Check ``value`` and return it converted to the parameter's type (the string
        ``"auto"`` sets a non-string parameter whose default is automatic back to it)."""
        if isinstance(value, str) and value == "auto" and self.default is None and self.type != "str":
            value = None
        if value is None:
            if self.default is None:
                return None
            raise ParameterError(f"{where}: parameter '{self.name}' may not be empty")
        label = f"{where}: parameter '{self.name}'"
        allowed = PARAMETER_TYPES[self.type]
        # bool is an int subclass: refuse it where a number is expected
        if self.type == "length" and isinstance(value, Real) and not isinstance(value, bool):
            allowed = Real  # numpy floats and ints too
        if not isinstance(value, allowed) or (self.type in ("int", "float", "length") and isinstance(value, bool)):
            raise ParameterError(f"{label} must be of type {self.type}, got {type(value).__name__} {value!r}")
        if self.type == "length":
            # a numpy number from the Python API: repr(np.float64(0.05)) is 'np.float64(0.05)'
            value = value if isinstance(value, str) else repr(int(value) if isinstance(value, Integral) else float(value))
            if value:
                _check_length(value, label)
        if self.type == "float":
            value = float(value)
            if not math.isfinite(value):
                raise ParameterError(f"{label} must be a finite number, got {value!r}")
        if self.type == "path":
            value = str(value)
        if self.type.endswith("_list"):
            item_type = {"float_list": (float, int), "int_list": (int,), "str_list": (str,)}[self.type]
            if any(not isinstance(v, item_type) or isinstance(v, bool) for v in value):
                raise ParameterError(f"{label} must be a list of {self.type[:-5]}, got {value!r}")
            value = [float(v) if self.type == "float_list" else v for v in value]
        numbers = [value] if self.type in ("int", "float") else (value if self.type in ("int_list", "float_list") else [])
        for v in numbers:
            if self.min is not None and v < self.min:
                raise ParameterError(f"{label} = {v} is below its minimum {self.min}")
            if self.max is not None and v > self.max:
                raise ParameterError(f"{label} = {v} is above its maximum {self.max}")
            if self.multiple_of and v % self.multiple_of:
                raise ParameterError(f"{label} = {v} must be a multiple of {self.multiple_of}" + (" (even)" if self.multiple_of == 2 else ""))
        if self.choices is not None and value not in self.choices:
            raise ParameterError(
                f"{label} = {value!r} is not one of {', '.join(map(repr, self.choices))}"
                + suggest(value, self.choices)
            )
        return value

    def range_text(self) -> str:
        if self.choices is not None:
            return "{" + ", ".join(map(str, self.choices)) + "}"
        if self.min is None and self.max is None:
            return ""
        lo = "-inf" if self.min is None else f"{self.min:g}"
        hi = "inf" if self.max is None else f"{self.max:g}"
        step = ("even" if self.multiple_of == 2 else f"multiple of {self.multiple_of}") if self.multiple_of else ""
        return f"[{lo}, {hi}]" + (f" {step}" if step else "")


@dataclass(frozen=True)
class Filter:
    """A registered filter: a named function over a run's context.

    The function is called as ``function(ctx, **params)`` with every parameter
    validated and filled in. ``reads`` are the context layers it needs, ``optional_reads``
    the ones it uses when present, ``writes`` the ones it produces or changes, and
    ``updates`` those of ``writes`` it only changes when they are present (a chain's
    check does not count them as provided by the filter). ``reads_when`` maps an optional
    layer to the boolean parameter without which the filter never uses it (a cached prefix
    is then not keyed on that layer).
    """

    name: str
    description: str
    function: Callable
    parameters: tuple[Parameter, ...] = ()
    reads: tuple[str, ...] = ()
    optional_reads: tuple[str, ...] = ()
    writes: tuple[str, ...] = ()
    updates: tuple[str, ...] = ()
    category: str = "misc"
    doc: str = ""
    check: Callable | None = None
    reads_when: tuple[tuple[str, str], ...] = ()  # (optional layer, boolean parameter) pairs

    def layers_read(self, params: dict | None = None) -> list[str]:
        """The layers the filter reads with ``params``: ``reads``, then the optional ones
        not switched off by their ``reads_when`` parameter."""
        params, when = params or {}, dict(self.reads_when)
        used = [layer for layer in self.optional_reads if layer not in when or params.get(when[layer], self.parameter(when[layer]).default)]
        return [*self.reads, *used]

    @property
    def parameter_names(self) -> list[str]:
        return [p.name for p in self.parameters]

    def parameter(self, name: str) -> Parameter:
        for p in self.parameters:
            if p.name == name:
                return p
        hint = suggest(name, self.parameter_names) or f" (its parameters: {', '.join(self.parameter_names) or 'none'})"
        raise ParameterError(f"filter '{self.name}' has no parameter '{name}'" + hint)

    def resolve(self, params: dict | None = None) -> dict:
        """Validate ``params`` and return them complete, defaults filled in."""
        params = dict(params or {})
        for key in params:
            self.parameter(key)  # raises with a suggestion
        where = f"filter '{self.name}'"
        resolved = {p.name: p.validate(params.get(p.name, p.default), where) for p in self.parameters}
        if self.check is not None:  # checks across parameters or against outside lists, before any step runs
            resolved = self.check(resolved) or resolved
        return resolved

    def __call__(self, ctx, **params):
        return self.function(ctx, **self.resolve(params))

    def parameter_table(self) -> str:
        """Text listing of the parameters, like pymeshlab's ``print_filter_parameter_list``."""
        lines = [f"{self.name}: {self.description}"]
        if self.doc:
            lines += ["", textwrap.indent(textwrap.fill(self.doc, 88), "  ")]
        lines += [
            "",
            f"  category: {self.category}",
            f"  reads:    {', '.join(self.reads) or '-'}"
            + (f" (optional: {', '.join(self.optional_reads)})" if self.optional_reads else ""),
            f"  writes:   {', '.join(self.writes) or '-'}"
            + (f" (only when present: {', '.join(self.updates)})" if self.updates else ""),
            "",
        ]
        if not self.parameters:
            lines.append("  (no parameters)")
        for p in self.parameters:
            default = "auto" if p.default is None else "'' (not set)" if p.default == "" and p.type == "length" else repr(p.default)
            head = f"  {p.name} : {p.type} = {default}"
            extras = [x for x in (p.range_text(), p.unit and f"unit: {p.unit}") if x]
            if extras:
                head += "   " + "  ".join(extras)
            lines.append(head)
            lines.append(textwrap.indent(textwrap.fill(p.description, 84), "      "))
        return "\n".join(lines)


_REGISTRY: dict[str, Filter] = {}


def register_filter(
    name: str | None = None,
    *,
    description: str,
    parameters=(),
    reads=(),
    optional_reads=(),
    writes=(),
    updates=(),
    category: str = "misc",
    check: Callable | None = None,
    reads_when: dict | None = None,
):
    """Decorator registering ``function(ctx, **params)`` as a filter.

    ``check(params) -> params or None``, if given, runs when a chain is resolved (before
    any step runs) on the validated parameters; it raises for values that no single
    parameter's type or range can catch and may return them normalised.

    Examples
    --------
    >>> @register_filter(description="Scale the input surface.",
    ...                  parameters=[Parameter("factor", "float", 1.0, "Scale factor.", min=0)],
    ...                  reads=("surface",), writes=("surface",))
    ... def scale_surface(ctx, factor):
    ...     ctx.surface = ctx.surface.scaled(factor)
    """

    def wrap(function):
        fname = name or function.__name__
        if fname in _REGISTRY:
            raise ValueError(f"filter '{fname}' is registered twice")
        for layer in (*reads, *optional_reads, *writes):
            if layer not in LAYERS:
                raise ValueError(f"filter '{fname}': unknown layer {layer!r}")
        if not set(updates) <= set(writes) & set(optional_reads):
            raise ValueError(f"filter '{fname}': 'updates' must be layers it writes and optionally reads")
        names = [p.name for p in parameters]
        if not set(reads_when or {}) <= set(optional_reads) or not set((reads_when or {}).values()) <= set(names):
            raise ValueError(f"filter '{fname}': 'reads_when' must map optional layers to its parameters")
        if len(set(names)) != len(names):
            raise ValueError(f"filter '{fname}': duplicate parameter names")
        _check_signature(fname, function, names)
        doc = " ".join((function.__doc__ or "").strip().split("\n\n")[0].split())
        _REGISTRY[fname] = Filter(
            name=fname,
            description=description,
            function=function,
            parameters=tuple(parameters),
            reads=tuple(reads),
            optional_reads=tuple(optional_reads),
            writes=tuple(writes),
            updates=tuple(updates),
            category=category,
            doc=doc if doc != description else "",
            check=check,
            reads_when=tuple((reads_when or {}).items()),
        )
        return function

    return wrap


def _check_signature(name: str, function: Callable, names: list[str]) -> None:
    """The function must take ``ctx`` and then exactly the declared parameters (by keyword):
    a parameter missing from either side would only fail when the filter runs."""
    args = list(inspect.signature(function).parameters.values())
    if not args or args[0].kind not in (args[0].POSITIONAL_ONLY, args[0].POSITIONAL_OR_KEYWORD):
        raise ValueError(f"filter '{name}': the function's first argument must be the context")
    if any(a.kind is a.VAR_KEYWORD for a in args):
        return
    taken = [a.name for a in args[1:] if a.kind in (a.POSITIONAL_OR_KEYWORD, a.KEYWORD_ONLY)]
    undeclared = [a for a in taken if a not in names]
    unused = [n for n in names if n not in taken]
    if undeclared or unused:
        raise ValueError(
            f"filter '{name}': parameters and function signature differ"
            + (f"; declared but not taken: {', '.join(unused)}" if unused else "")
            + (f"; taken but not declared: {', '.join(undeclared)}" if undeclared else "")
        )


def _ensure_loaded():
    from . import filters  # noqa: F401  (importing registers the built-in filters)


def get_filter(name: str) -> Filter:
    """Return the registered filter ``name``; unknown names suggest the closest one."""
    _ensure_loaded()
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ParameterError(f"unknown filter '{name}'" + suggest(name, _REGISTRY)) from None


def filter_list() -> list[str]:
    """Names of all registered filters, in pipeline order of their category."""
    _ensure_loaded()
    return [f.name for f in _sorted_filters()]


def _sorted_filters() -> list[Filter]:
    order = {c: i for i, c in enumerate(CATEGORY_ORDER)}
    return sorted(_REGISTRY.values(), key=lambda f: (order.get(f.category, len(order)), f.name))


CATEGORY_ORDER = (
    "input",
    "preprocessing",
    "implicit surface",
    "skeleton",
    "block structure",
    "meshing",
    "quality",
    "export",
    "misc",
)


def filter_list_text() -> str:
    _ensure_loaded()
    lines, category = [], None
    width = max(len(n) for n in _REGISTRY)
    for f in _sorted_filters():
        if f.category != category:
            category = f.category
            lines.append(f"\n{category}:")
        lines.append(f"  {f.name:<{width}}  {f.description}")
    return "\n".join(lines).lstrip("\n")


def print_filter_list() -> None:
    """Print every filter with its one-line description, grouped by stage."""
    print(filter_list_text())


def print_filter_parameter_list(name: str) -> None:
    """Print the parameters of filter ``name`` (type, default, range, unit, description)."""
    print(get_filter(name).parameter_table())

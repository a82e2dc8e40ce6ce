"""Batch manifests: the rows a batch meshes, from a CSV table or a TOML file with
``[defaults]``, ``[[row]]`` and ``[[sweep]]`` tables (parameter sweeps expanded into rows).

Reading checks everything it can before any row runs (columns, keys, types, sweep
ranges), so a typo fails the batch at once instead of row by row; :mod:`vmesh.batch`
re-exports these names.
"""

from __future__ import annotations

import csv
import io
import itertools
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._toml import tomllib
from .errors import InputError

#: Manifest columns that are not parameter overrides.
RESERVED = ("surface", "skeleton", "name")


@dataclass
class ManifestRow:
    """One mesh to make: input files, output name and parameter overrides."""

    name: str | None
    surface: str
    skeleton: str | None = None
    overrides: dict = field(default_factory=dict)
    where: str = ""  # "row 3" / "sweep 1, row 4": for messages


@dataclass
class Manifest:
    """The rows of a batch; ``chain`` is the chain a TOML manifest names (if any)."""

    rows: list
    path: Path | None = None
    chain: str | None = None
    #: override columns of a CSV header (checked even where every cell is empty)
    columns: list = field(default_factory=list)

    def __len__(self):
        return len(self.rows)

    @property
    def override_columns(self) -> list[str]:
        cols: list[str] = []
        for r in self.rows:
            cols += [k for k in r.overrides if k not in cols]
        return cols


def read_manifest(path) -> Manifest:
    """Read a CSV or TOML manifest.

    CSV: a header with ``surface`` (required), ``skeleton`` and ``name`` (optional) and
    one column per override named ``filter.param``; cells are parsed like ``--set``
    values (numbers, booleans, TOML lists), an empty cell leaves the parameter alone,
    lines starting with ``#`` are comments.

    TOML: ``chain = "..."`` (optional), a ``[defaults]`` table applied to every row,
    ``[[row]]`` tables (one row each) and ``[[sweep]]`` tables, each expanding to many
    rows (:func:`expand_sweep`).

    Relative paths are relative to the manifest's folder.

    Raises
    ------
    InputError
        ``<manifest>: <problem>`` for a missing, empty or malformed manifest.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("manifest not found" if not path.exists() else "manifest is not a file", path)
    if path.stat().st_size == 0:
        raise InputError("manifest is empty", path)
    try:
        text = path.read_text(encoding="utf-8-sig")  # spreadsheets save a byte-order mark
    except UnicodeDecodeError:
        raise InputError("manifest is not a text file", path) from None
    suffix = path.suffix.lower()
    if suffix == ".toml":
        manifest = _read_toml_manifest(text, path)
    elif suffix in (".csv", ".tsv", ".txt"):
        manifest = _read_csv_manifest(text, path, delimiter="\t" if suffix == ".tsv" else ",")
    else:
        raise InputError(f"unknown manifest format '{path.suffix}' (use .csv or .toml)", path)
    if not manifest.rows:
        raise InputError("manifest has no rows", path)
    base = path.resolve().parent
    for r in manifest.rows:
        r.surface = _resolve(r.surface, base)
        r.skeleton = _resolve(r.skeleton, base) if r.skeleton else None
    manifest.path = path
    return manifest


def manifest_from_rows(rows) -> Manifest:
    """A manifest from a list of dicts (keys as the columns of a CSV manifest, values
    typed); relative paths are taken from the working directory."""
    manifest = Manifest([_make_row(dict(d), None, f"row {k}") for k, d in enumerate(rows, start=1)])
    for r in manifest.rows:
        r.surface = _resolve(r.surface, Path.cwd())
        r.skeleton = _resolve(r.skeleton, Path.cwd()) if r.skeleton else None
    return manifest


def _resolve(p, base: Path) -> str:
    p = Path(os.path.expanduser(str(p)))
    return str(p if p.is_absolute() else base / p)


def _read_csv_manifest(text: str, path: Path, delimiter: str = ",") -> Manifest:
    from .cli import parse_value

    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise InputError("manifest has no header line", path)
    reader = csv.reader(io.StringIO("\n".join(lines)), delimiter=delimiter)
    header = [h.strip() for h in next(reader)]
    if "surface" not in header:
        raise InputError(f"missing column 'surface' (columns: {', '.join(header)})", path)
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise InputError(f"duplicate column(s) {', '.join(dup)}", path)
    for h in header:
        if h not in RESERVED and "." not in h:
            raise InputError(f"unknown column '{h}' (columns are surface, skeleton, name and filter.param overrides)", path)
    rows = []
    for k, cells in enumerate(reader, start=1):
        if len(cells) > len(header):
            raise InputError(f"row {k} has {len(cells)} cells, the header {len(header)}", path)
        cells = [c.strip() for c in cells] + [""] * (len(header) - len(cells))
        d = dict(zip(header, cells))
        if not d["surface"]:
            raise InputError(f"row {k}: empty surface", path)
        overrides = {h: parse_value(v) for h, v in d.items() if h not in RESERVED and v != ""}
        rows.append(ManifestRow(d.get("name") or None, d["surface"], d.get("skeleton") or None, overrides, f"row {k}"))
    return Manifest(rows, columns=[h for h in header if h not in RESERVED])


def _flatten(table: dict, path: Path, where: str, keep=RESERVED) -> dict:
    """``{"mesh_transfinite": {"order": 2}}`` (TOML dotted keys) -> ``{"mesh_transfinite.order": 2}``."""
    out = {}
    for k, v in table.items():
        if k in keep or "." in k:
            out[k] = v
        elif isinstance(v, dict):
            for pk, pv in v.items():
                out[f"{k}.{pk}"] = pv
        else:
            raise InputError(f"{where}: unknown key '{k}' (keys are surface, skeleton, name and filter.param overrides)", path)
    return out


def _read_toml_manifest(text: str, path: Path) -> Manifest:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not valid TOML ({exc})", path) from None
    unknown = set(data) - {"chain", "defaults", "row", "sweep"}
    if unknown:
        raise InputError(f"unknown top-level key(s) {', '.join(sorted(unknown))} (use chain, [defaults], [[row]], [[sweep]])", path)
    chain = data.get("chain")
    if chain is not None and not isinstance(chain, str):
        raise InputError("'chain' must be a preset name or file path", path)
    defaults = _flatten(data.get("defaults", {}), path, "[defaults]")
    if "name" in defaults:
        raise InputError("[defaults] cannot set a name", path)
    rows = []
    for k, table in enumerate(_tables(data.get("row", []), path, "row"), start=1):
        rows.append(_make_row({**defaults, **_flatten(table, path, f"row {k}")}, path, f"row {k}"))
    for k, table in enumerate(_tables(data.get("sweep", []), path, "sweep"), start=1):
        rows += expand_sweep(table, defaults, path, f"sweep {k}")
    if chain is not None and not Path(chain).is_absolute() and (path.resolve().parent / chain).is_file():
        chain = str(path.resolve().parent / chain)
    return Manifest(rows, chain=chain)


def _tables(value, path, key):
    if isinstance(value, dict):
        value = [value]
    if not isinstance(value, list) or not all(isinstance(t, dict) for t in value):
        raise InputError(f"'{key}' must be an array of tables ([[{key}]])", path)
    return value


def _make_row(d: dict, path: Path, where: str) -> ManifestRow:
    if not d.get("surface"):
        raise InputError(f"{where}: no surface", path)
    for key in RESERVED:
        if key in d and d[key] is not None and not isinstance(d[key], str):
            raise InputError(f"{where}: '{key}' must be a string, got {d[key]!r}", path)
    overrides = {k: v for k, v in d.items() if k not in RESERVED}
    return ManifestRow(d.get("name"), d["surface"], d.get("skeleton"), overrides, where)


def sweep_values(spec, path: Path | None = None, where: str = "") -> list:
    """The values of one sweep axis.

    A list is taken as it is; a table is a range:

    * ``{values = [...]}``
    * ``{start = a, stop = b, num = n}``: ``n`` evenly spaced values, both ends included
      (add ``log = true`` for geometric spacing);
    * ``{start = a, stop = b, step = h}``: ``a, a + h, ...`` up to and including ``b``
      (integers stay integers).
    """
    if isinstance(spec, list):
        values = spec
    elif isinstance(spec, dict):
        keys = set(spec)
        if keys == {"values"}:
            values = spec["values"]
        elif {"start", "stop"} <= keys and keys <= {"start", "stop", "num", "step", "log"} and (("num" in keys) != ("step" in keys)):
            a, b = spec["start"], spec["stop"]
            if not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in (a, b)):
                raise InputError(f"{where}: start and stop must be numbers", path)
            if "num" in keys:
                n = spec["num"]
                if not isinstance(n, int) or n < 1:
                    raise InputError(f"{where}: num must be a positive integer", path)
                if spec.get("log"):
                    if a <= 0 or b <= 0:
                        raise InputError(f"{where}: a log range needs positive start and stop", path)
                    values = np.geomspace(a, b, n).tolist()
                else:
                    values = np.linspace(a, b, n).tolist()
                values = [round(v, 12) for v in values]  # 0.1 * 3 prints as 0.3
            else:
                h = spec["step"]
                if not isinstance(h, (int, float)) or isinstance(h, bool) or h == 0 or (b - a) / h < 0:
                    raise InputError(f"{where}: step must be a non-zero number going from start towards stop", path)
                n = int(np.floor((b - a) / h + 1e-9)) + 1
                values = [a + i * h for i in range(n)]
                if not all(isinstance(x, int) for x in (a, b, h)):
                    values = [round(float(v), 12) for v in values]
        else:
            raise InputError(f"{where}: a range is {{start, stop, num}} or {{start, stop, step}} (or {{values = [...]}}), got {sorted(keys)}", path)
    else:
        raise InputError(f"{where}: a sweep axis is a list or a range table, got {spec!r}", path)
    if not values:
        raise InputError(f"{where}: no values", path)
    return list(values)


def expand_sweep(table: dict, defaults: dict | None = None, path: Path | None = None, where: str = "sweep") -> list[ManifestRow]:
    """Rows of one ``[[sweep]]`` table.

    Keys: ``surface``, ``skeleton``, ``name`` (a template: ``{filter.param}``, ``{i}``
    the 1-based row number in the sweep, ``{stem}`` the surface file's stem), fixed
    ``filter.param`` values, and the sweep axes in ``[sweep.product]`` (every
    combination) and ``[sweep.zip]`` (axes of equal length varied together). An axis is
    a list or a range (:func:`sweep_values`); ``surface`` and ``skeleton`` may be axes
    too. The product's last axis varies fastest.
    """
    table = dict(table)
    product = _flatten(table.pop("product", {}), path, f"{where}.product")
    zipped = _flatten(table.pop("zip", {}), path, f"{where}.zip")
    fixed = {**(defaults or {}), **_flatten(table, path, where)}
    both = set(product) & set(zipped)
    if both:
        raise InputError(f"{where}: {', '.join(sorted(both))} in both product and zip", path)
    axes = [(k, sweep_values(v, path, f"{where}.product.{k}")) for k, v in product.items()]
    zip_axes = [(k, sweep_values(v, path, f"{where}.zip.{k}")) for k, v in zipped.items()]
    if zip_axes and len({len(v) for _, v in zip_axes}) > 1:
        raise InputError(f"{where}: the zip axes have different lengths ({', '.join(f'{k}: {len(v)}' for k, v in zip_axes)})", path)
    zip_rows = [dict(zip([k for k, _ in zip_axes], vals)) for vals in zip(*[v for _, v in zip_axes])] if zip_axes else [{}]
    template = fixed.pop("name", None)
    rows = []
    combos = itertools.product(zip_rows, *[v for _, v in axes]) if axes else ((z,) for z in zip_rows)
    for i, combo in enumerate(combos, start=1):
        d = {**fixed, **combo[0], **{k: v for (k, _), v in zip(axes, combo[1:])}}
        if template is not None:
            d["name"] = _fill_name(template, d, i, path, where)
        rows.append(_make_row(d, path, f"{where}, row {i}"))
    return rows


def _fill_name(template: str, d: dict, i: int, path, where: str) -> str:
    def value(m):
        key = m.group(1)
        if key == "i":
            return str(i)
        if key == "stem":
            return Path(str(d.get("surface", ""))).stem
        if key not in d:
            raise InputError(f"{where}: name template '{template}' uses '{{{key}}}', which the sweep does not set", path)
        v = d[key]
        return f"{v:g}" if isinstance(v, float) else str(v)

    return re.sub(r"\{([^{}]+)\}", value, template)

"""The HDF5 project: a machine, its plan, the measured lines as imported and as corrected, and the
results computed from them.

Layout (format version 1; DESIGN.md "HDF5 project")::

    /                          attrs format_version (1), creator ("volucal <version>"),
                               created, modified (ISO 8601 UTC)
    /machine                   attrs name, chain, axes ("XYZ"), stroke_mm (3×2), tool_offset_mm,
                               reference_mm, screw_lead_json
    /plan                      attrs path, uncertainty_json; dataset toml (the plan's text)
    /measurements/<line>       attrs: the LineSpec (quantity, start_mm, direction, reflector_mm,
                               sensitive, file, deviation_unit, sign, env_corrected, reader_json)
                               and provenance (source_file, format, raw_unit, sign_convention,
                               corrections_json, notes_json, imported)
        raw/                   the values exactly as the file gave them (file unit and sign)
        corrected/             volucal's values (µm or µrad, measured − nominal)
                               each: targets_mm, deviations (attr unit), run_direction, times_s,
                               optional air_temp_c, material_temp_c; attrs start_time, unit,
                               environment values, metadata_json, optional origin_mm (the
                               file's position of its first target)
        source                 the source file's bytes (uint8), attrs filename, sha256
        capture/               (dynamic captures) time_s, deviation, optional position_mm
    /identifications/<name>, /loops/<name>, /sensitivity/<name>, /compensation/<name>
                               result trees: dicts → groups, arrays and lists → datasets,
                               scalars and strings → attributes; a key ending in _um, _urad, _mm,
                               _s or _c carries its unit as an attribute (``unit`` on a dataset,
                               ``volucal_unit:<key>`` for a scalar)

Metadata and numeric datasets carry checksums (HDF5 ``libver="latest"`` and Fletcher-32), so a
damaged file is reported as damaged rather than read as garbage. Saves are atomic: the project is
written to ``<path>.tmp-<pid>``, flushed and fsynced, renamed
over the old file with ``os.replace`` and the folder fsynced, all under a :class:`ProjectLock`.
A reader therefore only ever sees a complete old or a complete new file. Older format versions
load through :data:`MIGRATIONS`.

Nothing saved is lost to another writer: a command that changes a project holds the
:class:`ProjectLock` from reading to saving (:mod:`.project_lock`), and :meth:`Project.save`
refuses (:class:`ProjectChangedError`) to overwrite the file it was opened from when that file
changed since. A write-protected project is not overwritten, and a save keeps the old file's
permissions. Names (lines, results, keys) are printable text: HDF5 would cut a name at a NUL.
Opening refuses files that would make volucal read beyond them (links, external or virtual
data) or allocate far more than they hold (:mod:`.project_checks`).
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from .errors import (
    AXIS_ERROR_IDS,
    SQUARENESS_IDS,
    ErrorFunction,
    ErrorModel,
    basis_from_description,
)
from .io.plan import session_order
from .machine import AXES, Machine
from .measurement import Environment, Line, LineData, LineSpec, Measurement, Plan
from .names import check_name
from .project_checks import check_structure
from .project_lock import ProjectLock, recover, temporary_path
from .userror import UserError

__all__ = [
    "FORMAT_VERSION",
    "MIGRATIONS",
    "Project",
    "ProjectChangedError",
    "ProjectLock",
    "StoredLine",
    "error_model_from_tree",
    "error_model_to_tree",
    "group_to_tree",
    "tree_to_group",
]

FORMAT_VERSION = 1
# "report": what the calibration report states that the measurement does not (certificate
# fields, the user's ISO 230-2 tolerances per axis), written by the workbench's report dialog.
RESULT_KINDS = ("identifications", "loops", "sensitivity", "compensation", "thermal", "report")
UNIT_SUFFIXES = {"_um": "um", "_urad": "urad", "_mm": "mm", "_s": "s", "_c": "degC"}
_RESERVED = "volucal_"


# --------------------------------------------------------------------------------------------
# An HDF5 file as plain data (what migrations transform)
# --------------------------------------------------------------------------------------------


@dataclass
class Dataset:
    value: np.ndarray
    attrs: dict[str, Any] = field(default_factory=dict)


@dataclass
class Group:
    attrs: dict[str, Any] = field(default_factory=dict)
    children: dict[str, Group | Dataset] = field(default_factory=dict)


#: Upgrades a document of format version n to n + 1; old loaders are never deleted.
MIGRATIONS: dict[int, Callable[[Group], Group]] = {}


def _attr_value(value: Any) -> Any:
    if isinstance(value, h5py.Empty):
        return None
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.generic):
        return value.item()
    return value


def _read_group(group: h5py.Group) -> Group:
    out = Group({k: _attr_value(v) for k, v in group.attrs.items()})
    for name, item in group.items():
        if isinstance(item, h5py.Group):
            out.children[name] = _read_group(item)
        else:
            if h5py.check_string_dtype(item.dtype) is not None:
                value = np.asarray(item.asstr()[()], dtype=object)
            else:
                value = np.asarray(item[()])
            out.children[name] = Dataset(value, {k: _attr_value(v) for k, v in item.attrs.items()})
    return out


def _no_nul(value: Any, where: str) -> None:
    """HDF5 strings end at a NUL: refuse one rather than store a truncated value."""
    texts = (
        [value]
        if isinstance(value, str)
        else (
            value.ravel().tolist()
            if isinstance(value, np.ndarray) and value.dtype.kind in "OU"
            else []
        )
    )
    if any(isinstance(t, str) and "\0" in t for t in texts):
        raise UserError(
            f"{where}: a text holds a NUL character, which HDF5 cannot store; remove it"
        )


def _write_group(target: h5py.Group, group: Group) -> None:
    for key, value in group.attrs.items():
        _no_nul(value, f"{target.name} attribute {key!r}")
        target.attrs[key] = h5py.Empty("f8") if value is None else value
    for name, child in group.children.items():
        check_name(name, f"HDF5 name in {target.name}")
        if isinstance(child, Group):
            _write_group(target.create_group(name, track_order=True), child)
            continue
        value = child.value
        _no_nul(value, f"{target.name}/{name}")
        if value.dtype.kind in "OUS":
            data = target.create_dataset(name, data=value.astype(object), dtype=h5py.string_dtype())
        else:
            # Fletcher-32 checksums make damaged values an error instead of silent garbage
            checked = value.ndim > 0 and value.size > 0
            data = target.create_dataset(name, data=value, fletcher32=checked)
        for key, attr in child.attrs.items():
            data.attrs[key] = h5py.Empty("f8") if attr is None else attr


# --------------------------------------------------------------------------------------------
# Result trees
# --------------------------------------------------------------------------------------------


def _unit_of(key: str) -> str | None:
    for suffix, unit in UNIT_SUFFIXES.items():
        if key.endswith(suffix):
            return unit
    return None


def _is_scalar(value: Any) -> bool:
    return value is None or isinstance(value, bool | int | float | str | np.generic)


def tree_to_group(tree: Mapping[str, Any]) -> Group:
    """A result tree as a group (module notes give the mapping); raises TypeError for values it
    cannot store and ValueError for keys HDF5 cannot name."""
    group = Group({f"{_RESERVED}type": "dict"})
    for key, value in tree.items():
        if (
            not isinstance(key, str)
            or not key
            or "/" in key
            or key.startswith(".")
            or key.startswith(_RESERVED)
            or not key.isprintable()
        ):
            raise ValueError(
                f"result key {key!r}: use a non-empty printable string without "
                f"'/', not starting with '.' or {_RESERVED!r}"
            )
        _store(group, key, value)
    return group


def _store(group: Group, key: str, value: Any) -> None:
    unit = _unit_of(key)
    if _is_scalar(value):
        group.attrs[key] = value
        if unit:
            group.attrs[f"{_RESERVED}unit:{key}"] = unit
        return
    if isinstance(value, Mapping):
        group.children[key] = tree_to_group(value)
        return
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "biufcUS?":
            raise TypeError(f"result {key!r}: arrays of {value.dtype} cannot be stored")
        attrs = {f"{_RESERVED}type": "array"}
        if unit:
            attrs["unit"] = unit
        group.children[key] = Dataset(value, attrs)
        return
    if isinstance(value, list | tuple):
        items = list(value)
        numbers = items and all(
            isinstance(v, bool | int | float | np.number | np.bool_) for v in items
        )
        texts = items and all(isinstance(v, str) for v in items)
        if numbers or texts:
            kinds = {
                "bool"
                if isinstance(v, bool | np.bool_)
                else "int"
                if isinstance(v, int | np.integer)
                else "float"
                for v in items
            }
            element = "str" if texts else kinds.pop() if len(kinds) == 1 else "float"
            dtype = {"bool": bool, "int": np.int64, "float": float, "str": object}[element]
            attrs = {f"{_RESERVED}type": "list", f"{_RESERVED}element": element}
            if unit:
                attrs["unit"] = unit
            group.children[key] = Dataset(np.asarray(items, dtype=dtype), attrs)
            return
        inner = Group({f"{_RESERVED}type": "list", f"{_RESERVED}length": len(items)})
        for index, item in enumerate(items):
            _store(inner, str(index), item)
        group.children[key] = inner
        return
    raise TypeError(f"result {key!r}: values of type {type(value).__name__} cannot be stored")


def group_to_tree(group: Group) -> Any:
    """Inverse of :func:`tree_to_group`."""
    kind = group.attrs.get(f"{_RESERVED}type", "dict")
    entries: dict[str, Any] = {k: v for k, v in group.attrs.items() if not k.startswith(_RESERVED)}
    for name, child in group.children.items():
        entries[name] = group_to_tree(child) if isinstance(child, Group) else _dataset_value(child)
    if kind == "list":
        return [entries[str(i)] for i in range(int(group.attrs[f"{_RESERVED}length"]))]
    return entries


def _dataset_value(data: Dataset) -> Any:
    kind = data.attrs.get(f"{_RESERVED}type", "array")
    value = data.value
    if kind == "list":
        if data.attrs.get(f"{_RESERVED}element") == "str":
            return [str(v) for v in value.tolist()]
        return value.tolist()
    if value.dtype == object:
        return np.asarray(value.tolist(), dtype=str)
    return value


# --------------------------------------------------------------------------------------------
# Error models
# --------------------------------------------------------------------------------------------


def error_model_to_tree(model: ErrorModel) -> dict[str, Any]:
    """``{"functions": {id: {"basis": describe(), "coefficients": array}},
    "squareness_urad": {id: value}}``."""
    return {
        "functions": {
            eid: {"basis": dict(f.basis.describe()), "coefficients": np.asarray(f.coefficients)}
            for eid, f in model.functions.items()
        },
        "squareness_urad": {k: float(v) for k, v in model.squareness_urad.items()},
    }


def error_model_from_tree(tree: Mapping[str, Any], machine: Machine) -> ErrorModel:
    """Inverse of :func:`error_model_to_tree`."""
    functions = {}
    for eid in AXIS_ERROR_IDS:
        entry = tree["functions"][eid]
        basis = basis_from_description(entry["basis"])
        functions[eid] = ErrorFunction(eid, basis, np.asarray(entry["coefficients"], dtype=float))
    square = {k: float(tree["squareness_urad"][k]) for k in SQUARENESS_IDS}
    return ErrorModel(machine, functions, square)


# --------------------------------------------------------------------------------------------
# The project
# --------------------------------------------------------------------------------------------


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def _creator() -> str:
    from volucal import __version__

    return f"volucal {__version__}"


@dataclass(eq=False)
class StoredLine:
    """One line of a project: its specification, values and where they came from."""

    spec: LineSpec
    corrected: LineData
    raw: LineData
    raw_unit: str
    source_bytes: bytes
    provenance: dict[str, Any]
    capture: dict[str, np.ndarray] | None = None


class Project:
    """A volucal project in memory, loaded from and saved to HDF5 (module notes)."""

    def __init__(self, machine: Machine | None = None) -> None:
        self.machine = machine
        self.plan_toml: str | None = None
        self.plan_path: str | None = None
        self.uncertainty: dict[str, float] = {}
        self.lines: dict[str, StoredLine] = {}
        self._results: dict[str, dict[str, Group]] = {kind: {} for kind in RESULT_KINDS}
        self.grids: dict[str, Group] = {}  # /grids/<name>: volucal.core.grid2d_store
        self.created = _now()
        self.modified = self.created
        self.creator = _creator()
        self.path: Path | None = None
        self._fingerprint: tuple[int, ...] | None = None

    @classmethod
    def create(cls, machine: Machine | None = None) -> Project:
        return cls(machine)

    # ---- lines ---------------------------------------------------------------------------

    def add_lines(
        self,
        plan: Plan,
        measurement: Measurement,
        source_bytes: Mapping[str, bytes],
        raw: Mapping[str, LineData],
        *,
        provenance: Mapping[str, Mapping[str, Any]] | None = None,
        captures: Mapping[str, Mapping[str, np.ndarray]] | None = None,
        replace: bool = False,
    ) -> None:
        """Add the lines of ``measurement`` (corrected values), with the file values ``raw`` and
        the files' bytes, keyed by line name. ``provenance`` may give per line the keys
        ``raw_unit``, ``source_file``, ``format``, ``sign_convention``, ``corrections``,
        ``notes``. A line whose name is already in the project raises UserError unless
        ``replace``.
        """
        for line in measurement.lines:
            _check_line_name(line.name)
        if self.machine is not None and self.machine != plan.machine:
            raise UserError(
                f"the plan's machine ({plan.machine.name!r}) differs from the project's "
                f"({self.machine.name!r}); use a new project for another machine"
            )
        clashes = [line.name for line in measurement.lines if line.name in self.lines]
        if clashes and not replace:
            raise UserError(
                f"the project already has line(s) {', '.join(clashes)}; rename them in the plan "
                "or replace them (volucal import --replace)"
            )
        self.machine = plan.machine
        if plan.path is not None and Path(plan.path).is_file():
            self.plan_toml = Path(plan.path).read_text(encoding="utf-8", errors="replace")
            self.plan_path = str(plan.path)
        self.uncertainty.update(plan.uncertainty)
        for line in measurement.lines:
            info = dict((provenance or {}).get(line.name, {}))
            unit = str(info.get("raw_unit", line.spec.deviation_unit))
            info.setdefault("source_file", Path(line.spec.file or "").name)
            info["imported"] = _now()
            self.lines[line.name] = StoredLine(
                spec=line.spec,
                corrected=line.data,
                raw=raw[line.name],
                raw_unit=unit,
                source_bytes=bytes(source_bytes[line.name]),
                provenance=info,
                capture=dict(captures[line.name]) if captures and line.name in captures else None,
            )

    def measurement(self) -> Measurement:
        """The corrected lines as a :class:`Measurement`, in session order."""
        if self.machine is None:
            raise UserError("the project has no machine yet: import a plan first")
        lines = session_order([Line(s.spec, s.corrected) for s in self.lines.values()])
        return Measurement(self.machine, tuple(lines), dict(self.uncertainty))

    def plan(self) -> Plan:
        """The plan the lines were imported with (specifications, machine, uncertainty)."""
        if self.machine is None:
            raise UserError("the project has no machine yet: import a plan first")
        path = Path(self.plan_path) if self.plan_path else None
        return Plan(
            self.machine, tuple(s.spec for s in self.lines.values()), path, dict(self.uncertainty)
        )

    def _line(self, name: str) -> StoredLine:
        if name not in self.lines:
            raise KeyError(f"no line {name!r} in the project")
        return self.lines[name]

    def raw_bytes(self, name: str) -> bytes:
        """The bytes of the file line ``name`` was imported from."""
        return self._line(name).source_bytes

    def raw_data(self, name: str) -> LineData:
        """The values exactly as the file gave them (unit ``provenance(name)["raw_unit"]``)."""
        return self._line(name).raw

    def provenance(self, name: str) -> dict[str, Any]:
        line = self._line(name)
        return {**line.provenance, "raw_unit": line.raw_unit}

    # ---- results -------------------------------------------------------------------------

    @staticmethod
    def _check_result(kind: str, name: str) -> None:
        if kind not in RESULT_KINDS:
            raise ValueError(f"result kind {kind!r} is not one of {', '.join(RESULT_KINDS)}")
        if (
            not isinstance(name, str)
            or not name
            or "/" in name
            or name.startswith(".")
            or not name.isprintable()
        ):
            raise ValueError(
                f"result name {name!r}: use a non-empty printable name without "
                "'/', not starting with '.'"
            )

    def put_result(self, kind: str, name: str, tree: Mapping[str, Any]) -> None:
        """Store a result tree (replacing one of the same kind and name)."""
        self._check_result(kind, name)
        self._results[kind][name] = tree_to_group(tree)

    def result(self, kind: str, name: str) -> dict[str, Any]:
        self._check_result(kind, name)
        if name not in self._results[kind]:
            raise KeyError(f"no {kind} result {name!r} in the project")
        return group_to_tree(self._results[kind][name])  # type: ignore[no-any-return]

    def results(self, kind: str) -> list[str]:
        self._check_result(kind, "x")
        return list(self._results[kind])

    # ---- files ---------------------------------------------------------------------------

    @classmethod
    def open(cls, path: str | Path) -> Project:
        """Load a project file.

        Clears a stale lock and the temporary files of killed saves first (when no other process
        holds the lock), and refuses files that would make volucal read beyond them or allocate
        far more than they hold (:mod:`.project_checks`).

        Raises
        ------
        UserError
            For a missing, damaged or non-volucal file, one written by a newer volucal, or one
            holding links, external or virtual data or oversized datasets.
        """
        path = Path(path)
        if not path.is_file():
            raise UserError(f"{path}: no such project file")
        recover(path)
        if not h5py.is_hdf5(path):
            raise UserError(f"{path}: not an HDF5 file; it is damaged or not a volucal project")
        # A save renames a new file over this one: read until the file did not change under us,
        # so the fingerprint kept for the next save is that of the file read.
        for _ in range(5):
            before = _fingerprint(path)
            version, document = cls._read_file(path)
            if _fingerprint(path) == before:
                break
        for step in range(version, FORMAT_VERSION):
            document = MIGRATIONS[step](document)
        try:
            project = cls._from_document(document)
        except (KeyError, ValueError, TypeError, IndexError, AttributeError) as exc:
            raise UserError(
                f"{path}: the project file is damaged or incomplete ({exc!r})"
            ) from None
        project.path = path
        project._fingerprint = before
        return project

    @staticmethod
    def _read_file(path: Path) -> tuple[int, Group]:
        try:
            with h5py.File(path, "r") as handle:
                version = _format_version(handle, path)
                check_structure(handle, path)
                return version, _read_group(handle)
        except UserError:
            raise
        except Exception as exc:  # h5py reports damage as OSError, KeyError, RuntimeError…
            raise UserError(
                f"{path}: the project file is damaged ({exc}); restore a backup or "
                "import the plan again"
            ) from None

    def save(self, path: str | Path | None = None) -> Path:
        """Write the project atomically (module notes) under a :class:`ProjectLock`.

        Raises
        ------
        ProjectChangedError
            When the file this project was opened from was changed by someone else since:
            saving would lose that change.
        UserError
            When the file is write-protected or its folder cannot be written.
        """
        target = Path(path) if path is not None else self.path
        if target is None:
            raise ValueError("save(path): this project has no file yet")
        with ProjectLock(target), _SAVE_GUARD:
            existing = _stat_or_none(target)
            if existing is not None:
                self._check_unchanged(target)
                _check_writable(target, existing)
            temporary = temporary_path(target)
            self.modified = _now()
            document = self._to_document()
            try:
                with h5py.File(temporary, "w", track_order=True, libver="latest") as handle:
                    _write_group(handle, document)
                if existing is not None:
                    _copy_mode(existing, temporary)
                _fsync_path(temporary)
                os.replace(temporary, target)
                _fsync_path(target.parent if str(target.parent) else Path("."))
            except OSError as exc:
                temporary.unlink(missing_ok=True)
                raise UserError(
                    f"{target}: cannot save the project ({exc.strerror or exc}); "
                    "check that its folder is writable and has room"
                ) from None
            except BaseException:
                temporary.unlink(missing_ok=True)
                raise
            self._fingerprint = _fingerprint(target)
        self.path = target
        return target

    def _check_unchanged(self, target: Path) -> None:
        """Refuse to save over the file this project came from when someone changed it since."""
        if self.path is None or self._fingerprint is None:
            return
        try:
            same = os.path.samefile(self.path, target) or self.path.resolve() == target.resolve()
        except OSError:
            same = self.path.resolve() == target.resolve()
        if same and _fingerprint(target) != self._fingerprint:
            raise ProjectChangedError(
                f"{target} was changed by another program after this project was opened from "
                "it; saving now would lose that change. Open the project again and redo this "
                "step (nothing was written)"
            )

    # ---- documents -----------------------------------------------------------------------

    def _to_document(self) -> Group:
        root = Group(
            {
                "format_version": FORMAT_VERSION,
                "creator": self.creator,
                "created": self.created,
                "modified": self.modified,
            }
        )
        if self.machine is not None:
            root.children["machine"] = _machine_group(self.machine)
        plan = Group(
            {"path": self.plan_path or "", "uncertainty_json": json.dumps(self.uncertainty)}
        )
        if self.plan_toml is not None:
            plan.children["toml"] = Dataset(np.array(self.plan_toml, dtype=object))
        root.children["plan"] = plan
        measurements = Group()
        for name, line in self.lines.items():
            measurements.children[name] = _line_group(line)
        root.children["measurements"] = measurements
        for kind in RESULT_KINDS:
            root.children[kind] = Group(children=dict(self._results[kind]))  # type: ignore[arg-type]
        if self.grids:
            root.children["grids"] = Group(children=dict(self.grids))  # type: ignore[arg-type]
        return root

    @classmethod
    def _from_document(cls, root: Group) -> Project:
        project = cls(
            _machine_from(root.children["machine"]) if "machine" in root.children else None
        )
        project.created = str(root.attrs.get("created", ""))
        project.modified = str(root.attrs.get("modified", ""))
        project.creator = str(root.attrs.get("creator", ""))
        plan = root.children["plan"]
        assert isinstance(plan, Group)
        project.plan_path = str(plan.attrs.get("path", "")) or None
        project.uncertainty = {
            k: float(v) for k, v in json.loads(plan.attrs.get("uncertainty_json", "{}")).items()
        }
        if "toml" in plan.children:
            toml = plan.children["toml"]
            assert isinstance(toml, Dataset)
            project.plan_toml = str(toml.value.item())
        measurements = root.children["measurements"]
        assert isinstance(measurements, Group)
        for name, group in measurements.children.items():
            assert isinstance(group, Group)
            project.lines[name] = _line_from(name, group)
        for kind in RESULT_KINDS:
            results = root.children.get(kind, Group())
            assert isinstance(results, Group)
            for name, tree in results.children.items():
                assert isinstance(tree, Group)
                project._results[kind][name] = tree
        grids = root.children.get("grids")
        project.grids = dict(grids.children) if isinstance(grids, Group) else {}  # type: ignore[arg-type]
        return project


_SAVE_GUARD = threading.Lock()


def _check_line_name(name: object) -> str:
    """A line name names an HDF5 group: printable, no '/', not starting with '.'."""
    text = check_name(name, "line name")
    if "/" in text or text.startswith("."):
        raise UserError(
            f"line name {text!r}: a name cannot contain '/' or start with '.' (it "
            "names a group in the project file)"
        )
    return text


class ProjectChangedError(UserError):
    """The project file changed on disk since it was opened; saving would lose that change."""


def _format_version(handle: h5py.File, path: Path) -> int:
    version = handle.attrs.get("format_version")
    creator = handle.attrs.get("creator")
    if version is None or creator is None:
        raise UserError(
            f"{path}: an HDF5 file but not a volucal project (no format_version/creator stamp)"
        )
    value = _attr_value(version)
    whole = isinstance(value, int) and not isinstance(value, bool)
    if isinstance(value, float) and value.is_integer():
        value, whole = int(value), True
    if not whole or value < 1:
        raise UserError(
            f"{path}: format_version {value!r} is not a volucal format version (a whole number "
            f"from 1 to {FORMAT_VERSION}); the file is damaged or was not written by volucal"
        )
    if value > FORMAT_VERSION:
        raise UserError(
            f"{path}: written by a newer volucal ({_attr_value(creator)}, format "
            f"{value}); this volucal reads formats up to {FORMAT_VERSION}: update volucal"
        )
    return int(value)


def _stat_or_none(path: Path) -> os.stat_result | None:
    try:
        return os.stat(path)
    except FileNotFoundError:
        return None


def _fingerprint(path: Path) -> tuple[int, ...] | None:
    """Identity and content stamp of a file: a save renames a new file into place, so the inode
    changes; the size and modification time catch writes in place by other programs."""
    info = _stat_or_none(path)
    if info is None:
        return None
    return (info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns)


def _check_writable(target: Path, info: os.stat_result) -> None:
    # The write bits, not os.access: root may write anything, but a project someone made
    # read-only (chmod 444) is meant to stay as it is.
    if not info.st_mode & 0o222 or not os.access(target, os.W_OK):
        raise UserError(
            f"{target} is write-protected (mode {stat.S_IMODE(info.st_mode):04o}); volucal does "
            f"not overwrite it. Make it writable (chmod u+w {target}) or save under another name"
        )


def _copy_mode(existing: os.stat_result, temporary: Path) -> None:
    """Give the new file the old one's permissions (and owner and group where allowed)."""
    os.chmod(temporary, stat.S_IMODE(existing.st_mode))
    if hasattr(os, "chown"):
        current = os.stat(temporary)
        if (current.st_uid, current.st_gid) != (existing.st_uid, existing.st_gid):
            try:
                os.chown(temporary, existing.st_uid, existing.st_gid)
            except OSError:
                pass  # only root may give a file away; the mode is kept regardless


def _fsync_path(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _machine_group(machine: Machine) -> Group:
    return Group(
        {
            "name": machine.name,
            "chain": machine.chain,
            "axes": "".join(AXES),
            "stroke_mm": np.array([machine.stroke(a) for a in AXES], dtype=float),
            "tool_offset_mm": np.array(machine.tool_offset_mm, dtype=float),
            "reference_mm": np.array(machine.reference_mm, dtype=float),
            "screw_lead_json": json.dumps(dict(machine.screw_lead_mm)),
        }
    )


def _machine_from(group: Group | Dataset) -> Machine:
    a = group.attrs
    stroke = np.asarray(a["stroke_mm"], dtype=float)
    return Machine(
        name=str(a["name"]),
        chain=str(a["chain"]),
        stroke_mm={
            axis: (float(stroke[i, 0]), float(stroke[i, 1]))
            for i, axis in enumerate(str(a["axes"]))
        },
        screw_lead_mm=json.loads(a["screw_lead_json"]),
        tool_offset_mm=tuple(float(v) for v in a["tool_offset_mm"]),  # type: ignore[arg-type]
        reference_mm=tuple(float(v) for v in a["reference_mm"]),  # type: ignore[arg-type]
    )


def _data_group(data: LineData, unit: str) -> Group:
    env = data.environment
    attrs: dict[str, Any] = {
        "start_time": float(data.start_time),
        "unit": unit,
        "metadata_json": json.dumps(dict(data.metadata)),
    }
    for key in ("air_temp_c", "air_pressure_kpa", "air_humidity_pct"):
        value = getattr(env, key)
        if value is not None:
            attrs[f"environment_{key}"] = np.asarray(value, dtype=float)
    if env.material_temp_c:
        attrs["environment_material_temp_c"] = np.asarray(env.material_temp_c, dtype=float)
    if env.expansion_ppm_per_c is not None:
        attrs["environment_expansion_ppm_per_c"] = float(env.expansion_ppm_per_c)
    if data.origin_mm is not None:
        attrs["origin_mm"] = float(data.origin_mm)
    children: dict[str, Group | Dataset] = {
        "targets_mm": Dataset(data.targets_mm, {"unit": "mm"}),
        "deviations": Dataset(data.deviations, {"unit": unit}),
        "run_direction": Dataset(data.run_direction),
        "times_s": Dataset(data.times_s, {"unit": "s"}),
    }
    if data.air_temp_c is not None:
        children["air_temp_c"] = Dataset(data.air_temp_c, {"unit": "degC"})
    if data.material_temp_c is not None:
        children["material_temp_c"] = Dataset(data.material_temp_c, {"unit": "degC"})
    return Group(attrs, children)


def _data_from(group: Group | Dataset) -> LineData:
    assert isinstance(group, Group)
    a = group.attrs
    c = group.children

    def pair(key: str) -> tuple[float, float] | None:
        value = a.get(f"environment_{key}")
        return None if value is None else (float(value[0]), float(value[1]))

    material = a.get("environment_material_temp_c")
    environment = Environment(
        air_temp_c=pair("air_temp_c"),
        air_pressure_kpa=pair("air_pressure_kpa"),
        air_humidity_pct=pair("air_humidity_pct"),
        material_temp_c=tuple((float(s), float(e)) for s, e in np.asarray(material))
        if material is not None
        else (),
        expansion_ppm_per_c=a.get("environment_expansion_ppm_per_c"),
    )

    def array(key: str) -> np.ndarray | None:
        item = c.get(key)
        return None if item is None else np.asarray(item.value)  # type: ignore[union-attr]

    return LineData(
        targets_mm=array("targets_mm"),  # type: ignore[arg-type]
        deviations=array("deviations"),  # type: ignore[arg-type]
        run_direction=array("run_direction"),  # type: ignore[arg-type]
        times_s=array("times_s"),  # type: ignore[arg-type]
        start_time=float(a["start_time"]),
        environment=environment,
        air_temp_c=array("air_temp_c"),
        material_temp_c=array("material_temp_c"),
        metadata=json.loads(a.get("metadata_json", "{}")),
        origin_mm=a.get("origin_mm"),
    )


def _line_group(line: StoredLine) -> Group:
    spec = line.spec
    attrs: dict[str, Any] = {
        "quantity": spec.quantity,
        "start_mm": np.asarray(spec.start_mm),
        "direction": np.asarray(spec.direction),
        "reflector_mm": np.asarray(spec.reflector_mm),
        "file": spec.file or "",
        "deviation_unit": spec.deviation_unit,
        "sign": spec.sign,
        "env_corrected": spec.env_corrected,
        "reader_json": json.dumps(dict(spec.reader)),
    }
    if spec.sensitive is not None:
        attrs["sensitive"] = np.asarray(spec.sensitive)
    for key, value in line.provenance.items():
        attrs[f"{key}_json" if isinstance(value, list | dict) else key] = (
            json.dumps(value) if isinstance(value, list | dict) else str(value)
        )
    source = np.frombuffer(line.source_bytes, dtype=np.uint8)
    children: dict[str, Group | Dataset] = {
        "raw": _data_group(line.raw, line.raw_unit),
        "corrected": _data_group(line.corrected, spec.unit),
        "source": Dataset(
            source,
            {
                "filename": str(line.provenance.get("source_file", "")),
                "sha256": hashlib.sha256(line.source_bytes).hexdigest(),
            },
        ),
    }
    if line.capture is not None:
        children["capture"] = Group(
            children={
                k: Dataset(np.asarray(v), {"unit": _unit_of(k) or line.raw_unit})
                for k, v in line.capture.items()
            }
        )
    return Group(attrs, children)


_SPEC_ATTRS = {
    "quantity",
    "start_mm",
    "direction",
    "reflector_mm",
    "file",
    "deviation_unit",
    "sign",
    "env_corrected",
    "reader_json",
    "sensitive",
}


def _line_from(name: str, group: Group) -> StoredLine:
    a = group.attrs
    sensitive = a.get("sensitive")
    spec = LineSpec(
        name=name,
        quantity=str(a["quantity"]),
        start_mm=tuple(float(v) for v in a["start_mm"]),  # type: ignore[arg-type]
        direction=tuple(float(v) for v in a["direction"]),  # type: ignore[arg-type]
        reflector_mm=tuple(float(v) for v in a["reflector_mm"]),  # type: ignore[arg-type]
        sensitive=None if sensitive is None else tuple(float(v) for v in sensitive),  # type: ignore[arg-type]
        file=str(a["file"]) or None,
        deviation_unit=str(a["deviation_unit"]),
        sign=int(a["sign"]),
        env_corrected=bool(a["env_corrected"]),
        reader=json.loads(a["reader_json"]),
    )
    provenance: dict[str, Any] = {}
    for key, value in a.items():
        if key in _SPEC_ATTRS:
            continue
        if key.endswith("_json"):
            provenance[key[: -len("_json")]] = json.loads(value)
        else:
            provenance[key] = value
    raw = group.children["raw"]
    source = group.children["source"]
    assert isinstance(raw, Group) and isinstance(source, Dataset)
    capture = group.children.get("capture")
    return StoredLine(
        spec=spec,
        corrected=_data_from(group.children["corrected"]),
        raw=_data_from(raw),
        raw_unit=str(raw.attrs["unit"]),
        source_bytes=np.asarray(source.value, dtype=np.uint8).tobytes(),
        provenance=provenance,
        capture=None
        if capture is None
        else {
            k: np.asarray(v.value)
            for k, v in capture.children.items()  # type: ignore[union-attr]
        },
    )

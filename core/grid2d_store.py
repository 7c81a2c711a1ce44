"""Grids in the HDF5 project: ``/grids/<name>``, written and read here.

Layout (inside the project's format version 1; an older volucal ignores the group)::

    /grids/<name>               attrs name, source_file, upper_axis ("" when unknown),
                                units_json, metadata_json, imported (ISO 8601 UTC), sha256
        position_mm             (n, 2) commanded X, Y (attr unit mm)
        deviation_um            (n, 2) measured − commanded in X, Y; NaN where not measured
        file_lines              (n,) line of each reading in the source file
        air_temp_c, material_temp_c, pressure_kpa, humidity_pct   (n,), where the file has them
        source                  the source file's bytes (uint8), attrs filename, sha256
        identification/         (optional) the identification the grid took part in:
                                report_json (the identification as volucal grid --json prints
                                it), grids (the names of the grids fitted together)

:class:`volucal.core.project.Project` keeps these groups in ``project.grids`` and saves them
with the rest of the project (atomically).
"""

from __future__ import annotations

import hashlib
import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from .grid2d import GridMeasurement
from .project import Dataset, Group, Project
from .userror import UserError

_ENVIRONMENT = ("air_temp_c", "material_temp_c", "pressure_kpa", "humidity_pct")


def _check_name(name: str) -> None:
    if not isinstance(name, str) or not name or "/" in name or name.startswith("."):
        raise UserError(
            f"grid name {name!r}: use a non-empty name without '/', not starting with '.'"
        )


def grid_group(
    grid: GridMeasurement,
    identification: dict[str, Any] | None = None,
    fitted_with: list[str] | None = None,
) -> Group:
    """The ``/grids/<name>`` group of a grid (module notes)."""
    digest = hashlib.sha256(grid.source_bytes).hexdigest()
    group = Group(
        {
            "name": grid.name,
            "source_file": Path(grid.source_file).name if grid.source_file else "",
            "upper_axis": grid.upper_axis or "",
            "units_json": json.dumps(dict(grid.units), ensure_ascii=False),
            "metadata_json": json.dumps(dict(grid.metadata), ensure_ascii=False),
            "imported": datetime.now(UTC).isoformat(timespec="seconds"),
            "sha256": digest,
        }
    )
    group.children["position_mm"] = Dataset(np.asarray(grid.position_mm), {"unit": "mm"})
    group.children["deviation_um"] = Dataset(np.asarray(grid.deviation_um), {"unit": "um"})
    if grid.file_lines is not None:
        group.children["file_lines"] = Dataset(np.asarray(grid.file_lines))
    for key in _ENVIRONMENT:
        value = getattr(grid, key)
        if value is not None:
            unit = {
                "air_temp_c": "degC",
                "material_temp_c": "degC",
                "pressure_kpa": "kPa",
                "humidity_pct": "%RH",
            }[key]
            group.children[key] = Dataset(np.asarray(value), {"unit": unit})
    group.children["source"] = Dataset(
        np.frombuffer(grid.source_bytes, dtype=np.uint8).copy(),
        {"filename": Path(grid.source_file).name, "sha256": digest},
    )
    if identification is not None:
        group.children["identification"] = Group(
            children={
                "report_json": Dataset(np.array(json.dumps(identification), dtype=object)),
                "grids": Dataset(np.array(fitted_with or [grid.name], dtype=object)),
            }
        )
    return group


def grid_from_group(group: Group) -> GridMeasurement:
    """The grid stored in a ``/grids/<name>`` group."""

    def array(key: str) -> np.ndarray | None:
        child = group.children.get(key)
        return np.asarray(child.value) if isinstance(child, Dataset) else None

    source = array("source")
    return GridMeasurement(
        name=str(group.attrs["name"]),
        position_mm=array("position_mm"),  # type: ignore[arg-type]
        deviation_um=array("deviation_um"),  # type: ignore[arg-type]
        air_temp_c=array("air_temp_c"),
        material_temp_c=array("material_temp_c"),
        pressure_kpa=array("pressure_kpa"),
        humidity_pct=array("humidity_pct"),
        upper_axis=str(group.attrs.get("upper_axis") or "") or None,
        units=json.loads(group.attrs.get("units_json", "{}")),
        metadata=json.loads(group.attrs.get("metadata_json", "{}")),
        source_file=str(group.attrs.get("source_file", "")),
        source_bytes=source.tobytes() if source is not None else b"",
        file_lines=array("file_lines"),
    )


def put_grid(
    project: Project,
    grid: GridMeasurement,
    identification: dict[str, Any] | None = None,
    fitted_with: list[str] | None = None,
    *,
    replace: bool = False,
) -> None:
    """Add a grid (and the identification it took part in) to the project in memory."""
    _check_name(grid.name)
    if grid.name in project.grids and not replace:
        raise UserError(
            f"the project already has a grid {grid.name!r}; give another name or replace it"
        )
    project.grids[grid.name] = grid_group(grid, identification, fitted_with)


def grid_names(project: Project) -> list[str]:
    return list(project.grids)


def get_grid(project: Project, name: str) -> GridMeasurement:
    if name not in project.grids:
        raise UserError(
            f"no grid {name!r} in the project (it has {', '.join(project.grids) or 'none'})"
        )
    try:
        return grid_from_group(project.grids[name])
    except (KeyError, ValueError, TypeError) as exc:
        raise UserError(f"grid {name!r} in the project is damaged ({exc})") from None


def grid_identification(project: Project, name: str) -> dict[str, Any] | None:
    """The identification stored with a grid (as ``volucal grid --json`` prints it), if any."""
    if name not in project.grids:
        raise UserError(f"no grid {name!r} in the project")
    child = project.grids[name].children.get("identification")
    if not isinstance(child, Group) or "report_json" not in child.children:
        return None
    report = child.children["report_json"]
    assert isinstance(report, Dataset)
    return json.loads(str(report.value.item()))  # type: ignore[no-any-return]

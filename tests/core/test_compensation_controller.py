"""How controllers apply tables: interpolation, direction, indexing — hand-worked cases."""

from __future__ import annotations

import numpy as np
import pytest
from compensation_models import linear_model
from volucal.core.compensation import ModelSource, TableRequest, build_tables
from volucal.core.compensation.controller import (
    ControllerCompensation,
    LoadedTable,
    axis_compensation,
    step_value,
)


def test_linear_table_interpolates_and_holds_end_values() -> None:
    table = LoadedTable("X", "X", np.array([0.0, 100.0, 200.0]), np.array([0.0, 10.0, 4.0]))
    q = np.array([-50.0, 0.0, 50.0, 150.0, 200.0, 300.0])
    np.testing.assert_allclose(table.value_at(q, np.ones(6)), [0, 0, 5, 7, 4, 4])


def test_direction_tables_apply_only_while_moving_their_way() -> None:
    forward = LoadedTable("X", "X", np.array([0.0, 100.0]), np.array([2.0, 2.0]), direction=1)
    backward = LoadedTable("X", "X", np.array([0.0, 100.0]), np.array([-2.0, -2.0]), -1)
    compensation = ControllerCompensation("test", (forward, backward))
    nominal = np.array([[50.0, 0, 0], [50.0, 0, 0]])
    approach = np.array([[1.0, 1, 1], [-1.0, 1, 1]])
    command = compensation.command_mm(nominal, approach)
    np.testing.assert_allclose((command - nominal)[:, 0] * 1e3, [2.0, -2.0])


def test_step_value_is_the_last_point_passed() -> None:
    """Fanuc: moving positive the value of the last point at or below q applies, moving
    negative that of the first point at or above q; end values held."""
    nodes = np.array([0.0, 10.0, 20.0])
    values = np.array([0.0, 1.0, 3.0])
    q = np.array([-5.0, 5.0, 10.0, 15.0, 20.0, 25.0])
    np.testing.assert_allclose(step_value(nodes, values, q, np.ones(6)), [0, 0, 1, 1, 3, 3])
    np.testing.assert_allclose(step_value(nodes, values, q, -np.ones(6)), [0, 1, 1, 3, 3, 3])


def test_table_indexed_by_actual_position_settles_where_the_loop_does() -> None:
    """Siemens EEC: the table holds the error v(c) = 0.5·c µm at the actual position; the axis
    settles where c + v(c)/1000 = n, i.e. c = n / 1.0005."""
    table = LoadedTable(
        "Y", "Y", np.array([0.0, 400.0]), np.array([0.0, 200.0]), indexed_by="actual"
    )
    compensation = ControllerCompensation("eec", (table,))
    nominal = np.array([[0.0, 100.0, 0.0], [0.0, 400.0, 0.0]])
    command = compensation.command_mm(nominal, np.ones(3))
    np.testing.assert_allclose(command[:, 1], nominal[:, 1] / 1.0005, atol=1e-10)
    with pytest.raises(ValueError, match="own axis"):
        LoadedTable("X", "Y", np.array([0.0, 1.0]), np.zeros(2), indexed_by="actual")


def test_cross_table_corrects_the_output_axis() -> None:
    table = LoadedTable("Y", "X", np.array([0.0, 400.0]), np.array([0.0, 4.0]))
    command = ControllerCompensation("cross", (table,)).command_mm(
        np.array([[10.0, 200.0, 5.0]]), np.ones(3)
    )
    np.testing.assert_allclose((command - [10.0, 200.0, 5.0]) * 1e3, [[2.0, 0.0, 0.0]])


def test_axis_tables_compensate_scale_errors_exactly() -> None:
    source = ModelSource(linear_model({"EXX": 0.01, "EYY": -0.02, "EZZ": 0.03}))
    tables = build_tables(source, TableRequest(spacing_mm=100.0, grid_spacing_mm=None))
    compensation = axis_compensation(tables)
    rng = np.random.default_rng(1)
    nominal = rng.uniform([0, 0, 0], [400, 400, 350], size=(200, 3))
    command = compensation.command_mm(nominal, np.ones(3))
    landed = command + source.error_um(command) / 1e3
    np.testing.assert_allclose(landed, nominal, atol=1e-8)

"""Per-axis, cross-axis and volumetric tables, against hand-worked values."""

from __future__ import annotations

import numpy as np
import pytest
from compensation_models import linear_model, paper_like_model
from volucal.core.compensation import (
    ModelSource,
    ReversalSource,
    TableRequest,
    build_tables,
)
from volucal.core.compensation.tables import even_nodes
from volucal.core.errors import ErrorFunction, ErrorModel, PolynomialBasis
from volucal.core.machine import Machine
from volucal.core.userror import UserError


def test_nodes_divide_the_range_evenly_without_exceeding_the_spacing() -> None:
    np.testing.assert_allclose(even_nodes(0, 400, 10), np.arange(0, 401, 10))
    nodes = even_nodes(0, 400, 30)  # 13.3 intervals -> 14 of 28.57 mm
    assert len(nodes) == 15 and nodes[-1] == 400
    assert np.max(np.diff(nodes)) <= 30


def test_axis_tables_of_scale_errors() -> None:
    """E_x = 0.01·x µm: error column 0.01·x, correction −0.01·x/(1 + 1e-5)."""
    source = ModelSource(linear_model({"EXX": 0.01, "EYY": -0.02, "EZZ": 0.03}))
    tables = build_tables(source, TableRequest(spacing_mm=50.0, grid_spacing_mm=None))
    x = tables.axis["X"]
    np.testing.assert_allclose(x.position_mm, np.arange(0, 401, 50))
    np.testing.assert_allclose(x.error_forward_um, 0.01 * x.position_mm, atol=1e-12)
    np.testing.assert_allclose(x.correction_forward_um, -0.01 * x.position_mm / 1.00001, atol=1e-9)
    assert not x.bidirectional
    np.testing.assert_allclose(tables.axis["Z"].error_mean_um, 0.03 * tables.axis["Z"].position_mm)
    assert tables.grid is None
    assert tables.tool_offset_mm == (0.0, 0.0, 200.0)  # the paper machine's


def test_cross_tables_carry_squareness_and_tool_offset_abbe() -> None:
    """EC0Y = 10 µrad: along Y, E_x = −y·EC0Y = −0.01·y µm. Roll of X, EAX = 0.05·x µrad, with
    the 200 mm tool offset: along X, E_y = −200 mm · EAX = −0.01·x µm (θ × lever)."""
    source = ModelSource(linear_model({"EAX": 0.05}, squareness_urad={"EC0Y": 10.0}))
    tables = build_tables(source, TableRequest(spacing_mm=100.0, grid_spacing_mm=None))
    x_of_y = tables.cross_table("Y", "X")
    np.testing.assert_allclose(x_of_y.error_um, -0.01 * x_of_y.position_mm, atol=1e-9)
    np.testing.assert_allclose(x_of_y.correction_um, 0.01 * x_of_y.position_mm, atol=1e-6)
    y_of_x = tables.cross_table("X", "Y")
    np.testing.assert_allclose(y_of_x.error_um, -0.01 * y_of_x.position_mm, atol=1e-9)
    # The own-axis tables do not see them.
    np.testing.assert_allclose(tables.axis["X"].error_mean_um, 0.0, atol=1e-9)
    with pytest.raises(KeyError):
        tables.cross_table("X", "X")


def test_cross_tables_are_zero_at_the_reference() -> None:
    """With the reference mid-stroke a squareness error is non-zero there (E_x = −y·EC0Y at
    y = 200); the cross table is shifted so the three axes' tables do not count it thrice."""
    machine = Machine(
        stroke_mm={"X": (0, 400), "Y": (0, 400), "Z": (0, 350)},
        tool_offset_mm=(0, 0, 0),
        reference_mm=(0, 200, 0),
    )
    model = linear_model({}, machine, {"EC0Y": 10.0})
    tables = build_tables(ModelSource(model), TableRequest(spacing_mm=100.0, grid_spacing_mm=None))
    x_of_y = tables.cross_table("Y", "X")
    assert x_of_y.error_um[2] == pytest.approx(0.0, abs=1e-12)  # y = 200
    np.testing.assert_allclose(x_of_y.error_um, -0.01 * (x_of_y.position_mm - 200), atol=1e-9)
    # The X table along y = 200 holds E_x there: −2 µm, once.
    np.testing.assert_allclose(tables.axis["X"].error_mean_um, -2.0, atol=1e-9)


def test_bidirectional_tables_from_reversal() -> None:
    source = ReversalSource(ModelSource(paper_like_model()), {"Y": lambda y: 2.0 + 0.01 * y})
    tables = build_tables(source, TableRequest(grid_spacing_mm=None))
    y = tables.axis["Y"]
    assert y.bidirectional and not tables.axis["X"].bidirectional
    np.testing.assert_allclose(y.reversal_um, 2.0 + 0.01 * y.position_mm, atol=1e-12)
    # To first order the corrections differ by minus the reversal; the second-order term is
    # the error's slope times the reversal (nanometres).
    np.testing.assert_allclose(
        y.correction_forward_um - y.correction_backward_um, -y.reversal_um, atol=5e-3
    )


def test_nodes_beyond_the_measured_range_are_flagged_and_held() -> None:
    basis = PolynomialBasis(0.0, 400.0, 1)
    model = ErrorModel.zero(paper_like_model().machine, lambda axis, eid: basis)
    functions = dict(model.functions)
    functions["EXX"] = ErrorFunction("EXX", basis, np.array([2.0, 2.0]))  # 0.01·x µm
    source = ModelSource(ErrorModel(model.machine, functions))
    request = TableRequest(spacing_mm=50.0, range_mm={"X": (-100.0, 500.0)}, grid_spacing_mm=None)
    tables = build_tables(source, request)
    x = tables.axis["X"]
    outside = (x.position_mm < 0) | (x.position_mm > 400)
    np.testing.assert_array_equal(x.beyond_range, outside)
    np.testing.assert_allclose(x.error_mean_um[x.position_mm > 400], 4.0)  # held, not 5.0
    np.testing.assert_allclose(x.error_mean_um[x.position_mm < 0], 0.0)
    assert len(tables.flags) == 1 and "X table" in tables.flags[0]
    assert "not extrapolated" in tables.flags[0]


def test_volumetric_grid_holds_the_source_error() -> None:
    source = ModelSource(paper_like_model())
    tables = build_tables(source, TableRequest(grid_spacing_mm=50.0))
    grid = tables.grid
    assert grid is not None
    assert grid.error_um.shape == (9, 9, 8, 3)  # 400/50 + 1, 350/50 + 1
    points = grid.points_mm
    np.testing.assert_allclose(grid.error_um.reshape(-1, 3), source.error_um(points), atol=1e-12)
    commanded = points + grid.correction_um.reshape(-1, 3) / 1e3
    # Commanding the corrected position lands on the grid node.
    landed = commanded + source.error_um(commanded) / 1e3
    np.testing.assert_allclose(landed, points, atol=1e-9)


def test_bad_requests_are_user_errors() -> None:
    source = ModelSource(paper_like_model())
    with pytest.raises(UserError, match="positive"):
        build_tables(source, TableRequest(spacing_mm=0.0))
    with pytest.raises(UserError, match="ascending"):
        build_tables(source, TableRequest(nodes_mm={"X": (0.0, 0.0)}))
    with pytest.raises(UserError, match="grid spacing"):
        build_tables(source, TableRequest(grid_spacing_mm=-1.0))


def test_an_axis_measured_at_one_position_spans_its_stroke_and_is_flagged() -> None:
    class Narrow(ModelSource):
        measured_range_mm = {"X": (0.0, 400.0), "Y": (100.0, 100.0), "Z": (0.0, 350.0)}

    source = Narrow(paper_like_model())
    tables = build_tables(source, TableRequest(grid_spacing_mm=None))
    y = tables.axis["Y"]
    assert y.position_mm[0] == 0.0 and y.position_mm[-1] == 400.0
    assert np.array_equal(y.beyond_range, y.position_mm != 100.0)
    assert [f for f in tables.flags if f.startswith("Y table")] == [
        "Y table: no measured line moved Y (every reading at Y = 100 mm); its 41 nodes span "
        "[0, 400] mm, along which nothing was measured"
    ]
    assert not any(f.startswith(("X table", "Z table")) for f in tables.flags)
    # an explicit extent is taken as given; one of a single position is refused
    tables = build_tables(source, TableRequest(range_mm={"Y": (50.0, 150.0)}, grid_spacing_mm=None))
    assert tables.axis["Y"].position_mm[0] == 50.0 and tables.axis["Y"].position_mm[-1] == 150.0
    with pytest.raises(UserError, match="single position"):
        build_tables(source, TableRequest(range_mm={"Y": (100.0, 100.0)}))

"""What a grid model predicts between its measured nodes: the smooth part of each error function,
its nodes' departures and how far they carry, chosen by cross-validation over held-out lines."""

import numpy as np
import pytest
from scipy.interpolate import make_smoothing_spline
from volucal.core.cli import main
from volucal.core.compensation.export_grid2d import grid_table
from volucal.core.errors import BSplineBasis, NodeTableBasis
from volucal.core.grid2d import GridGauge, GridMeasurement, rms
from volucal.core.grid2d_departures import (
    NodeDepartureBasis,
    carry_kernel,
    fit_smooth_part,
)
from volucal.core.grid2d_fit import GridFitRequest, identify_grid
from volucal.core.userror import UserError

NODES = np.array([0.0, 10.0, 20.0, 35.0, 50.0])


@pytest.mark.parametrize("carry", [0.0, 0.3, 1.0])
def test_the_carry_kernel_is_a_table_at_half_the_node_step(carry):
    # reference: np.interp on the nodes and midpoints, holding 1 at a node, carry/2 beside it
    half = np.sort(np.concatenate([NODES, 0.5 * (NODES[:-1] + NODES[1:])]))
    q = np.linspace(-5.0, 55.0, 241)
    kernel = carry_kernel(q, NODES, carry)
    for n in range(NODES.size):
        table = np.where(np.isclose(half, NODES[n]), 1.0, 0.0)
        for side in (n - 1, n + 1):
            if 0 <= side < NODES.size:
                table[np.isclose(half, 0.5 * (NODES[n] + NODES[side]))] = carry / 2
        np.testing.assert_allclose(kernel[:, n], np.interp(q, half, table), atol=1e-12)
    np.testing.assert_allclose(carry_kernel(NODES, NODES, carry), np.eye(NODES.size),
                               atol=1e-12)


@pytest.mark.parametrize("degree, carry", [(1, 0.0), (3, 0.0), (3, 0.6), (1, 1.0)])
def test_a_function_is_its_node_values_at_the_nodes_whatever_its_smooth_part(degree, carry):
    values = np.array([0.0, 1.3, -0.4, 0.9, 0.2])
    basis = NodeTableBasis(tuple(NODES)) if degree == 1 else BSplineBasis(tuple(NODES))
    smooth = fit_smooth_part(basis, NODES, values, 10.0)
    departures = values - basis.design(NODES) @ smooth
    combined = NodeDepartureBasis(basis, tuple(NODES), carry)
    coefficients = np.concatenate([smooth, departures])
    np.testing.assert_allclose(combined.evaluate(NODES, coefficients), values, atol=1e-12)
    middle = 0.5 * (NODES[1:] + NODES[:-1])
    expected = (basis.design(middle) @ smooth
                + carry * 0.5 * (departures[1:] + departures[:-1]))
    np.testing.assert_allclose(combined.evaluate(middle, coefficients), expected, atol=1e-12)
    assert combined.describe()["carry"] == carry


def test_the_cubic_smooth_part_is_the_smoothing_spline_of_the_node_values():
    # scipy's make_smoothing_spline minimises Σ (v − f)² + lam ∫ f''²: with knots at every
    # lattice node (some without a value) and weight w the smooth part is it, lam = w·step³
    lattice = np.arange(0.0, 101.0, 10.0)
    seen = np.ones(lattice.size, dtype=bool)
    seen[[3, 7]] = False
    rng = np.random.default_rng(4)
    values = np.sin(lattice[seen] / 17.0) + rng.normal(0, 0.2, seen.sum())
    basis = BSplineBasis(tuple(lattice))
    for weight in (0.1, 1.0, 30.0):
        smooth = fit_smooth_part(basis, lattice[seen], values, weight)
        reference = make_smoothing_spline(lattice[seen], values, lam=weight * 10.0**3)
        q = np.linspace(0.0, 100.0, 57)
        np.testing.assert_allclose(basis.design(q) @ smooth, reference(q), atol=1e-7)


def test_the_node_table_smooth_part_tends_to_the_mean():
    basis = NodeTableBasis(tuple(NODES))
    values = np.array([0.0, 1.3, -0.4, 0.9, 0.2])
    smooth = fit_smooth_part(basis, NODES, values, 1e9)
    np.testing.assert_allclose(smooth, values.mean(), atol=1e-6)


def rough_rows(seed: int = 7, offsets_um: float = 0.4) -> GridMeasurement:
    """A 5 mm grid whose X readings carry an offset per row (the straightness of Y in X at a
    5 mm pitch, as the grid 643494) on smooth planar errors, a turned mirror, 0.02 µm noise."""
    step = 5.0
    x, y = np.meshgrid(np.arange(0.0, 200.1, step), np.arange(0.0, 200.1, step))
    u, v = x.ravel() / 200.0, y.ravel() / 200.0
    rng = np.random.default_rng(seed)
    rows = rng.normal(0.0, offsets_um, x.shape[0])
    ex = 2.0 * np.sin(2.0 * u) + 3.0 * v**2 + rows[np.rint(y.ravel() / step).astype(int)]
    ey = 1.5 * np.cos(3.0 * u) - 2.0 * v + 0.4 * np.sin(np.pi * u) * np.sin(np.pi * v)
    position = np.stack([x.ravel(), y.ravel()], axis=1)
    error = np.stack([ex, ey], axis=1) + GridGauge(0.5, -0.3, 20.0).evaluate(position)
    error += rng.normal(0.0, 0.02, error.shape)
    return GridMeasurement("rough", position, error, upper_axis="Y")


def even_and_odd_rows(grid: GridMeasurement):
    ix = np.rint(grid.position_mm[:, 0] / 5.0).astype(int)
    iy = np.rint(grid.position_mm[:, 1] / 5.0).astype(int)
    fit = (ix % 2 == 0) & (iy % 2 == 0)
    between_rows = (ix % 2 == 0) & (iy % 2 == 1)
    even = GridMeasurement("even", grid.position_mm[fit], grid.deviation_um[fit],
                           upper_axis=grid.upper_axis)
    return even, between_rows


def test_rough_row_offsets_are_not_carried_between_rows():
    grid = rough_rows()
    even, between_rows = even_and_odd_rows(grid)
    result = identify_grid(even)
    # cross-validation over held-out rows sees that a row's offset says nothing of the next
    assert result.choices["EXY"]["carry"] < 0.3
    # at the measured nodes the model keeps the rows' offsets (0.4 µm): it leaves the readings'
    # 0.02 µm noise, which the surface's cross-validated smoothing does not follow
    rebuilt = result.error(even.position_mm) + result.gauges["even"].evaluate(even.position_mm)
    assert rms(rebuilt - even.deviation_um) < 0.025
    # between the rows it predicts the X errors better than the node values interpolated
    # linearly, which is what a table at the measured nodes gives a controller
    q = grid.position_mm[between_rows]
    measured = grid.deviation_um[between_rows, 0] - result.gauges["even"].evaluate(q)[:, 0]
    model = result.error(q)[:, 0]
    table = grid_table(result)
    at_reference = result.error(np.array([result.reference_mm]))[0, 0]
    lookup = at_reference + np.array([np.interp(
        p[1], table.y_mm, table.error_um[0, :, int(round(p[0] / 10.0))]) for p in q])
    assert rms(measured - model) < 0.9 * rms(measured - lookup)
    between = result.statistics["cv_between_lines_rms_um"]["rows"]
    assert between["model"]["X"] < between["node_values_interpolated"]["X"]


def test_without_evidence_the_model_is_the_lookup_table():
    grid = rough_rows(offsets_um=0.0)
    even, _ = even_and_odd_rows(grid)
    result = identify_grid(even, GridFitRequest(significance=1e9))
    for eid, choice in result.choices.items():
        if eid != "surface":
            assert (choice["degree"], choice["carry"]) == (1, 1.0), eid
    # then a table at the measured nodes, interpolated linearly, is the model everywhere
    table = grid_table(result)
    at_reference = result.error(np.array([result.reference_mm]))[0]
    q = np.array([[15.0, 35.0], [72.5, 101.0], [133.0, 5.0]])
    for k in range(2):
        i = np.clip(np.searchsorted(table.x_mm, q[:, 0]) - 1, 0, table.x_mm.size - 2)
        j = np.clip(np.searchsorted(table.y_mm, q[:, 1]) - 1, 0, table.y_mm.size - 2)
        tx = (q[:, 0] - table.x_mm[i]) / 10.0
        ty = (q[:, 1] - table.y_mm[j]) / 10.0
        e = table.error_um[k]
        bilinear = (e[j, i] * (1 - tx) * (1 - ty) + e[j, i + 1] * tx * (1 - ty)
                    + e[j + 1, i] * (1 - tx) * ty + e[j + 1, i + 1] * tx * ty)
        np.testing.assert_allclose(result.error(q)[:, k], at_reference[k] + bilinear, atol=1e-9)


def test_a_reference_between_nodes_is_a_node_of_every_function():
    grid, _ = even_and_odd_rows(rough_rows())
    result = identify_grid(grid, GridFitRequest(reference_mm=(55.0, 123.0)))
    for eid, function in result.functions.items():
        at = 55.0 if eid[2] == "X" else 123.0
        assert abs(float(function(np.array([at]))[0])) < 1e-9, eid
    rebuilt = result.error(grid.position_mm) + result.gauges["even"].evaluate(grid.position_mm)
    assert rms(rebuilt - grid.deviation_um) < 0.025


def test_significance_must_be_a_number_of_standard_errors():
    with pytest.raises(UserError, match="significance"):
        GridFitRequest(significance=-1.0)
    with pytest.raises(UserError, match="significance"):
        GridFitRequest(significance=float("nan"))


def test_the_command_says_how_to_write_the_model_between_the_nodes(tmp_path, capsys):
    grid, _ = even_and_odd_rows(rough_rows())
    source = tmp_path / "rough.csv"
    lines = ["x,y,dx,dy"] + [f"{p[0]:.3f},{p[1]:.3f},{d[0]:.5f},{d[1]:.5f}"
                             for p, d in zip(grid.position_mm, grid.deviation_um, strict=True)]
    source.write_text("\n".join(lines) + "\n")
    columns = "x=x,y=y,deviation_x=dx,deviation_y=dy"
    table = tmp_path / "table.csv"
    arguments = ["grid", str(source), "--columns", columns, "--position-unit", "mm",
                 "--deviation-unit", "um", "--upper-axis", "Y", "--export-csv", str(table)]
    assert main(arguments) == 0
    text = capsys.readouterr().out
    assert "EXY" in text and "carrying" in text
    assert "held-out rows (cross-validated)" in text
    assert "--spacing 5 writes it at half the measured step" in text
    assert main(arguments + ["--spacing", "5"]) == 0
    assert "--spacing 5 writes it" not in capsys.readouterr().out
    rows = [line for line in table.read_text().splitlines() if not line.startswith("#")]
    assert rows[0].startswith("x_mm,y_mm") and len(rows) == 1 + 41 * 41

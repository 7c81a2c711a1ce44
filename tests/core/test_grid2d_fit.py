"""Identification of the planar errors from a grid, checked against volucal's own kinematic chain
(the 3-D model's signs and lever arms): grids simulated from a known ErrorModel through
``volumetric_error``, plus a laser zero and a mirror rotation, are identified back."""

import numpy as np
import pytest
from volucal.core.errors import ErrorFunction, ErrorModel, PolynomialBasis
from volucal.core.grid2d import GridGauge, GridMeasurement, remove_gauge_terms, rms
from volucal.core.grid2d_fit import GridFitRequest, identify_grid
from volucal.core.kinematics import volumetric_error
from volucal.core.machine import Machine
from volucal.core.userror import UserError

STROKE = {"X": (0.0, 300.0), "Y": (0.0, 200.0), "Z": (0.0, 100.0)}
TRUTH = {  # Legendre coefficients over each stroke (before the gauge projection)
    "EXX": [0.0, 3.0, -1.5, 0.8], "EYY": [0.0, -2.0, 1.2, 0.5], "EYX": [0.0, 0.0, 1.5, -0.6],
    "EXY": [0.0, 0.0, -1.0, 0.4], "ECY": [0.0, 20.0, -8.0, 3.0], "ECX": [0.0, -15.0, 6.0, 2.0],
}


def machine_and_model(chain: str, squareness_urad: float) -> ErrorModel:
    machine = Machine(name="grid test", chain=chain, stroke_mm=STROKE)
    functions = {}
    for axis in ("X", "Y", "Z"):
        low, high = STROKE[axis]
        for c in "XYZABC":
            eid = f"E{c}{axis}"
            basis = PolynomialBasis(low, high, 3)
            functions[eid] = ErrorFunction(eid, basis, TRUTH.get(eid, [0.0] * 4))
    model = ErrorModel(machine, functions, {"EC0Y": squareness_urad, "EB0Z": 0.0, "EA0Z": 0.0})
    return model.gauged()  # volucal's gauge: zero at the reference, straightness without slope


def simulate(model: ErrorModel, gauge: GridGauge, noise_um: float = 0.0,
             step: float = 10.0, seed: int = 1) -> GridMeasurement:
    xs = np.arange(0.0, 300.0 + 1e-9, step)
    ys = np.arange(0.0, 200.0 + 1e-9, step)
    xx, yy = np.meshgrid(xs, ys)
    position = np.stack([xx.ravel(), yy.ravel()], axis=1)
    error = volumetric_error(model, np.column_stack([position, np.zeros(len(position))]))
    deviation = error[:, :2] + gauge.evaluate(position)
    deviation += np.random.default_rng(seed).normal(0.0, noise_um, deviation.shape)
    upper = model.machine.axis_order[0]  # nearest the workpiece: mounted on the other
    return GridMeasurement("sim", position, deviation, upper_axis=upper)


@pytest.mark.parametrize("chain, yaw", [("WYXFZT", "ECY"), ("WXYFZT", "ECX")])
def test_planar_errors_squareness_and_yaw_come_back_in_volucal_conventions(chain, yaw):
    model = machine_and_model(chain, squareness_urad=25.0)
    gauge = GridGauge(offset_x_um=1.2, offset_y_um=-0.7, rotation_urad=40.0)
    grid = simulate(model, gauge, noise_um=0.02)
    result = identify_grid(grid, GridFitRequest(surface=False))
    assert set(result.functions) == {"EXX", "EYY", "EYX", "EXY", yaw}
    for eid in result.functions:
        q, value, std = result.sampled(eid)
        truth = model.functions[eid](q)
        # within the stated standard uncertainty of the node values (least squares per line)
        assert np.all(np.abs(value - truth) <= 5 * std + 0.005), eid
        assert std[0] == pytest.approx(0.0, abs=1e-9)  # zero at the reference, by the gauge
        bound = 0.2 if eid.startswith("EC") else 0.02  # µrad, µm for 0.02 µm noise
        assert np.all(std[1:] > 0) and np.all(std < bound), eid
    assert result.squareness_urad == pytest.approx(25.0, abs=0.2)
    assert abs(result.squareness_urad - 25.0) < 5 * result.squareness_std_urad + 0.05
    fitted = result.gauges["sim"]
    assert fitted.rotation_urad == pytest.approx(40.0, abs=0.2)
    assert fitted.offset_x_um == pytest.approx(1.2, abs=0.02)
    assert fitted.offset_y_um == pytest.approx(-0.7, abs=0.02)
    assert result.statistics["rms_um"]["rigid_body"]["X"] == pytest.approx(0.02, rel=0.2)


def test_a_turned_mirror_is_not_squareness_and_squareness_is_not_a_turned_mirror():
    model = machine_and_model("WYXFZT", squareness_urad=0.0)
    turned = identify_grid(simulate(model, GridGauge(rotation_urad=60.0)),
                           GridFitRequest(surface=False))
    assert turned.squareness_urad == pytest.approx(0.0, abs=0.01)
    assert turned.gauges["sim"].rotation_urad == pytest.approx(60.0, abs=0.01)
    square = identify_grid(simulate(machine_and_model("WYXFZT", 60.0), GridGauge()),
                           GridFitRequest(surface=False))
    assert square.squareness_urad == pytest.approx(60.0, abs=0.01)
    assert square.gauges["sim"].rotation_urad == pytest.approx(0.0, abs=0.01)


def test_the_map_is_the_model_plus_gauges_and_the_surface_takes_what_is_not_rigid():
    model = machine_and_model("WYXFZT", squareness_urad=-30.0)
    grid = simulate(model, GridGauge(0.3, 0.1, -20.0))
    x, y = grid.position_mm[:, 0], grid.position_mm[:, 1]
    sag = 0.8 * np.sin(np.pi * x / 300.0) * np.sin(np.pi * y / 200.0)  # a twist no axis makes
    bent = GridMeasurement("sim", grid.position_mm,
                           grid.deviation_um + np.column_stack([sag, -sag]), upper_axis="Y")
    result = identify_grid(bent)
    rebuilt = result.error(bent.position_mm) + result.gauges["sim"].evaluate(bent.position_mm)
    assert rms(rebuilt - bent.deviation_um) < 0.02
    # what no function of x plus a function of y can hold (X readings have no lever-arm term)
    table = sag.reshape(21, 31)
    interaction = table - table.mean(axis=0) - table.mean(axis=1)[:, None] + table.mean()
    without = identify_grid(bent, GridFitRequest(surface=False))
    assert without.statistics["rms_um"]["rigid_body"]["X"] == pytest.approx(rms(interaction),
                                                                         rel=0.05)
    # the surface is that part
    np.testing.assert_allclose(result.surface_um[0], interaction - interaction.mean(), atol=0.01)
    assert result.squareness_urad == pytest.approx(-30.0, abs=3.0)


def test_several_grids_share_the_errors_and_keep_their_own_gauges():
    model = machine_and_model("WYXFZT", squareness_urad=15.0)
    whole = simulate(model, GridGauge())
    x = whole.position_mm[:, 0]
    zones = []
    for name, mask, gauge in (("left", x <= 160, GridGauge(2.0, -1.0, 30.0)),
                              ("right", x >= 140, GridGauge(-0.5, 0.4, -12.0))):
        position = whole.position_mm[mask]
        error = volumetric_error(model, np.column_stack([position, np.zeros(mask.sum())]))
        zones.append(GridMeasurement(name, position, error[:, :2] + gauge.evaluate(position),
                                     upper_axis="Y"))
    result = identify_grid(zones, GridFitRequest(surface=False))
    assert result.squareness_urad == pytest.approx(15.0, abs=0.05)
    assert result.gauges["left"].rotation_urad == pytest.approx(30.0, abs=0.05)
    assert result.gauges["right"].rotation_urad == pytest.approx(-12.0, abs=0.05)
    q, value, _ = result.sampled("EXX")
    np.testing.assert_allclose(value, model.functions["EXX"](q), atol=0.005)


def test_gauge_terms_are_removed_before_comparing_two_maps():
    rng = np.random.default_rng(3)
    position = rng.uniform(0, 100, (50, 2))
    values = rng.normal(0, 1, (50, 2))
    shifted = values + GridGauge(5.0, -2.0, 70.0).evaluate(position)
    a, _ = remove_gauge_terms(position, values)
    b, gauge = remove_gauge_terms(position, shifted)
    np.testing.assert_allclose(a, b, atol=1e-9)


def test_bad_requests_and_degenerate_grids_are_user_errors():
    with pytest.raises(UserError, match="upper axis"):
        GridFitRequest(upper_axis="Z")
    line = GridMeasurement("line", np.column_stack([np.arange(5.0), np.zeros(5)]),
                           np.zeros((5, 2)))
    with pytest.raises(UserError, match="two Y positions"):
        identify_grid(line)
    grid = simulate(machine_and_model("WYXFZT", 0.0), GridGauge(), step=50.0)
    with pytest.raises(UserError, match="outside the grid"):
        identify_grid(grid, GridFitRequest(reference_mm=(500.0, 0.0)))

"""Verification: compensation rates and ISO 230-2 figures, hand-worked and analytic cases."""

from __future__ import annotations

import numpy as np
import pytest
from compensation_models import linear_model, paper_like_model
from volucal.core.compensation import (
    ModelSource,
    ReversalSource,
    VerifyRequest,
    build_tables,
    standard_compensations,
    verify,
)
from volucal.core.compensation.verify import (
    compensation_rates,
    positioning_figures,
    verification_points,
)


def test_rates_by_hand() -> None:
    before = np.array([[2.0, 1.0, 0.0], [-2.0, 3.0, 0.0]])
    after = np.array([[1.0, 1.0, 0.0], [-1.0, -1.0, 0.0]])
    rates = compensation_rates(before, after)
    assert rates.rms_percent["X"] == pytest.approx(50.0)
    assert rates.rms_percent["Y"] == pytest.approx(100 * (1 - 1 / np.sqrt(5)))
    assert rates.range_percent["X"] == pytest.approx(50.0)
    assert rates.range_percent["Y"] == pytest.approx(0.0)
    assert np.isnan(rates.rms_percent["Z"])  # nothing to compensate
    assert rates.max_after_um["Y"] == 1.0


def test_positioning_figures_by_hand() -> None:
    """ISO 230-2 with one run each way: E↑, E↓, E, M, B, mean reversal."""
    figures = positioning_figures([0.0, 2.0, 1.0], [-1.0, 1.0, 1.0])
    assert figures.E_up_um == 2.0
    assert figures.E_down_um == 2.0
    assert figures.E_um == 3.0
    assert figures.M_um == 2.0  # means -0.5, 1.5, 1.0
    assert figures.B_um == 1.0
    assert figures.mean_reversal_um == pytest.approx(2 / 3)


def test_verification_points_include_cell_centres() -> None:
    points = verification_points({"X": (0, 100), "Y": (0, 100), "Z": (0, 50)}, 50.0)
    assert len(points) == 3 * 3 * 2 + 2 * 2 * 1
    assert [25.0, 25.0, 25.0] in points.tolist()


def test_exact_compensation_of_the_true_model_removes_everything() -> None:
    source = ModelSource(paper_like_model())
    result = verify(source, standard_compensations(source, build_tables(source)))
    nc = result.methods["nc_rewriting"].rates
    assert min(nc.rms_percent.values()) > 99.999
    grid = result.methods["volumetric_grid"].rates
    assert min(grid.rms_percent.values()) > 95.0  # smooth errors, 25 mm trilinear grid
    assert result.approaches == (1,)
    assert "RMS" in result.rate_definition


def test_identification_error_limits_the_rate() -> None:
    """Compensating with a model 10 % too small leaves 10 % of the error: rate ≈ 90 %."""
    truth = ModelSource(paper_like_model(seed=4))
    identified = ModelSource(paper_like_model(seed=4).scaled(0.9))
    tables = build_tables(identified)
    result = verify(truth, standard_compensations(identified, tables))
    for value in result.methods["nc_rewriting"].rates.rms_percent.values():
        assert value == pytest.approx(90.0, abs=0.1)


def test_axis_tables_cannot_correct_squareness_but_cross_tables_can() -> None:
    source = ModelSource(linear_model({"EXX": 0.01}, squareness_urad={"EC0Y": 20.0}))
    result = verify(source, standard_compensations(source, build_tables(source)))
    axis_only = result.methods["axis_tables"].rates
    with_cross = result.methods["axis_and_cross_tables"].rates
    # E_x = 0.01·x − 0.02·y: the X table removes 0.01·x, the −0.02·y part stays.
    remaining = np.sqrt(
        np.mean(
            (0.02 * verification_points({"X": (0, 400), "Y": (0, 400), "Z": (0, 350)}, 25.0)[:, 1])
            ** 2
        )
    )
    assert axis_only.rms_after_um["X"] == pytest.approx(remaining, rel=1e-4)
    assert with_cross.rms_percent["X"] > 99.99
    assert result.methods["volumetric_grid"].rates.rms_percent["X"] > 99.99  # bilinear: exact


def test_reversal_is_left_by_the_grid_and_corrected_by_direction_tables() -> None:
    truth = ReversalSource(ModelSource(paper_like_model()), {"X": 6.0})
    result = verify(truth, standard_compensations(truth, build_tables(truth)))
    assert result.approaches == (1, -1)
    grid = result.methods["volumetric_grid"]
    assert grid.iso230_2["X"]["after"].B_um == pytest.approx(6.0, abs=1e-6)
    with_reversal = result.methods["volumetric_grid_and_reversal"]
    assert with_reversal.iso230_2["X"]["after"].B_um < 0.05
    assert with_reversal.rates.rms_percent["X"] > grid.rates.rms_percent["X"] + 20
    assert result.methods["nc_rewriting"].iso230_2["X"]["after"].B_um < 1e-6
    assert result.methods["axis_tables"].iso230_2["X"]["after"].B_um < 0.05
    before = grid.iso230_2["X"]["before"]
    assert before.B_um == pytest.approx(6.0) and before.mean_reversal_um == pytest.approx(6.0)


def test_verify_respects_the_request() -> None:
    source = ModelSource(paper_like_model())
    tables = build_tables(source)
    result = verify(
        source,
        standard_compensations(source, tables),
        VerifyRequest(grid_spacing_mm=50.0, tool_offset_mm=(0.0, 0.0, 100.0)),
    )
    assert result.grid_spacing_mm == 50.0
    assert result.tool_offset_mm == (0.0, 0.0, 100.0)
    assert result.points == 9 * 9 * 8 + 8 * 8 * 7
    document = result.to_json()
    assert set(document["methods"]) == set(result.methods)

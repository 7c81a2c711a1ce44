"""Error ids, aliases and signs; bases and their design matrices; gauges."""

import numpy as np
import pytest
from volucal.core.errors import (
    ERROR_IDS,
    ERROR_INFO,
    BSplineBasis,
    ConstantBasis,
    ErrorModel,
    NodeTableBasis,
    PolynomialBasis,
    basis_from_description,
    error_label,
    gauge_constraints,
    gauge_null_space,
)
from volucal.core.machine import PAPER_MACHINE

BASES = [
    ConstantBasis(0.0, 400.0),
    PolynomialBasis(0.0, 400.0, 4),
    BSplineBasis.uniform(0.0, 400.0, 50.0),
    BSplineBasis((0.0, 30.0, 100.0, 250.0, 400.0)),
    NodeTableBasis(tuple(np.linspace(0.0, 400.0, 11))),
]


def test_there_are_21_iso_ids_with_paper_aliases() -> None:
    assert len(ERROR_IDS) == 21
    assert ERROR_INFO["EXX"].paper == "δx(x)" and ERROR_INFO["EXX"].kind == "positioning"
    assert ERROR_INFO["ECY"].paper == "εz(y)" and ERROR_INFO["ECY"].unit == "urad"
    assert ERROR_INFO["EAX"].kind == "roll" and ERROR_INFO["EBY"].kind == "roll"
    assert ERROR_INFO["EZY"].kind == "straightness"
    # ISO EB0Z is minus the paper's Sxz; the other two squareness errors equal the paper's
    assert ERROR_INFO["EB0Z"].paper == "Sxz" and ERROR_INFO["EB0Z"].paper_sign == -1
    assert ERROR_INFO["EC0Y"].paper == "Sxy" and ERROR_INFO["EC0Y"].paper_sign == 1
    assert ERROR_INFO["EA0Z"].paper == "Syz" and ERROR_INFO["EA0Z"].paper_sign == 1
    assert error_label("EB0Z") == "EB0Z (−Sxz)"


@pytest.mark.parametrize("basis", BASES, ids=lambda b: b.kind)
def test_design_matrix_and_fast_evaluation_agree(basis) -> None:  # type: ignore[no-untyped-def]
    q = np.linspace(-10.0, 410.0, 97)  # beyond the stroke the ends are held
    c = np.random.default_rng(1).normal(size=basis.size)
    assert np.allclose(basis.design(q) @ c, basis.evaluate(q, c), atol=1e-12)
    assert np.allclose(basis.evaluate([-10.0], c), basis.evaluate([0.0], c))


@pytest.mark.parametrize("basis", BASES, ids=lambda b: b.kind)
def test_descriptions_round_trip(basis) -> None:  # type: ignore[no-untyped-def]
    again = basis_from_description(basis.describe())
    q = np.linspace(0.0, 400.0, 33)
    assert np.allclose(again.design(q), basis.design(q))


def test_bspline_partition_of_unity_and_table_interpolation() -> None:
    q = np.linspace(0.0, 400.0, 101)
    assert np.allclose(BSplineBasis.uniform(0, 400, 50).design(q).sum(axis=1), 1.0)
    table = NodeTableBasis((0.0, 100.0, 400.0))
    assert table.evaluate([50.0, 250.0], [0.0, 2.0, 8.0]) == pytest.approx([1.0, 5.0])


@pytest.mark.parametrize("straightness", [False, True])
def test_gauge_null_space_satisfies_the_gauge(straightness: bool) -> None:
    basis = BSplineBasis.uniform(0.0, 400.0, 50.0)
    null = gauge_null_space(basis, 100.0, straightness)
    assert null.shape[1] == basis.size - (2 if straightness else 1)
    assert np.allclose(gauge_constraints(basis, 100.0, straightness) @ null, 0.0, atol=1e-12)
    f = null @ np.random.default_rng(2).normal(size=null.shape[1])
    assert basis.evaluate([100.0], f)[0] == pytest.approx(0.0, abs=1e-12)
    if straightness:
        q = np.linspace(0.0, 400.0, 801)
        assert np.polyfit(q, basis.evaluate(q, f), 1)[0] == pytest.approx(0.0, abs=1e-12)


def test_parameter_vector_round_trip() -> None:
    model = ErrorModel.zero(PAPER_MACHINE)
    p = np.random.default_rng(3).normal(size=model.parameter_count)
    again = model.with_parameters(p)
    assert np.allclose(again.parameters, p)
    assert again.squareness_urad["EA0Z"] == p[-1]

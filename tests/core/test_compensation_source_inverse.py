"""Error sources and the iterated inverse, against hand-worked answers."""

from __future__ import annotations

import numpy as np
import pytest
from compensation_models import linear_model, paper_like_model
from volucal.core.compensation import ErrorSource, ModelSource, ReversalSource, as_source, invert
from volucal.core.compensation.source import measured_range, rigid_model
from volucal.core.kinematics import naive_error
from volucal.core.machine import PAPER_MACHINE
from volucal.core.userror import UserError


def test_model_source_is_the_exact_chain() -> None:
    model = paper_like_model()
    points = np.array([[0, 0, 0], [400, 400, 350], [123.4, 56.7, 289.0]])
    np.testing.assert_allclose(
        ModelSource(model).error_um(points), naive_error(model, points), atol=1e-9
    )
    assert isinstance(ModelSource(model), ErrorSource)
    assert rigid_model(ModelSource(model)) is model


def test_reversal_source_adds_half_the_reversal_by_direction() -> None:
    base = ModelSource(paper_like_model())
    source = ReversalSource(base, {"X": 3.0, "Z": lambda z: 1.0 + 0.01 * z})
    points = np.array([[100.0, 50.0, 200.0], [300.0, 10.0, 0.0]])
    up = source.error_um(points, np.ones(3))
    down = source.error_um(points, -np.ones(3))
    # ISO 230-2 sign: reversal = approached from below minus from above.
    np.testing.assert_allclose(up[:, 0] - down[:, 0], [3.0, 3.0])
    np.testing.assert_allclose(up[:, 1] - down[:, 1], [0.0, 0.0])
    np.testing.assert_allclose(up[:, 2] - down[:, 2], [3.0, 1.0])
    np.testing.assert_allclose(source.error_um(points), base.error_um(points))
    np.testing.assert_allclose((up + down) / 2, base.error_um(points), atol=1e-12)
    mixed = source.error_um(points, np.array([[1, 1, -1], [-1, 1, 1]]))
    np.testing.assert_allclose(mixed[:, 0] - base.error_um(points)[:, 0], [1.5, -1.5])
    assert rigid_model(source) is base.model
    assert measured_range(source) == {a: PAPER_MACHINE.stroke(a) for a in "XYZ"}


def test_reversal_source_rejects_bad_input() -> None:
    base = ModelSource(paper_like_model())
    with pytest.raises(ValueError, match="unknown axis"):
        ReversalSource(base, {"W": 1.0})
    with pytest.raises(ValueError, match=r"\+1"):
        ReversalSource(base, {"X": 1.0}).error_um(np.zeros((1, 3)), np.array([0.5, 1, 1]))


def test_inverse_of_a_scale_error_is_hand_computable() -> None:
    """E_x = s·x (µm, s in µm/mm): c + s·c/1000 = n gives c = n / (1 + s/1000)."""
    s = 25.0  # an exaggerated 25 µm/mm so the second-order term is visible
    source = ModelSource(linear_model({"EXX": s}))
    nominal = np.array([[0.0, 0, 0], [100.0, 0, 0], [400.0, 0, 0]])
    result = invert(source, nominal)
    np.testing.assert_allclose(result.commanded_mm[:, 0], nominal[:, 0] / (1 + s / 1000), atol=1e-9)
    np.testing.assert_allclose(result.commanded_mm[:, 1:], 0.0, atol=1e-12)
    assert result.residual_um < 1e-6
    np.testing.assert_allclose(result.correction_um, (result.commanded_mm - nominal) * 1e3)


def test_inverse_lands_on_nominal_for_a_realistic_machine() -> None:
    source = ReversalSource(ModelSource(paper_like_model(seed=2)), {"Y": 5.0})
    rng = np.random.default_rng(0)
    nominal = rng.uniform([0, 0, 0], [400, 400, 350], size=(500, 3))
    approach = rng.choice([-1.0, 1.0], size=(500, 3))
    result = invert(source, nominal, approach)
    actual = result.commanded_mm + source.error_um(result.commanded_mm, approach) / 1e3
    np.testing.assert_allclose(actual, nominal, atol=1e-9)
    assert result.iterations <= 5


class _Steep:
    """A source whose 'error' grows 2 mm per mm: not a machine tool."""

    machine = PAPER_MACHINE

    def error_um(self, positions_mm, approach=None, tool_offset_mm=None):
        return np.asarray(positions_mm, dtype=float) * 2000.0


def test_inverse_reports_divergence_as_a_user_error() -> None:
    with pytest.raises(UserError, match="did not converge"):
        invert(_Steep(), np.array([[10.0, 0, 0]]))


def test_as_source_wraps_models_and_rejects_other_objects() -> None:
    assert isinstance(as_source(paper_like_model()), ModelSource)
    with pytest.raises(TypeError, match="ErrorModel"):
        as_source(object())  # type: ignore[arg-type]

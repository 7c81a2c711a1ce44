"""The volumetric error model: exact chain, first-order form (paper eq. 6), Jacobian, grids."""

import numpy as np
import pytest
from volucal.core import kinematics as K
from volucal.core.errors import (
    AXIS_ERROR_IDS,
    ERROR_IDS,
    SQUARENESS_IDS,
    BSplineBasis,
    ErrorFunction,
    ErrorModel,
    NodeTableBasis,
    PolynomialBasis,
)
from volucal.core.machine import PAPER_MACHINE, Machine, MachineError
from volucal.core.simulate import random_truth


def _random_model(
    seed: int = 1, machine: Machine = PAPER_MACHINE, scale: float = 5.0
) -> ErrorModel:
    zero = ErrorModel.zero(machine)
    rng = np.random.default_rng(seed)
    return zero.with_parameters(rng.normal(0, scale, zero.parameter_count))


def _points(n: int, seed: int = 2) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform([0, 0, 0], [400, 400, 350], (n, 3))


def paper_eq6_first_order(model: ErrorModel, q: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The linear terms of the paper's eq. 6, transcribed in the paper's symbols.

    Sxy = EC0Y, Syz = EA0Z, Sxz = −EB0Z. Translations µm, angles µrad, lengths mm.
    """
    x, y, z = q.T
    d1, d2, d3 = d

    def v(eid: str, axis: int) -> np.ndarray:
        return model.functions[eid](q[:, axis])

    u = 1e-3  # mm·µrad -> µm
    dx = {a: v(f"EX{a}", i) for i, a in enumerate("XYZ")}
    dy = {a: v(f"EY{a}", i) for i, a in enumerate("XYZ")}
    dz = {a: v(f"EZ{a}", i) for i, a in enumerate("XYZ")}
    ex = {a: v(f"EA{a}", i) for i, a in enumerate("XYZ")}
    ey = {a: v(f"EB{a}", i) for i, a in enumerate("XYZ")}
    ez = {a: v(f"EC{a}", i) for i, a in enumerate("XYZ")}
    sxy = model.squareness_urad["EC0Y"]
    syz = model.squareness_urad["EA0Z"]
    sxz = -model.squareness_urad["EB0Z"]
    e_x = (
        dx["Z"]
        + dx["X"]
        + dx["Y"]
        - y * (ez["X"] + sxy) * u
        + d2 * (-ez["X"] - ez["Y"] - ez["Z"]) * u
        + z * (ey["X"] + ey["Y"] - sxz) * u
        + d3 * (ey["X"] + ey["Y"] + ey["Z"]) * u
    )
    e_y = (
        dy["Z"]
        + dy["X"]
        + dy["Y"]
        + d1 * (ez["Y"] + ez["X"] + ez["Z"]) * u
        - z * (ex["X"] + ex["Y"] + syz) * u
        - d3 * (ex["X"] + ex["Y"] + ex["Z"]) * u
    )
    e_z = (
        dz["Z"]
        + dz["X"]
        + dz["Y"]
        + y * ex["X"] * u
        + d1 * (-ey["X"] - ey["Y"] - ey["Z"]) * u
        + d2 * (ex["X"] + ex["Y"] + ex["Z"]) * u
    )
    return np.stack([e_x, e_y, e_z], axis=-1)


def _single_error_model(eid: str, seed: int) -> ErrorModel:
    model = _random_model(seed)
    p = np.zeros(model.parameter_count)
    rng = np.random.default_rng(seed)
    sl = model.parameter_slices[eid]
    p[sl] = rng.normal(0, 10, sl.stop - sl.start)
    return model.with_parameters(p)


@pytest.mark.parametrize("eid", ERROR_IDS)
def test_first_order_matches_paper_eq6_term_by_term(eid: str) -> None:
    model = _single_error_model(eid, seed=ERROR_IDS.index(eid) + 3)
    q = _points(200)
    rng = np.random.default_rng(7)
    for _ in range(3):
        d = rng.uniform(-250, 250, 3)
        ours = K.first_order_error(model, q, d)
        paper = paper_eq6_first_order(model, q, d)
        assert np.allclose(ours, paper, atol=1e-9), eid


def test_first_order_matches_eq6_with_all_errors_and_free_tool_offset() -> None:
    model = _random_model(11)
    q = _points(500)
    d = np.array([35.0, -60.0, 180.0])
    assert np.allclose(
        K.first_order_error(model, q, d), paper_eq6_first_order(model, q, d), atol=1e-9
    )


def test_exact_minus_first_order_scales_with_the_square_of_the_errors() -> None:
    model = _random_model(3, scale=20.0)
    q = _points(400)
    gaps = []
    for factor in (1.0, 2.0, 4.0, 8.0):
        scaled = model.scaled(factor)
        gap = K.volumetric_error(scaled, q) - K.first_order_error(scaled, q)
        gaps.append(np.max(np.abs(gap)))
    ratios = np.array(gaps[1:]) / np.array(gaps[:-1])
    assert np.allclose(ratios, 4.0, rtol=0.02), ratios
    # and the second-order gap is tiny for realistic errors
    assert gaps[0] < 1e-2 * np.max(np.abs(K.volumetric_error(model, q)))


def test_exact_chain_matches_naive_homogeneous_products() -> None:
    model = _random_model(5)
    q = _points(60)
    tool = np.array([12.0, -30.0, 150.0])
    assert np.allclose(K.volumetric_error(model, q, tool), K.naive_error(model, q, tool), atol=1e-9)


def test_per_point_tool_offsets() -> None:
    model = _random_model(6)
    q = _points(40)
    tools = np.random.default_rng(1).uniform(-100, 250, (40, 3))
    vm = K.VolumetricModel(model)
    expected = np.array([K.naive_error(model, q[i : i + 1], tools[i])[0] for i in range(40)])
    assert np.allclose(vm.error(q, tools), expected, atol=1e-9)


def test_compose_error_with_values_per_point_matches_the_model() -> None:
    model = _random_model(8)
    q = _points(300)
    values = {a: model.axis_values(a, q[:, i]) for i, a in enumerate("XYZ")}
    composed = K.compose_error(model.machine, q, values, model.squareness_urad)
    assert np.allclose(composed, K.volumetric_error(model, q), atol=1e-9)


def test_jacobian_against_finite_differences_of_the_exact_chain() -> None:
    model = _random_model(9, scale=50.0)
    q = _points(15)
    tool = np.array([20.0, 10.0, 200.0])
    jac = K.jacobian(model, q, tool)
    p0 = model.parameters
    h = 1e-2
    for i in range(model.parameter_count):
        up, down = p0.copy(), p0.copy()
        up[i] += h
        down[i] -= h
        fd = (
            K.volumetric_error(model.with_parameters(up), q, tool)
            - K.volumetric_error(model.with_parameters(down), q, tool)
        ) / (2 * h)
        assert np.allclose(jac[:, :, i], fd, atol=1e-7), i


def test_grid_error_equals_pointwise_evaluation() -> None:
    model = _random_model(10)
    vm = K.VolumetricModel(model)
    xs, ys, zs = np.linspace(0, 400, 5), np.linspace(0, 400, 4), np.linspace(0, 350, 3)
    for i, e in vm.grid_error(xs, ys, zs):
        yy, zz = np.meshgrid(ys, zs, indexing="ij")
        points = np.stack([np.full(yy.size, xs[i]), yy.ravel(), zz.ravel()], axis=-1)
        assert np.allclose(e.reshape(-1, 3), vm.error(points), atol=1e-9)


def test_another_chain_uses_its_own_lever_arms() -> None:
    """In "WYXFZT" Y comes first, so a yaw of Y acts through x (it cannot in "WXYFZT")."""
    machine = Machine(chain="WYXFZT", tool_offset_mm=(0.0, 0.0, 0.0))
    basis = PolynomialBasis(0.0, 400.0, 1)
    zero = ErrorModel.zero(
        machine, lambda a, e: basis if a == "Y" else PolynomialBasis(*machine.stroke(a), 1)
    )
    functions = dict(zero.functions)
    # ECY(y) = 10 µrad at y = 400 (linear, zero at 0): P0 + P1 with s = (2y - 400)/400
    functions["ECY"] = ErrorFunction("ECY", basis, np.array([5.0, 5.0]))
    model = ErrorModel(machine, functions)
    q = np.array([[300.0, 400.0, 100.0]])
    e = K.volumetric_error(model, q)[0]
    assert e[1] == pytest.approx(300.0 * 10e-6 * 1e3, rel=1e-4)  # E_y = x·ECY
    paper_machine = ErrorModel(PAPER_MACHINE, functions)
    assert K.volumetric_error(paper_machine, q)[0][1] == pytest.approx(0.0, abs=1e-9)


def test_rotation_error_is_the_sum_of_the_axes_angles_at_first_order() -> None:
    model = _random_model(12)
    q = _points(100)
    expected = sum(model.axis_values(a, q[:, i])[:, 3:] for i, a in enumerate("XYZ"))
    assert np.allclose(K.rotation_error(model, q), expected, atol=1e-3)


def test_every_basis_evaluates_through_the_piecewise_tables() -> None:
    machine = PAPER_MACHINE
    bases = {
        "X": PolynomialBasis(0.0, 400.0, 5),
        "Y": NodeTableBasis(tuple(np.linspace(0.0, 400.0, 9))),
        "Z": BSplineBasis.uniform(0.0, 350.0, 35.0),
    }
    zero = ErrorModel.zero(machine, lambda a, e: bases[a])
    model = zero.with_parameters(np.random.default_rng(4).normal(0, 3, zero.parameter_count))
    q = _points(200)
    assert np.allclose(K.volumetric_error(model, q), K.naive_error(model, q), atol=1e-9)


def test_truth_is_in_the_gauge() -> None:
    truth = random_truth(seed=4)
    for eid in AXIS_ERROR_IDS:
        f = truth.functions[eid]
        assert abs(f(0.0)) < 1e-9
        if truth.functions[eid].info.is_straightness:
            q = np.linspace(f.basis.low, f.basis.high, 801)
            slope = np.polyfit(q, f(q), 1)[0]
            assert abs(slope) < 1e-9
    assert set(truth.squareness_urad) == set(SQUARENESS_IDS)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"chain": "WXYQZT"}, "machine.chain"),
        ({"chain": "WXYZT"}, "machine.chain"),
        ({"stroke_mm": {"X": (0, 400), "Y": (400, 0), "Z": (0, 350)}}, "machine.stroke.Y"),
        ({"stroke_mm": {"X": (0, float("nan")), "Y": (0, 400), "Z": (0, 350)}}, "machine.stroke.X"),
        ({"tool_offset_mm": (0, 0, float("inf"))}, "machine.tool_offset"),
        ({"reference_mm": (0, 0, 500)}, "machine.reference.Z"),
        ({"screw_lead_mm": {"X": -16}}, "machine.screw_lead.X"),
    ],
)
def test_bad_machine_values_name_the_field(kwargs: dict, field: str) -> None:
    with pytest.raises(MachineError, match=field.replace(".", r"\.")):
        Machine(**kwargs)

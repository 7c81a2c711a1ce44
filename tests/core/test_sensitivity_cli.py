"""``volucal sensitivity`` and ``volucal paper`` from the command line."""

import json

import numpy as np
import pytest
from volucal.core import project as project_module
from volucal.core.cli import main
from volucal.core.errors import ERROR_IDS, ErrorModel, PolynomialBasis
from volucal.core.kinematics import compose_error
from volucal.core.machine import PAPER_MACHINE
from volucal.core.paper import table2_iso
from volucal.core.sensitivity import SensitivityResult


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _linear_truth(point):
    """c_i²σ_i²/Σc_j²σ_j² of Ex, Ey, Ez under Table 2, from differences of compose_error."""
    table = table2_iso()
    mean = np.array([table[i][0] for i in ERROR_IDS])
    sd = np.array([table[i][1] for i in ERROR_IDS])
    rows = np.repeat(mean[None], 42, axis=0)
    for k in range(21):
        rows[2 * k, k] += 1e-3
        rows[2 * k + 1, k] -= 1e-3
    per_axis = {a: rows[:, 6 * k : 6 * k + 6] for k, a in enumerate("XYZ")}
    square = {s: rows[:, 18 + k] for k, s in enumerate(("EC0Y", "EB0Z", "EA0Z"))}
    error = compose_error(PAPER_MACHINE, np.broadcast_to(point, (42, 3)), per_axis, square)
    slope = (error[0::2] - error[1::2]) / 2e-3
    share = slope**2 * sd[:, None] ** 2
    return share / share.sum(axis=0)


def test_preset_at_one_position_in_the_report_shape(capsys):
    code, out, err = _run(capsys, "sensitivity", "--preset", "paper", "--position", "200,200,175",
                          "--json")
    assert code == 0, err
    document = json.loads(out)
    sensitivity = document["sensitivity"]
    assert set(sensitivity) == {"Ex", "Ey", "Ez", "ET"}
    assert set(sensitivity["Ex"]["S1"]) == set(ERROR_IDS)
    assert "Sxz" not in sensitivity["Ex"]["S1"]
    truth = _linear_truth(np.array([200.0, 200.0, 175.0]))
    for k, output in enumerate(("Ex", "Ey", "Ez")):
        ours = np.array([sensitivity[output]["S1"][i] for i in ERROR_IDS])
        total = np.array([sensitivity[output]["ST"][i] for i in ERROR_IDS])
        np.testing.assert_allclose(ours, truth[:, k], atol=0.02)
        np.testing.assert_allclose(total, truth[:, k], atol=0.02)
    settings = document["settings"]
    assert settings["n"] == 1400 and settings["m"] == 4 and settings["seed"] == 0
    assert document["positions_mm"] == [[200.0, 200.0, 175.0]]


def test_preset_text_names_paper_symbols_beside_iso_ids(capsys):
    code, out, _ = _run(capsys, "sensitivity", "--preset", "paper", "--position", "200,200,350",
                        "--output", "Ex", "--repeats", "2", "--tool-offset", "0,0,100")
    assert code == 0
    assert "EB0Z (−Sxz)" in out
    assert "tool offset 0, 0, 100 mm" in out
    assert "Ey:" not in out


def test_preset_map_gives_every_point(capsys):
    code, out, _ = _run(capsys, "sensitivity", "--preset", "paper", "--map", "200", "--output",
                        "ET", "--n", "400", "--repeats", "1", "--json")
    assert code == 0
    document = json.loads(out)
    assert len(document["positions_mm"]) == 27
    assert len(document["map"]["ET"]["S1"]) == 27
    assert document["sensitivity"]["ET"]["S1_std"]["EXX"] is None  # one repeat: no spread


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--preset", "paper", "--positions", "noise"], "refused"),
        (["--preset", "paper", "--position", "1,2"], "expected three numbers"),
        (["--preset", "paper", "--position", "0,0,500"], "outside the stroke"),
        (["--preset", "paper", "--output", "Eq"], "use Ex, Ey, Ez, ET"),
        (["--preset", "paper", "--n", "40"], "N > 4·M²"),
        ([], "either PROJECT.h5 or --preset paper"),
        (["missing.h5"], "no such project file"),
    ],
)
def test_bad_input_is_one_clear_line(capsys, argv, message):
    code, out, err = _run(capsys, "sensitivity", *argv)
    assert code == 1
    assert message in err
    assert "Traceback" not in err and err.count("\n") == 1


def _project(tmp_path, with_covariance=True):
    machine = PAPER_MACHINE
    model = ErrorModel.zero(machine, lambda axis, eid: PolynomialBasis(*machine.stroke(axis), 2))
    rng = np.random.default_rng(1)
    model = model.with_parameters(rng.normal(0, 3.0, model.parameter_count))
    tree = {"model": project_module.error_model_to_tree(model)}
    if with_covariance:
        tree["covariance"] = np.diag(rng.uniform(0.05, 0.5, model.parameter_count) ** 2)
    project = project_module.Project.create(machine)
    project.put_result("identifications", "fit", tree)
    path = tmp_path / "machine.h5"
    project.save(path)
    return path


def test_project_analysis_is_stored_in_the_project(tmp_path, capsys):
    path = _project(tmp_path)
    code, out, err = _run(capsys, "sensitivity", path, "--position", "100,300,50", "--n", "600",
                          "--repeats", "2", "--json", "--name", "point")
    assert code == 0, err
    document = json.loads(out)
    assert document["settings"]["problem"]["identified"] is True
    stored = project_module.Project.open(path).result("sensitivity", "point")
    assert stored["identification"] == "fit"
    result = SensitivityResult.from_tree(stored)
    assert result.outputs == ("Ex", "Ey", "Ez", "ET")
    assert result.indices("Ex", "S1")["EXX"] == pytest.approx(
        document["sensitivity"]["Ex"]["S1"]["EXX"]
    )


def test_project_map_design_and_noise(tmp_path, capsys):
    path = _project(tmp_path, with_covariance=False)
    code, out, err = _run(capsys, "sensitivity", path, "--output", "Ez", "--n", "300",
                          "--repeats", "1", "--map", "200")
    assert code == 0, err
    assert "workspace-averaged" in out
    code, out, err = _run(capsys, "sensitivity", path, "--output", "Ex", "--n", "300",
                          "--repeats", "1", "--json")
    assert code == 0, err
    document = json.loads(out)
    assert document["positions_mm"] is None  # X, Y, Z were design factors
    assert set(document["sensitivity"]["Ex"]["positions"]["S1"]) == {"X", "Y", "Z"}
    code, _, err = _run(capsys, "sensitivity", path, "--positions", "noise")
    assert code == 1 and "refused" in err


def test_paper_command_reports_both_sides_and_the_assumptions(capsys):
    code, out, err = _run(capsys, "paper", "--repeats", "2", "--grid-step", "200", "--json")
    assert code == 0, err
    document = json.loads(out)
    assumptions = " ".join(document["assumptions"].values())
    assert "N = 1400" in assumptions and "D1, D2, D3 = 0, 0, 200 mm" in assumptions
    rows = {r["id"]: r for r in document["S1"]["Ex"]}
    assert rows["EXX"]["paper"] == 0.30 and rows["EB0Z"]["symbol"] == "−Sxz"
    assert rows["EB0Z"]["map"] > 0.5
    findings = " ".join(document["findings"])
    assert "gives 0.91 µm against the printed 0.81 µm" in findings
    assert "gives 0.74 µm against the printed 0.54 µm" in findings
    table3 = {r["id"]: r for r in document["table3"]}
    assert table3["EXX"]["paper"] == 0.97
    assert set(document["design_positions"]["Ex"]["S1"]) == {"X", "Y", "Z"}

"""Thermal error model on the real spindle record: held-out error against the baselines, and time.

Targets (issue 15), on ../shared/realdata/sjtu_spindle_thermal (axial thermal elongation ΔL in µm
and 16 temperatures, one sample a minute, 4,683 rows), trained on the first 40 % of the time and
tested on the rest:

- a plain static least-squares fit on all 16 temperatures leaves 1.14 µm RMS held out, the best
  single sensor 1.25 µm (uncompensated 15.1 µm);
- volucal's chosen model: at most 0.75 µm held out, with at most 6 sensors;
- choosing, fitting and validating in under 5 s.

Honesty: volucal's choice (sensors, time constants, squared terms) is made on the first 40 %
alone, by rolling-origin cross-validation inside it; the last 60 % is touched once, for the final
figure. The "best single sensor" baseline is the best of the 16 *on the test part* (hindsight, as
the issue states it): an optimistic baseline, printed beside the one chosen by cross-validation.

Run: ``python benchmarks/bench_thermal.py`` (prints the figures; exit code 1 if a target is
missed). Timings on a loaded machine are indicative only.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from volucal.core.io.thermal_table import ErrorColumn, ThermalTableFormat, read_thermal_table
from volucal.core.thermal_fit import ThermalFitOptions, ThermalFitRequest, fit_thermal
from volucal.core.thermal_model import ThermalTerm, fit_model

REPO = Path(__file__).resolve().parents[1]
RELATIVE = Path("sjtu_spindle_thermal") / "thermal_expansion_error_original.csv"
CANDIDATES = (REPO.parent / "shared" / "realdata", Path("/work/shared/realdata"))
TRAIN_FRACTION = 0.4
TARGET_RMS_UM = 0.75
MAX_SENSORS = 6
TARGET_SECONDS = 5.0


def rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def main() -> int:
    path = next((c / RELATIVE for c in CANDIDATES if (c / RELATIVE).is_file()), None)
    if path is None:
        print("the real spindle record is not on this machine (../shared/realdata); nothing to "
              "measure")
        return 0
    started = time.perf_counter()
    record = read_thermal_table(path, ThermalTableFormat(
        errors=(ErrorColumn("delta L", "um"),), temperature_unit="C", sample_interval_s=60.0))
    read_s = time.perf_counter() - started
    fit_started = time.perf_counter()
    result = fit_thermal(ThermalFitRequest(record, options=ThermalFitOptions(
        train_fraction=TRAIN_FRACTION, max_sensors=MAX_SENSORS)))
    fit_s = time.perf_counter() - fit_started

    y = record.errors[0].values
    temps = record.temperature_map()
    train = slice(0, result.train_samples)
    test = slice(result.train_samples, None)
    singles = {}
    for sensor in record.sensor_names:
        model = fit_model("delta L", "um", record.time_s, y, temps, [ThermalTerm(sensor)], train,
                          covariance=False)
        singles[sensor] = rms((y - model.predict(record.time_s, temps))[test])
    hindsight = min(singles, key=singles.__getitem__)
    baselines = {b.name: b for b in result.baselines}
    everything = baselines["all sensors, static least squares"]
    by_cv = baselines["best single sensor by cross-validation"]

    print(f"{path.name}: {record.samples} samples, {len(record.sensor_names)} sensors; "
          f"trained on the first {result.train_samples} ({100 * TRAIN_FRACTION:g} %), tested "
          f"on {result.test_samples}")
    print(f"{'held-out RMS, µm':<58}{'µm':>8}")
    print(f"  {'uncompensated':<56}{result.uncompensated_test_rms:8.3f}")
    print(f"  {'static least squares, all 16 sensors':<56}{everything.test_rms:8.3f}")
    print(f"  {f'best single sensor in hindsight ({hindsight})':<56}{singles[hindsight]:8.3f}")
    print(f"  {f'best single sensor by CV on the training part ({by_cv.sensors[0]})':<56}"
          f"{by_cv.test_rms:8.3f}")
    label = f"volucal model ({len(result.model.sensors)} sensors: " \
            f"{', '.join(result.model.sensors)})"
    print(f"  {label:<56}{result.test_rms:8.3f}")
    print(f"  model: {result.model.formula()}")
    for decision in result.decisions:
        print(f"    {decision}")
    print(f"  cross-validated RMS on the training part {result.cv_rms:.3f} µm; "
          f"coefficient std (Newey–West): "
          + ", ".join(f"{s:.3f}" for s in result.model.coefficient_std))
    print(f"time: read {read_s:.2f} s, choose + fit + validate {fit_s:.2f} s "
          f"(target < {TARGET_SECONDS:g} s)")
    print("sensitivity of the held-out figure to volucal's CV settings (each row a full, "
          "honest run; not used for the choice above)")
    windows = (0.4, 0.5, 0.6, 0.7)
    print(f"  {'blocks / initial window':<26}" + "".join(f"{w:>10g}" for w in windows))
    for blocks in (5, 10, 20):
        cells = []
        for window in windows:
            other = fit_thermal(ThermalFitRequest(record, options=ThermalFitOptions(
                train_fraction=TRAIN_FRACTION, blocks=blocks, initial_fraction=window)))
            cells.append(f"{other.test_rms:.3f}/{len(other.model.sensors)}")
        print(f"  {blocks:<26}" + "".join(f"{c:>10}" for c in cells))
    print("  (held-out RMS µm / sensors)")
    met = (result.test_rms <= TARGET_RMS_UM and len(result.model.sensors) <= MAX_SENSORS
           and fit_s < TARGET_SECONDS)
    print(f"targets: held-out ≤ {TARGET_RMS_UM} µm with ≤ {MAX_SENSORS} sensors in < "
          f"{TARGET_SECONDS:g} s: {'met' if met else 'MISSED'}")
    return 0 if met else 1


if __name__ == "__main__":
    sys.exit(main())

"""`DeployReport`: a deploy's per-tick figures in fixed memory, summarised as NumPy would on the whole series."""

import numpy as np

from wbmpc.hardware.deploy_report import DeployReport


def test_an_hour_of_ticks_is_summarised_in_fixed_memory():
    rng = np.random.default_rng(3)
    n = 36_000  # a minute and more at 500 Hz; the memory does not depend on it
    tick = rng.gamma(2.0, 0.1, n)
    age = rng.uniform(0.0, 25.0, n)
    error = rng.uniform(0.0, 0.02, n)
    xy = np.cumsum(rng.normal(0.0, 1e-3, (n, 2)), axis=0)
    report = DeployReport()
    held = report.tick_ms.nbytes + report.plan_age_ms.nbytes
    report.phases = [(0.0, "mpc"), (72.0, "lie-down")]
    for k in range(n):
        report.tick_ms.add(tick[k])
        report.plan_age_ms.add(age[k])
        report.record_ee_error(error[k])
        report.record_position(xy[k])
    summary = report.summary()
    assert report.tick_ms.nbytes + report.plan_age_ms.nbytes == held and len(report.estimated_xy_m) == 2
    assert abs(summary["controller_tick_ms_p99"] - np.percentile(tick, 99)) <= report.tick_ms.resolution
    assert abs(summary["plan_age_ms_p50"] - np.percentile(age, 50)) <= report.plan_age_ms.resolution
    assert summary["plan_age_ms_max"] == age.max()
    assert np.isclose(summary["ee_rmse_estimated_m"], np.sqrt(np.mean(error ** 2)), rtol=1e-12)
    assert np.isclose(summary["estimated_drift_cm_s"], 100 * np.linalg.norm(xy[-1] - xy[0]) / 72.0, rtol=1e-12)
    assert DeployReport().summary()["controller_tick_ms_p50"] is None  # nothing measured: no figure

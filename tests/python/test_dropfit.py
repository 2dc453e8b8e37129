"""The Python module (python/), as installed: CTest runs this file with
PYTHONPATH at the staging install prefix (tests/CMakeLists.txt,
python_pytest). Expected values are physics worked out here, or the
generator's truth for samples/demo-session."""
import json
import math
import os
import pathlib

import numpy as np
import pytest

import dropfit

SOURCE = pathlib.Path(os.environ.get("DROPFIT_SOURCE_DIR", pathlib.Path(__file__).resolve().parents[2]))
DEMO = SOURCE / "samples" / "demo-session"
G = 9.81


def test_imported_from_the_install_prefix():
    # PYTHONPATH names the prefix's package folder: the module there, not a
    # build tree's, is the one under test.
    path = os.environ.get("PYTHONPATH")
    if not path:
        pytest.skip("PYTHONPATH not set (run through CTest)")
    assert pathlib.Path(dropfit.__file__).resolve().is_relative_to(pathlib.Path(path).resolve())


def spring_peak_n(k, m, v0):
    # m y'' = m g - k y from y = 0, y' = v0: y_max = mg/k + sqrt((mg/k)^2 + m v0^2 / k).
    return m * G + math.sqrt((m * G) ** 2 + k * m * v0 ** 2)


def spring_contact_s(k, m, v0):
    # y = a (1 - cos wt) + b sin wt with a = mg/k, b = v0/w; back at y = 0 at
    # wt = 2 (pi - atan2(b, a)).
    w = math.sqrt(k / m)
    return 2.0 * (math.pi - math.atan2(v0 / w, m * G / k)) / w


def test_simulate_a_spring_mat_matches_the_closed_form():
    fit = dropfit.Fit("model1", {"k1_n_m": 1.0e5, "r1_n_s_m": 0.0}, impactor_mass_kg=24.0)
    sim = dropfit.simulate(fit, velocity_m_s=5.0, dt_s=1e-4, duration_s=0.3)
    assert isinstance(sim["t_s"], np.ndarray) and sim["t_s"].shape == sim["grf_n"].shape
    assert sim["t_s"][1] - sim["t_s"][0] == pytest.approx(1e-4)
    # Sampled every 0.1 ms, the peak is within 1e-5 of the closed form.
    assert sim["grf_n"].max() == pytest.approx(spring_peak_n(1.0e5, 24.0, 5.0), rel=1e-4)
    assert sim["separation_s"] == pytest.approx(spring_contact_s(1.0e5, 24.0, 5.0), abs=2e-4)
    # A heavier impactor (mass_kg overrides the fit's).
    heavy = dropfit.simulate(fit, velocity_m_s=5.0, mass_kg=48.0, dt_s=1e-4)
    assert heavy["grf_n"].max() == pytest.approx(spring_peak_n(1.0e5, 48.0, 5.0), rel=1e-4)


def test_fit_round_trips_through_fit_json(tmp_path):
    params = {"k1_n_m": 72075.0, "k2_n_m": 1061532.0, "k3_n_m": 748625.0, "r1_n_s_m": 263.0,
              "r2_n_s_m": 761.0, "r3_n_s_m": 1007.0, "m1_kg": 2.44, "m2_kg": 3.66}
    path = tmp_path / "fit.json"
    path.write_text(json.dumps({"model": "model4", "impactor_mass_kg": 23.5, "parameters": params}))
    fit = dropfit.read_fit(str(path))
    assert fit.model == "model4"
    assert fit.impactor_mass_kg == 23.5
    assert fit.parameters == pytest.approx(params)


def test_bad_input_raises_dropfit_errors(tmp_path):
    path = tmp_path / "fit.json"
    path.write_text('{"model": "model4", "parameters": {"k1_n_m": "stiff"}}')
    with pytest.raises(dropfit.InputError, match="fit.json"):
        dropfit.read_fit(str(path))
    assert issubclass(dropfit.InputError, dropfit.Error)
    with pytest.raises(dropfit.Error):
        dropfit.MatContact("model5", {"k1_n_m": 7e4})  # Model 5 cannot be co-simulated
    with pytest.raises(dropfit.Error, match="unknown mat parameter"):
        dropfit.Fit("model1", {"k9_n_m": 1.0})
    mat = dropfit.MatContact("model1", {"k1_n_m": 1e5, "r1_n_s_m": 100.0})
    with pytest.raises(dropfit.Error):
        mat.step(0.001, 1.0, 0.0)  # dt must be positive


def test_contact_follows_a_prescribed_foot_exactly():
    # Model 1 is massless: while the foot presses, foot = grf = k y + r y'.
    k, r = 1.0e5, 300.0
    mat = dropfit.MatContact("model1", {"k1_n_m": k, "r1_n_s_m": r})
    dt = 1e-4
    t = np.arange(1, 201) * dt
    y = 0.01 * np.sin(2 * np.pi * 10 * t)        # 10 Hz, 10 mm: presses for the first half cycle
    v = 0.01 * 2 * np.pi * 10 * np.cos(2 * np.pi * 10 * t)
    mat.reset(0.0, v[0])
    foot, grf = mat.step_many(y, v, dt)
    pressing = (y > 1e-4) & (k * y + r * v > 0)
    assert pressing.sum() > 20
    np.testing.assert_allclose(foot[pressing], (k * y + r * v)[pressing], rtol=1e-6)
    np.testing.assert_allclose(grf[pressing], foot[pressing], rtol=1e-6)
    assert np.all(foot >= 0.0)  # the mat never pulls


def test_closed_loop_landing_on_a_spring_mat():
    # A caller's own integrator (semi-implicit Euler, 0.01 ms) landing 24 kg
    # at 5 m/s: the peak force is the closed form's within 0.5 %.
    k, m, dt = 1.0e5, 24.0, 1e-5
    mat = dropfit.MatContact(dropfit.Fit("model1", {"k1_n_m": k, "r1_n_s_m": 0.0}))
    y, v, peak = 0.0, 5.0, 0.0
    mat.reset(y, v)
    for _ in range(int(0.2 / dt)):
        y += v * dt
        f = mat.step(y, v, dt)
        v += (G - f.foot_n / m) * dt
        peak = max(peak, f.foot_n)
    assert peak == pytest.approx(spring_peak_n(k, m, 5.0), rel=5e-3)
    assert not mat.in_contact and v < 0  # it bounced off


def write_model6_fit(path):
    law = lambda layer, sp, e, h, d, ed: {f"{layer}_plateau_pa": sp, f"{layer}_modulus_pa": e,
                                          f"{layer}_hardening_pa": h, f"{layer}_densification_pa": d,
                                          f"{layer}_densification_strain": ed,
                                          f"{layer}_densification_exponent": 2.0}
    params = {**law("top", 3.0e3, 6.0e4, 5.0e4, 500.0, 0.85), **law("base", 4.0e4, 8.0e5, 1.0e5, 6.0e3, 0.8),
              "prony_g1": 0.5, "prony_tau1_s": 2e-3, "prony_g2": 0.3, "prony_tau2_s": 4e-2,
              "viscosity_pa_s": 50.0, "top_mass_kg": 2.4, "base_mass_kg": 3.6}
    geometry = {"area_m2": 0.0625, "top_thickness_m": 0.11, "base_thickness_m": 0.08, "n_top": 5, "n_base": 3,
                "max_step_s": 2.5e-4}
    path.write_text(json.dumps({"model": "model6", "parameters": params, "geometry": geometry}))


def column_landing_peak(path, dt):
    mat = dropfit.ColumnContact(str(path))
    y, v, peak = -0.002, 5.0, 0.0
    mat.reset(y, v)
    for _ in range(int(0.15 / dt)):
        y += v * dt
        f = mat.step(y, v, dt)
        v += (G - f.foot_n / 24.0) * dt
        peak = max(peak, f.grf_n)
    return peak, mat.in_contact, v


def test_model6_column_co_simulation(tmp_path):
    # A Model 6 fit.json stepped by a caller's own integrator: the plate's
    # peak at 1 ms steps within 2.5 % of that at 0.05 ms (measured 1.7 %: the
    # caller's Euler step at 1 ms), and the impactor
    # bounces off; nothing touches the column above it; a fit.json missing a
    # parameter names it.
    fit = tmp_path / "fit.json"
    write_model6_fit(fit)
    fine, _, _ = column_landing_peak(fit, 5e-5)
    coarse, contact, v = column_landing_peak(fit, 1e-3)
    assert 3000.0 < fine < 20000.0
    assert coarse == pytest.approx(fine, rel=0.025)
    assert not contact and v < 0
    mat = dropfit.ColumnContact(str(fit))
    f = mat.step(-0.01, 1.0, 1e-3)
    assert f.foot_n == 0.0 and not f.contact
    doc = json.loads(fit.read_text())
    del doc["parameters"]["prony_g1"]
    fit.write_text(json.dumps(doc))
    with pytest.raises(dropfit.InputError, match="parameters.prony_g1"):
        dropfit.ColumnContact(str(fit))


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "out"
    return dropfit.run(DEMO, out, diagnose=False, threads=2), out


def test_run_the_demo_session(demo_run):
    res, _ = demo_run
    truth = json.loads((SOURCE / "samples" / "demo-truth.json").read_text())
    true_v = {t["id"]: t["impact_velocity_m_s"] for t in truth["trials"]}
    assert res.run_summary["trials"] == 5
    assert list(res.summary["trial"]) == sorted(true_v)
    assert res.summary["accepted"] == ["yes"] * 5
    # Each impact velocity within its 95 % interval (at least 2 cm/s) of the truth.
    for trial, v, ci in zip(res.summary["trial"], res.summary["impact_velocity_m_s"],
                            res.summary["impact_velocity_ci_m_s"]):
        assert abs(v - true_v[trial]) < max(ci, 0.02), trial
    # The canonical fit: Model 4 on a linear world, its top spring within 10 %.
    assert res.fit.model == "model4"
    k1 = res.fit.parameters["k1_n_m"]
    assert k1 == pytest.approx(truth["parameters"]["k1_n_m"], rel=0.10)
    # Measured and simulated force of every trial, as numpy arrays.
    assert sorted(res.series) == sorted(true_v)
    s = res.series["trial3"]
    assert s["t_s"].shape == s["measured_fz_n"].shape == s["simulated_fz_n"].shape
    peak = np.nanmax(s["measured_fz_n"])
    rms = np.sqrt(np.nanmean((s["simulated_fz_n"] - s["measured_fz_n"]) ** 2))
    assert rms < 0.05 * peak
    assert set(res.fits) == {"model1", "model2", "model3", "model4", "model5"}


def test_results_read_back_from_the_folder(demo_run):
    res, out = demo_run
    back = dropfit.read_results(out)
    assert set(back.files) - {".dropfit-output"} == set(res.files)
    np.testing.assert_array_equal(back.summary["peak_force_n"], res.summary["peak_force_n"])
    np.testing.assert_array_equal(back.series["trial1"]["simulated_fz_n"], res.series["trial1"]["simulated_fz_n"])
    assert back.fit.parameters == res.fit.parameters
    with pytest.raises(FileNotFoundError):
        dropfit.read_results(DEMO)  # a session folder is not a results folder


def test_simulate_the_fitted_mat_reproduces_its_series(demo_run):
    # The fit's simulated force for a trial, from that trial's impact
    # velocity and the plate's sampling, as the fitter drew it.
    res, _ = demo_run
    trial = res.fit_json["trials"][2]
    s = res.series[trial["id"]]
    dt = float(np.median(np.diff(s["t_s"])))
    first = s["t_s"][s["t_s"] >= 0][0]
    sim = dropfit.simulate(res.fit, velocity_m_s=trial["impact_velocity_m_s"], dt_s=dt, first_output_s=first,
                           duration_s=s["t_s"][-1] + dt)
    n = min(len(sim["grf_n"]), int((s["t_s"] >= 0).sum()))
    peak = np.nanmax(s["simulated_fz_n"])
    np.testing.assert_allclose(sim["grf_n"][:n], s["simulated_fz_n"][s["t_s"] >= 0][:n], atol=0.02 * peak)

// Option structs refuse out-of-range values at the stage entry with a
// dropfit::Error naming the field and the value (validate()).
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>
#include <string>

#include "calibration/calibration.h"
#include "capture/tracking.h"
#include "core/error.h"
#include "diagnosis/structure.h"
#include "forceplate/forceplate.h"
#include "reconstruction/reconstruction.h"
#include "trial/trial.h"

namespace {

using dropfit::Error;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Runs `f`, expects a dropfit::Error whose message holds every one of `parts`.
void expect_error_naming(const std::function<void()>& f, std::initializer_list<std::string> parts) {
  try {
    f();
    ADD_FAILURE() << "no error; expected one naming " << *parts.begin();
  } catch (const Error& e) {
    const std::string what = e.what();
    for (const std::string& p : parts) EXPECT_NE(what.find(p), std::string::npos) << what << " lacks '" << p << "'";
  }
}

TEST(OptionsValidate, ForceplateProcessOptions) {
  using dropfit::forceplate::ProcessOptions;
  EXPECT_NO_THROW(ProcessOptions{}.validate());
  ProcessOptions o;
  o.sample_rate_hz = -1000.0;
  expect_error_naming([&] { o.validate(); }, {"forceplate options", "sample_rate_hz", "-1000"});
  o = {};
  o.trigger_threshold_n = kNaN;
  expect_error_naming([&] { o.validate(); }, {"trigger_threshold_n", "nan"});
  o = {};
  o.pretrigger_fraction = 1.0;  // the whole record before the trigger: no contact left
  expect_error_naming([&] { o.validate(); }, {"pretrigger_fraction", "1"});
  o = {};
  o.min_quiet_samples = 0;
  expect_error_naming([&] { o.validate(); }, {"min_quiet_samples", "0"});
  o = {};
  o.sample_rate_hz = 0.0;  // documented: the time column is then not checked
  EXPECT_NO_THROW(o.validate());
  // At the stage entry, before the record is looked at.
  o.onset_band_sd = -3.0;
  expect_error_naming([&] { dropfit::forceplate::process(dropfit::forceplate::Resultants{}, o); },
                      {"onset_band_sd", "-3"});
}

TEST(OptionsValidate, TrialOptions) {
  using dropfit::trial::TrialOptions;
  TrialOptions o;
  o.id = "t1";
  o.base_markers = {0};
  EXPECT_NO_THROW(o.validate());
  TrialOptions bad = o;
  bad.frame_rate_hz = -1000.0;
  expect_error_naming([&] { bad.validate(); }, {"trial t1 options", "frame_rate_hz", "-1000"});
  bad = o;
  bad.gravity_m_s2 = kNaN;
  expect_error_naming([&] { bad.validate(); }, {"gravity_m_s2", "nan"});
  bad = o;
  bad.min_freefall_frames = 0;  // a parabola needs three
  expect_error_naming([&] { bad.validate(); }, {"min_freefall_frames", "0"});
  bad = o;
  bad.min_marker_coverage = 1.5;
  expect_error_naming([&] { bad.validate(); }, {"min_marker_coverage", "1.5"});
  bad = o;
  bad.max_surface_reference_m = -0.001;
  expect_error_naming([&] { bad.validate(); }, {"max_surface_reference_m", "-0.001"});
  bad = o;
  bad.min_rest_frames = 0;
  expect_error_naming([&] { bad.validate(); }, {"min_rest_frames", "0"});
  // At the stage entry: an error, not a rejected trial.
  bad = o;
  bad.impulse_tolerance = 0.0;
  dropfit::reconstruction::Trajectories markers;
  markers.lab_m = Eigen::MatrixXd::Zero(10, 3);
  markers.residual_px = Eigen::MatrixXd::Zero(10, 1);
  expect_error_naming([&] { dropfit::trial::analyse_without_force(markers, bad, "none"); },
                      {"impulse_tolerance", "0"});
  dropfit::forceplate::ProcessOptions po;
  po.quiet_guard_s = -0.05;
  expect_error_naming([&] { dropfit::trial::analyse(dropfit::forceplate::Resultants{}, po, markers, o); },
                      {"quiet_guard_s", "-0.05"});
}

TEST(OptionsValidate, CalibrationOptions) {
  using dropfit::calibration::CalibrationOptions;
  EXPECT_NO_THROW(CalibrationOptions{}.validate());
  CalibrationOptions o;
  o.outlier_ratio = 0.5;  // would call half the markers outliers
  expect_error_naming([&] { o.validate(); }, {"calibration options", "outlier_ratio", "0.5"});
  o = {};
  o.max_outliers = -1;
  expect_error_naming([&] { o.validate(); }, {"max_outliers", "-1"});
  o = {};
  o.min_outlier_m = kNaN;
  expect_error_naming([&] { o.validate(); }, {"min_outlier_m", "nan"});
  o = {};
  o.dlt.radial_terms = 4;
  expect_error_naming([&] { o.validate(); }, {"dlt.radial_terms", "4"});
  o = {};
  o.dlt.fit_distortion = true;
  o.dlt.radial_terms = 0;
  o.dlt.tangential = false;
  expect_error_naming([&] { o.validate(); }, {"dlt.fit_distortion", "no distortion term"});
  // At the stage entry, before the markers are looked at.
  o = {};
  o.outlier_ratio = kNaN;
  expect_error_naming([&] { dropfit::calibration::calibrate({}, {}, o); }, {"outlier_ratio", "nan"});
}

TEST(OptionsValidate, TrackingOptions) {
  using dropfit::capture::TrackingOptions;
  EXPECT_NO_THROW(TrackingOptions{}.validate());
  TrackingOptions o;
  o.gate_px = -6.0;
  expect_error_naming([&] { o.validate(); }, {"tracking options", "gate_px", "-6"});
  o = {};
  o.max_gate_px = 3.0;  // below the 6 px gate: the search could never widen
  expect_error_naming([&] { o.validate(); }, {"max_gate_px", "3"});
  o = {};
  o.ambiguity_ratio = 0.5;
  expect_error_naming([&] { o.validate(); }, {"ambiguity_ratio", "0.5"});
  o = {};
  o.detection.threshold_fraction = kNaN;
  expect_error_naming([&] { o.validate(); }, {"detection.threshold_fraction", "nan"});
  o = {};
  o.detection.max_area_px2 = 2.0;  // below min_area_px2 = 3
  expect_error_naming([&] { o.validate(); }, {"detection.max_area_px2", "2"});
  // At the stage entry: the tracker's constructor.
  o = {};
  o.max_lost_frames = -1;
  expect_error_naming([&] { dropfit::capture::MarkerTracker("cam1", {"a"}, {}, o); }, {"max_lost_frames", "-1"});
}

TEST(OptionsValidate, StructureOptions) {
  using dropfit::diagnosis::StructureOptions;
  EXPECT_NO_THROW(StructureOptions{}.validate());
  StructureOptions o;
  o.alpha = 0.0;
  expect_error_naming([&] { o.validate(); }, {"structure options", "alpha", "0"});
  o = {};
  o.dt_s = -1e-3;
  expect_error_naming([&] { o.validate(); }, {"dt_s", "-0.001"});
  o = {};
  o.sparse.max_iterations = 0;
  expect_error_naming([&] { o.validate(); }, {"sparse.max_iterations", "0"});
  o = {};
  o.max_lag = 0;  // the calibration stage's choice: no whiteness test
  EXPECT_NO_THROW(o.validate());
  // At the entries.
  o.min_share = kNaN;
  const Eigen::VectorXd r = Eigen::VectorXd::LinSpaced(50, -1.0, 1.0);
  expect_error_naming([&] { dropfit::diagnosis::analyse_residual(r, {}, o); }, {"min_share", "nan"});
  dropfit::diagnosis::SparseOptions sp;
  sp.ridge = -1.0;
  expect_error_naming([&] { dropfit::diagnosis::stlsq(Eigen::MatrixXd::Ones(50, 1), r, sp); }, {"sparse.ridge", "-1"});
}

}  // namespace

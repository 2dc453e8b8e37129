// The diagnosis stages on the independent validation sessions
// (../shared/validation, see its README): what each must name and what it
// must not. Skipped when ../shared is absent.
#include <gtest/gtest.h>

#include <filesystem>

#include "capture/io.h"
#include "cli/pipeline.h"
#include "diagnosis/diagnosis.h"

namespace dropfit::diagnosis {
namespace {

std::string validation(const std::string& name) {
  return std::string(DROPFIT_SOURCE_DIR) + "/../shared/validation/" + name + "/session";
}

bool have(const std::string& name) { return std::filesystem::exists(validation(name)); }

CalibrationDiagnosis calibration_of(const std::string& name) {
  const Session s = capture::read_session(validation(name));
  return diagnose_calibration(pipeline::calibration_markers(s.frame), pipeline::camera_views(s.images));
}

bool named(const std::vector<Effect>& effects, const std::string& name) {
  for (const auto& e : effects)
    if (e.name == name) return true;
  return false;
}

std::string report(const CalibrationDiagnosis& d) {
  DiagnosisResult r;
  append(r, d);
  return r.report();
}

TEST(ValidationCalibration, CleanSessionsNameNothing) {
  for (const std::string name : {"v1-realistic", "v2-linear-control", "v3-hysteresis", "v4-rate",
                                 "v6-formats-drift-scale"}) {
    if (!have(name)) GTEST_SKIP() << "../shared/validation absent";
    const CalibrationDiagnosis d = calibration_of(name);
    EXPECT_TRUE(d.effects.empty()) << name << "\n" << report(d);
    EXPECT_TRUE(d.remaining.empty()) << name << "\n" << report(d);
  }
}

TEST(ValidationCalibration, SwappedPairAndLensDistortion) {
  if (!have("v5-outlier-lens-offset")) GTEST_SKIP() << "../shared/validation absent";
  const CalibrationDiagnosis d = calibration_of("v5-outlier-lens-offset");
  std::cerr << report(d);
  EXPECT_TRUE(named(d.effects, "outlier_marker")) << report(d);
  EXPECT_TRUE(named(d.effects, "lens_distortion")) << report(d);
  EXPECT_TRUE(d.remaining.empty()) << report(d);
}

}  // namespace
}  // namespace dropfit::diagnosis

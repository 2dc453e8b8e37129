// The diagnosis stages on the independent validation sessions
// (../shared/validation, see its README): what each must name and what it
// must not. Skipped when ../shared is absent.
#include <gtest/gtest.h>

#include <algorithm>
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

namespace dropfit::diagnosis {
namespace {

// Calibration, sync and force plate on the pipeline's state (the mat stage
// is the lead's, tested elsewhere): exactly the session's injected effects
// of those stages.
std::vector<std::string> upstream_effects(const std::string& name, DiagnosisResult* out = nullptr) {
  const Session s = capture::read_session(validation(name));
  const SessionState state = pipeline::session_state(s);
  DiagnosisOptions o;
  o.mat = false;
  const DiagnosisResult r = diagnose(state, o);
  std::vector<std::string> names;
  for (const auto& e : r.effects) names.push_back(e.name);
  std::sort(names.begin(), names.end());
  if (out) *out = r;
  return names;
}

TEST(ValidationUpstream, EachSessionNamesExactlyItsInjectedEffects) {
  const std::vector<std::pair<std::string, std::vector<std::string>>> cases{
      {"v1-realistic", {}},
      {"v2-linear-control", {}},
      {"v3-hysteresis", {}},
      {"v4-rate", {}},
      {"v5-outlier-lens-offset", {"lens_distortion", "outlier_marker", "time_offset"}},
      {"v6-formats-drift-scale", {"baseline_drift", "force_scale"}}};
  for (const auto& [name, expected] : cases) {
    if (!have(name)) GTEST_SKIP() << "../shared/validation absent";
    DiagnosisResult r;
    EXPECT_EQ(upstream_effects(name, &r), expected) << name << "\n" << r.report();
    EXPECT_FALSE(r.unexplained) << name << "\n" << r.report();
    std::cerr << name << "\n" << r.report();
  }
}

}  // namespace
}  // namespace dropfit::diagnosis

// Every command is a view of one session state (pipeline/pipeline.h): for
// the same trial, `process`, `fit`, `run` and `reconstruct` report the same
// verdict, impact velocity and its interval, clock offset and trajectories.
// On sessions of an independent world (../shared/validation: read in place;
// skipped without ../shared, failing under CI=true), one of them with its
// cameras swapped in the manifest, which every command must reject alike.
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <filesystem>
#include <map>
#include <string>

#include "support/cli_harness.h"
#include "support/shared_data.h"

namespace dropfit {
namespace {

using clitest::read_text;
using clitest::run_dropfit;
using clitest::TempDir;
using json = nlohmann::json;
namespace fs = std::filesystem;

fs::path shared_session(const std::string& name) {
  return testsupport::shared_path("validation") / name / "session";
}

// trial.json of every trial a command wrote, by id.
std::map<std::string, json> trials_of(const fs::path& out) {
  std::map<std::string, json> trials;
  for (const auto& entry : fs::directory_iterator(out / "trials")) {
    const fs::path file = entry.path() / "trial.json";
    if (fs::exists(file)) trials[entry.path().filename().string()] = json::parse(read_text(file));
  }
  return trials;
}

// The same trial as two commands saw it: verdict, reason, velocity, its
// interval, the clock offset and its SE (exactly: one state, one number).
void expect_same_trials(const std::map<std::string, json>& a, const std::map<std::string, json>& b,
                        const std::string& what) {
  ASSERT_EQ(a.size(), b.size()) << what;
  for (const auto& [id, ta] : a) {
    ASSERT_TRUE(b.count(id)) << what << ": " << id;
    const json& tb = b.at(id);
    for (const char* key : {"accepted", "reject_reason", "impact_velocity_m_s", "impact_velocity_ci_m_s",
                            "video_offset_s", "video_offset_se_s", "max_deformation_m"}) {
      EXPECT_EQ(ta.value(key, json()), tb.value(key, json())) << what << ": " << id << " " << key;
    }
  }
}

struct Views {
  std::map<std::string, json> run, process, fit;
  int run_exit = -1, process_exit = -1, fit_exit = -1;
  std::string run_xyz, reconstruct_xyz;  // trial3's xyzpts.csv
};

Views views_of(const fs::path& session, TempDir& tmp) {
  Views v;
  const auto run = run_dropfit({"run", session.string(), "--out", (tmp / "run").string()}, tmp.path());
  const auto process = run_dropfit({"process", session.string(), "--out", (tmp / "process").string()}, tmp.path());
  const auto fit = run_dropfit({"fit", session.string(), "--model", "2", "--out", (tmp / "fit").string()}, tmp.path());
  const auto rec = run_dropfit({"reconstruct", session.string(), "--out", (tmp / "rec").string()}, tmp.path());
  v.run_exit = run.exit_code;
  v.process_exit = process.exit_code;
  v.fit_exit = fit.exit_code;
  EXPECT_EQ(rec.exit_code, 0) << rec.describe();
  if (fs::exists(tmp / "run" / "trials")) v.run = trials_of(tmp / "run");
  if (fs::exists(tmp / "process" / "trials")) v.process = trials_of(tmp / "process");
  if (fs::exists(tmp / "fit" / "trials")) v.fit = trials_of(tmp / "fit");
  if (fs::exists(tmp / "run" / "trials" / "trial3" / "xyzpts.csv"))
    v.run_xyz = read_text(tmp / "run" / "trials" / "trial3" / "xyzpts.csv");
  if (fs::exists(tmp / "rec" / "trials" / "trial3" / "xyzpts.csv"))
    v.reconstruct_xyz = read_text(tmp / "rec" / "trials" / "trial3" / "xyzpts.csv");
  return v;
}

TEST(PipelineViews, EveryCommandSaysTheSameOfEachTrial) {
  for (const char* name : {"v1-realistic", "v5-outlier-lens-offset"}) {
    const fs::path session = shared_session(name);
    DROPFIT_NEED_SHARED(session);
    TempDir tmp;
    const Views v = views_of(session, tmp);
    ASSERT_EQ(v.run_exit, 0) << name;
    ASSERT_EQ(v.process_exit, 0) << name;
    ASSERT_EQ(v.fit_exit, 0) << name;
    ASSERT_EQ(v.run.size(), 5u) << name;
    expect_same_trials(v.run, v.process, std::string(name) + ": run vs process");
    expect_same_trials(v.run, v.fit, std::string(name) + ": run vs fit");
    // The offset is the final model's contact instant, not the plate onset.
    for (const auto& [id, t] : v.run) EXPECT_NE(t["video_offset_s"], t["video_offset_onset_s"]) << name << " " << id;
    EXPECT_FALSE(v.run_xyz.empty());
    EXPECT_EQ(v.run_xyz, v.reconstruct_xyz) << name << ": run and reconstruct triangulate alike";
  }
}

TEST(PipelineViews, SwappedCamerasAreRejectedByEveryCommand) {
  const fs::path original = shared_session("v2-linear-control");
  DROPFIT_NEED_SHARED(original);
  TempDir tmp;
  const fs::path session = tmp / "swapped";
  fs::copy(original, session, fs::copy_options::recursive);
  const std::string toml = read_text(session / "session.toml");
  clitest::write_text(session / "session.toml",
                      clitest::replace_first(toml, "cameras = [\"cam1\", \"cam2\"]", "cameras = [\"cam2\", \"cam1\"]"));
  const Views v = views_of(session, tmp);
  // No usable trial: run and process write every trial rejected with its
  // reason and exit non-zero; fit has nothing to fit.
  EXPECT_NE(v.run_exit, 0);
  EXPECT_NE(v.process_exit, 0);
  EXPECT_NE(v.fit_exit, 0);
  ASSERT_EQ(v.run.size(), 5u);
  for (const auto& [id, t] : v.run) {
    EXPECT_FALSE(t["accepted"].get<bool>()) << id;
    EXPECT_FALSE(t["reject_reason"].get<std::string>().empty()) << id;
  }
  expect_same_trials(v.run, v.process, "swapped: run vs process");
}

// The canonical fit.json is the final model: on a stiffening mat the closed
// loop's (Model 4 with the cubic term), labelled so; plain Model 4 stays
// under fits/model4; the MJCF of the final model states its stable step.
TEST(PipelineViews, TheCanonicalResultIsTheFinalModel) {
  const fs::path session = shared_session("v1-realistic");
  DROPFIT_NEED_SHARED(session);
  TempDir tmp;
  const auto run = run_dropfit({"run", session.string(), "--out", (tmp / "run").string()}, tmp.path());
  ASSERT_EQ(run.exit_code, 0) << run.describe();
  const json canonical = json::parse(read_text(tmp / "run" / "fit.json"));
  const json loop = json::parse(read_text(tmp / "run" / "fits" / "closed_loop" / "fit.json"));
  const json plain = json::parse(read_text(tmp / "run" / "fits" / "model4" / "fit.json"));
  EXPECT_EQ(canonical["label"], "closed_loop");
  EXPECT_EQ(canonical["parameters"], loop["parameters"]);
  EXPECT_EQ(plain["label"], "model4");
  // The closed loop's springs within 5 % of the truth (plain Model 4 sits on
  // its bounds on this stiffening mat).
  const json truth = json::parse(read_text(session.parent_path() / "truth.json"))["mat"];
  for (const char* k : {"k1", "k2", "k3"}) {
    const double want = truth[k].get<double>();
    EXPECT_NEAR(canonical["parameters"][std::string(k) + "_n_m"].get<double>(), want, 0.05 * want) << k;
  }
  EXPECT_NEAR(canonical["parameters"]["k1_cubic_n_m3"].get<double>(), truth["k1_cubic"].get<double>(),
              0.05 * truth["k1_cubic"].get<double>());
  const std::string mjcf = read_text(tmp / "run" / "mat.mjcf.xml");
  EXPECT_NE(mjcf.find("dropfit_max_stable_timestep_s"), std::string::npos);
  EXPECT_NE(mjcf.find("WARNING: k1_cubic_n_m3"), std::string::npos) << "the cubic term a joint spring cannot carry";
}

}  // namespace
}  // namespace dropfit

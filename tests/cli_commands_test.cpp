// End-to-end tests of the dropfit commands on a synthetic session with known
// truth (samples/generator: make_session, then capture::write_session).
// Each test writes its own short session into a fresh folder, runs the
// binary, and checks the files it wrote against the contract
// (docs/formats.md) and against the generator's truth, and
// that the session folder was not touched.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "capture/io.h"
#include "fitting/models.h"  // fitting::ModelKind, MatParams (synth.h no longer includes fitting/)
#include "samples/generator/synth.h"
#include "support/cli_harness.h"

namespace dropfit::clitest {
namespace {

using nlohmann::json;

// A CSV file of numbers with a header ("NaN" reads as NaN).
struct Csv {
  std::vector<std::string> header;
  std::vector<std::vector<double>> rows;
  int column(const std::string& name) const {
    for (std::size_t i = 0; i < header.size(); ++i)
      if (header[i] == name) return static_cast<int>(i);
    return -1;
  }
};

std::vector<std::string> split(const std::string& line, char sep = ',') {
  std::vector<std::string> out;
  std::string field;
  std::istringstream in(line);
  while (std::getline(in, field, sep)) out.push_back(field);
  if (!line.empty() && line.back() == sep) out.emplace_back();
  return out;
}

// Parses `text`; with has_header = false every line is a row.
Csv parse_csv(const std::string& text, bool has_header = true) {
  Csv csv;
  std::istringstream in(text);
  std::string line;
  bool first = true;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    if (first && has_header) {
      csv.header = split(line);
    } else {
      std::vector<double> row;
      for (const auto& f : split(line)) row.push_back(std::stod(f));
      csv.rows.push_back(row);
    }
    first = false;
  }
  return csv;
}

// summary.csv: column name -> text, per row. The last column
// (reject_reason) is quoted text and is left out.
std::vector<std::map<std::string, std::string>> read_summary(const std::string& text) {
  std::vector<std::map<std::string, std::string>> rows;
  std::istringstream in(text);
  std::string line;
  std::vector<std::string> header;
  while (std::getline(in, line)) {
    if (header.empty()) {
      header = split(line);
      continue;
    }
    const auto fields = split(line.substr(0, line.find('"')));
    std::map<std::string, std::string> row;
    for (std::size_t i = 0; i < fields.size() && i < header.size(); ++i) row[header[i]] = fields[i];
    rows.push_back(row);
  }
  return rows;
}

json read_json(const fs::path& path) {
  EXPECT_TRUE(fs::exists(path)) << path;
  return json::parse(read_text(path));
}

// A number of a JSON document; NaN for null (JSON has no NaN).
double number(const json& doc, const std::string& key) {
  const json& v = doc.at(key);
  return v.is_null() ? std::nan("") : v.get<double>();
}

// Checks that `doc` has each key; lists the missing ones.
void expect_keys(const json& doc, const std::vector<std::string>& keys, const std::string& what) {
  for (const auto& key : keys) EXPECT_TRUE(doc.contains(key)) << what << " has no key '" << key << "'";
}

class CliCommands : public ::testing::Test {
 protected:
  void SetUp() override {
    synthetic_ = write_synthetic_session(session());
    before_ = listing(session());
  }
  // After a test changed the session on purpose: this is the state to keep.
  void keep_session_as_is() { before_ = listing(session()); }
  // A new session with other options, in place of the test's.
  void regenerate(const synth::SynthOptions& options) {
    fs::remove_all(session());
    fs::remove_all(out());
    synthetic_ = write_synthetic_session(session(), options);
    before_ = listing(session());
  }
  void TearDown() override { EXPECT_EQ(listing(session()), before_) << "the session folder changed"; }

  fs::path session() const { return dir_ / "session"; }
  fs::path out() const { return dir_ / "out"; }
  const synth::SyntheticSession& synthetic() const { return synthetic_; }

  // Runs a command on the session; expects success with nothing on stderr.
  CliRun run_ok(const std::string& command) {
    CliRun run = run_dropfit({command, session().string(), "--out", out().string()}, dir_.path());
    EXPECT_EQ(run.exit_code, 0) << run.describe();
    EXPECT_EQ(run.err, "") << run.describe();
    return run;
  }

  TempDir dir_;

 private:
  synth::SyntheticSession synthetic_;
  std::map<std::string, std::string> before_;
};

calibration::Dlt11 dlt_of(const json& camera) {
  calibration::Dlt11 l;
  for (int i = 0; i < 11; ++i) l[i] = camera.at("dlt").at(i).get<double>();
  return l;
}

Eigen::Vector2d project(const calibration::Dlt11& l, const Eigen::Vector3d& x) {
  const double w = l[8] * x.x() + l[9] * x.y() + l[10] * x.z() + 1.0;
  return {(l[0] * x.x() + l[1] * x.y() + l[2] * x.z() + l[3]) / w,
          (l[4] * x.x() + l[5] * x.y() + l[6] * x.z() + l[7]) / w};
}

// Linear least-squares DLT triangulation (each camera gives two equations
// linear in X), independent of calibration/.
Eigen::Vector3d triangulate(const std::vector<calibration::Dlt11>& dlts, const std::vector<Eigen::Vector2d>& px) {
  Eigen::MatrixXd a(2 * dlts.size(), 3);
  Eigen::VectorXd b(2 * dlts.size());
  for (std::size_t c = 0; c < dlts.size(); ++c) {
    const auto& l = dlts[c];
    const double u = px[c].x(), v = px[c].y();
    a.row(2 * c) << l[0] - u * l[8], l[1] - u * l[9], l[2] - u * l[10];
    a.row(2 * c + 1) << l[4] - v * l[8], l[5] - v * l[9], l[6] - v * l[10];
    b(2 * c) = u - l[3];
    b(2 * c + 1) = v - l[7];
  }
  return a.colPivHouseholderQr().solve(b);
}

// The point whose projections are closest to the pixels (least squares of
// the reprojection error, Gauss-Newton from the linear solution with a
// numerical Jacobian), as calibration/ reconstructs its check points.
Eigen::Vector3d triangulate_refined(const std::vector<calibration::Dlt11>& dlts,
                                    const std::vector<Eigen::Vector2d>& px) {
  auto residuals = [&](const Eigen::Vector3d& x) {
    Eigen::VectorXd r(2 * dlts.size());
    for (std::size_t c = 0; c < dlts.size(); ++c) r.segment<2>(2 * c) = project(dlts[c], x) - px[c];
    return r;
  };
  Eigen::Vector3d x = triangulate(dlts, px);
  for (int iteration = 0; iteration < 20; ++iteration) {
    const Eigen::VectorXd r = residuals(x);
    Eigen::MatrixXd j(r.size(), 3);
    for (int k = 0; k < 3; ++k) {
      Eigen::Vector3d step = Eigen::Vector3d::Zero();
      step[k] = 1e-7;
      j.col(k) = (residuals(x + step) - residuals(x - step)) / 2e-7;
    }
    const Eigen::Vector3d dx = j.colPivHouseholderQr().solve(-r);
    x += dx;
    if (dx.norm() < 1e-12) break;
  }
  return x;
}

// ---------------------------------------------------------------------------

TEST_F(CliCommands, CalibrateWritesTheSpecKeysWithSubMillimetreChecks) {
  const CliRun run = run_ok("calibrate");
  const json cal = read_json(out() / "calibration.json");
  expect_keys(cal, {"model", "cameras", "check_points", "check_rms_mm", "check_max_mm"}, "calibration.json");
  EXPECT_EQ(cal.at("model"), "dlt11");

  const auto& truth = synthetic().truth;
  const auto& session = synthetic().session;
  ASSERT_EQ(cal.at("cameras").size(), 2u);
  std::vector<calibration::Dlt11> dlts;
  for (std::size_t c = 0; c < 2; ++c) {
    const json& camera = cal.at("cameras").at(c);
    expect_keys(camera, {"name", "dlt", "distortion", "fit_rms_px", "n_fit_points"}, "cameras[]");
    EXPECT_EQ(camera.at("name"), session.manifest.video.cameras[c]);
    ASSERT_EQ(camera.at("dlt").size(), 11u);
    for (const auto& l : camera.at("dlt")) EXPECT_TRUE(l.is_number());
    EXPECT_TRUE(camera.at("distortion").empty());
    dlts.push_back(dlt_of(camera));
    // Fit markers this camera sees.
    int n_fit = 0;
    for (const auto& o : session.images[c].observations)
      for (const auto& m : session.frame)
        if (m.id == o.id && m.role == MarkerRole::Fit) ++n_fit;
    EXPECT_EQ(camera.at("n_fit_points").get<int>(), n_fit);
    // 0.25 px noise per coordinate, 11 parameters from 2 n equations:
    // expected RMS distance 0.25 sqrt(2 (2n - 11) / (2n)), about 0.24 px.
    EXPECT_GT(camera.at("fit_rms_px").get<double>(), 0.08);
    EXPECT_LT(camera.at("fit_rms_px").get<double>(), 0.5);
    // The DLT reproduces the true (noise-free) images of every marker.
    for (const auto& marker : truth.calibration_markers)
      EXPECT_LT((project(dlts[c], marker.lab_m) - marker.image_px[c]).norm(), 1.0) << marker.id;
  }

  // Check points: every check marker both cameras see, with its error
  // agreeing with an independent triangulation from the same DLTs and
  // pixels (the reprojection-error optimum).
  std::map<std::string, std::vector<Eigen::Vector2d>> seen;
  for (const auto& image : session.images)
    for (const auto& o : image.observations) seen[o.id].push_back(o.image_px);
  std::set<std::string> expected_ids;
  for (const auto& m : session.frame)
    if (m.role == MarkerRole::Check && seen[m.id].size() == 2) expected_ids.insert(m.id);
  ASSERT_GE(expected_ids.size(), 5u);
  std::set<std::string> ids;
  Eigen::Vector3d sum_sq = Eigen::Vector3d::Zero();
  double max_abs = 0.0;
  for (const auto& check : cal.at("check_points")) {
    expect_keys(check, {"id", "error_mm"}, "check_points[]");
    const std::string id = check.at("id");
    ids.insert(id);
    ASSERT_EQ(check.at("error_mm").size(), 3u);
    const Eigen::Vector3d error_mm(check.at("error_mm")[0], check.at("error_mm")[1], check.at("error_mm")[2]);
    for (const auto& m : session.frame) {
      if (m.id != id) continue;
      const Eigen::Vector3d expected_mm = 1e3 * (triangulate_refined(dlts, seen[id]) - m.lab_m);
      EXPECT_LT((error_mm - expected_mm).cwiseAbs().maxCoeff(), 0.002)
          << id << ": " << error_mm.transpose() << " vs " << expected_mm.transpose();
    }
    sum_sq += error_mm.cwiseAbs2();
    max_abs = std::max(max_abs, error_mm.cwiseAbs().maxCoeff());
  }
  EXPECT_EQ(ids, expected_ids);
  ASSERT_EQ(cal.at("check_rms_mm").size(), 3u);
  for (int axis = 0; axis < 3; ++axis) {
    const double rms = cal.at("check_rms_mm")[axis].get<double>();
    EXPECT_NEAR(rms, std::sqrt(sum_sq[axis] / static_cast<double>(ids.size())), 1e-9 + 1e-9 * rms) << axis;
    EXPECT_LT(rms, 0.5) << "axis " << axis;  // at 0.25 px noise
  }
  EXPECT_NEAR(cal.at("check_max_mm").get<double>(), max_abs, 1e-9);

  // dlt_coefficients.csv: 11 rows (L1..L11), one column per camera.
  const Csv coefficients = parse_csv(read_text(out() / "dlt_coefficients.csv"), false);
  ASSERT_EQ(coefficients.rows.size(), 11u);
  for (int i = 0; i < 11; ++i) {
    ASSERT_EQ(coefficients.rows[i].size(), 2u) << "row " << i + 1;
    for (int c = 0; c < 2; ++c) EXPECT_NEAR(coefficients.rows[i][c], dlts[c][i], 1e-12 * std::abs(dlts[c][i]));
  }
  EXPECT_NE(run.out.find("calibration.json"), std::string::npos) << run.describe();
}

// Reconstructed minus true marker positions over every frame of every trial
// (metres), checking the layout of xyzpts.csv on the way.
struct TrajectoryErrors {
  Eigen::Vector3d sum_sq = Eigen::Vector3d::Zero();
  Eigen::Vector3i n = Eigen::Vector3i::Zero();
  double max_m = 0.0;
  int total = 0;
  Eigen::Vector3d rms_m() const {
    return (sum_sq.array() / n.cast<double>().array()).sqrt();
  }
};

TrajectoryErrors trajectory_errors(const fs::path& out, const synth::SynthTruth& truth) {
  TrajectoryErrors e;
  const int n_points = static_cast<int>(truth.points.size());
  for (const auto& trial : truth.trials) {
    const Csv xyz = parse_csv(read_text(out / "trials" / trial.id / "xyzpts.csv"));
    EXPECT_EQ(xyz.header.size(), static_cast<std::size_t>(3 * n_points)) << trial.id;
    if (xyz.header.size() != static_cast<std::size_t>(3 * n_points)) continue;
    EXPECT_EQ(xyz.header[0], "pt1_X");
    EXPECT_EQ(xyz.header[3 * n_points - 1], fmt::format("pt{}_Z", n_points));
    EXPECT_EQ(static_cast<Eigen::Index>(xyz.rows.size()), trial.markers_lab_m.rows()) << trial.id;
    for (Eigen::Index f = 0; f < trial.markers_lab_m.rows() && f < static_cast<Eigen::Index>(xyz.rows.size()); ++f) {
      EXPECT_EQ(xyz.rows[f].size(), static_cast<std::size_t>(3 * n_points));
      for (int c = 0; c < 3 * n_points && c < static_cast<int>(xyz.rows[f].size()); ++c) {
        ++e.total;
        if (std::isnan(xyz.rows[f][c])) continue;
        const double d = xyz.rows[f][c] - trial.markers_lab_m(f, c);
        e.sum_sq[c % 3] += d * d;
        ++e.n[c % 3];
        e.max_m = std::max(e.max_m, std::abs(d));
      }
    }
    const Csv residuals = parse_csv(read_text(out / "trials" / trial.id / "residuals.csv"));
    EXPECT_EQ(residuals.rows.size(), xyz.rows.size());
  }
  return e;
}

TEST_F(CliCommands, ReconstructWritesTrajectoriesWithinAMillimetreOfTruth) {
  // At the default 0.25 px digitising noise: sub-millimetre RMS per axis
  // (the largest single error over ~9000 coordinates is a 4-sigma draw,
  // about 1.3 mm).
  run_ok("reconstruct");
  ASSERT_EQ(synthetic().truth.trials.size(), 2u);
  const TrajectoryErrors noisy = trajectory_errors(out(), synthetic().truth);
  // No gaps were injected: (nearly) every coordinate is there.
  EXPECT_GE(noisy.n.sum(), noisy.total * 95 / 100);
  for (int axis = 0; axis < 3; ++axis) EXPECT_LT(1e3 * noisy.rms_m()[axis], 0.5) << "axis " << axis;
  EXPECT_LT(noisy.max_m, 0.002);
  RecordProperty("rms_mm_at_0.25px", fmt::format("{:.3f} {:.3f} {:.3f}", 1e3 * noisy.rms_m()[0],
                                                 1e3 * noisy.rms_m()[1], 1e3 * noisy.rms_m()[2]));
  RecordProperty("max_mm_at_0.25px", fmt::format("{:.3f}", 1e3 * noisy.max_m));

  // At 0.1 px every reconstructed point is within 1 mm of the truth.
  synth::SynthOptions o = short_session_options();
  o.pixel_noise_px = 0.1;
  regenerate(o);
  run_ok("reconstruct");
  const TrajectoryErrors fine = trajectory_errors(out(), synthetic().truth);
  EXPECT_GE(fine.n.sum(), fine.total * 95 / 100);
  EXPECT_LT(fine.max_m, 0.001);
  RecordProperty("max_mm_at_0.1px", fmt::format("{:.3f}", 1e3 * fine.max_m));
}

TEST_F(CliCommands, ProcessWritesTrialJsonAndSummary) {
  run_ok("process");
  const auto& truth = synthetic().truth;
  const auto summary = read_summary(read_text(out() / "summary.csv"));
  ASSERT_EQ(summary.size(), truth.trials.size()) << read_text(out() / "summary.csv");

  for (std::size_t t = 0; t < truth.trials.size(); ++t) {
    const synth::TrialTruth& tt = truth.trials[t];
    const json trial = read_json(out() / "trials" / tt.id / "trial.json");
    expect_keys(trial,
                {"id", "accepted", "reject_reason", "impact_velocity_m_s", "impact_velocity_ci_m_s",
                 "max_deformation_m", "tilt_deg", "peak_force_n", "time_to_peak_s", "contact_time_s",
                 "video_offset_s"},
                "trial.json");
    EXPECT_EQ(trial.at("id"), tt.id);
    EXPECT_TRUE(trial.at("accepted").get<bool>()) << trial.dump(2);
    EXPECT_EQ(trial.at("reject_reason"), "");
    // Against the generator's truth (0.25 px marker noise, 1 N channel noise).
    EXPECT_NEAR(number(trial, "impact_velocity_m_s"), tt.impact_velocity_m_s, 0.03) << tt.id;
    EXPECT_GT(number(trial, "impact_velocity_ci_m_s"), 0.0);
    EXPECT_LT(number(trial, "impact_velocity_ci_m_s"), 0.05);
    EXPECT_NEAR(number(trial, "max_deformation_m"), tt.max_deformation_m, 0.002) << tt.id;
    EXPECT_NEAR(number(trial, "tilt_deg"), std::abs(tt.tilt_deg), 0.5) << tt.id;
    EXPECT_NEAR(number(trial, "peak_force_n"), tt.peak_force_n, 0.01 * tt.peak_force_n) << tt.id;
    EXPECT_NEAR(number(trial, "time_to_peak_s"), tt.time_to_peak_s, 0.002) << tt.id;
    EXPECT_NEAR(number(trial, "contact_time_s"), tt.contact_time_s, 0.001) << tt.id;
    EXPECT_NEAR(number(trial, "video_offset_s"), tt.video_offset_s, 0.001) << tt.id;
    RecordProperty(tt.id + "_minus_truth",
                   fmt::format("v {:+.4f} m/s, def {:+.2f} mm, tilt {:+.2f} deg, peak {:+.1f} N, ttp {:+.2f} ms, "
                               "contact {:+.3f} ms, offset {:+.3f} ms",
                               number(trial, "impact_velocity_m_s") - tt.impact_velocity_m_s,
                               1e3 * (number(trial, "max_deformation_m") - tt.max_deformation_m),
                               number(trial, "tilt_deg") - std::abs(tt.tilt_deg),
                               number(trial, "peak_force_n") - tt.peak_force_n,
                               1e3 * (number(trial, "time_to_peak_s") - tt.time_to_peak_s),
                               1e3 * (number(trial, "contact_time_s") - tt.contact_time_s),
                               1e3 * (number(trial, "video_offset_s") - tt.video_offset_s)));
    // summary.csv says the same (5 significant digits).
    EXPECT_EQ(summary[t].at("trial"), tt.id);
    EXPECT_EQ(summary[t].at("accepted"), "yes");
    EXPECT_NEAR(std::stod(summary[t].at("impact_velocity_m_s")), number(trial, "impact_velocity_m_s"), 1e-3);
    EXPECT_NEAR(std::stod(summary[t].at("peak_force_n")), number(trial, "peak_force_n"), 1.0);

    const Csv series = parse_csv(read_text(out() / "trials" / tt.id / "series.csv"));
    for (const char* column : {"t_s", "fz_n", "impactor_z_m"})
      EXPECT_GE(series.column(column), 0) << "series.csv has no " << column;
    EXPECT_GT(series.rows.size(), 30u);
  }
}

// The spec's manifest style (several key/values on a line, separated by ';')
// runs end to end.
TEST_F(CliCommands, SpecStyleManifestIsAccepted) {
  const fs::path manifest = session() / "session.toml";
  std::string text = read_text(manifest);
  for (const auto& layer : synthetic().session.manifest.mat.layers) {
    // name = "carpet"\nthickness_m = 0.005\nmass_kg = 0 -> one line, as the spec writes it.
    const std::string name = "name = \"" + layer.name + "\"\n";
    const std::size_t at = text.find(name);
    ASSERT_NE(at, std::string::npos) << text;
    const std::size_t first = at + name.size() - 1;
    const std::size_t second = text.find('\n', first + 1);
    text.replace(second, 1, "; ");
    text.replace(first, 1, ";  ");
  }
  write_text(manifest, text);
  keep_session_as_is();  // the rewritten manifest is the state to keep
  ASSERT_NE(text.find("name = \"carpet\";  thickness_m = 0.005; mass_kg = 0"), std::string::npos) << text;
  // What the reader makes of it is what it made of the original.
  EXPECT_EQ(capture::read_manifest(manifest.string()).mat.thickness_m(),
            synthetic().session.manifest.mat.thickness_m());
  run_ok("calibrate");
  EXPECT_TRUE(fs::exists(out() / "calibration.json"));
}

// The peak of `dropfit simulate` output and its time.
struct Peak {
  double force_n = -1.0;
  double t_s = 0.0;
};
Peak simulated_peak(const CliRun& run) {
  EXPECT_EQ(run.exit_code, 0) << run.describe();
  EXPECT_EQ(run.err, "");
  const Csv csv = parse_csv(run.out);
  const int t_col = csv.column("t_s");
  const int f_col = csv.column("grf_n");
  EXPECT_GE(t_col, 0) << run.out.substr(0, 200);
  EXPECT_GE(f_col, 0) << run.out.substr(0, 200);
  EXPECT_GT(csv.rows.size(), 100u);
  Peak peak;
  if (t_col < 0 || f_col < 0) return peak;
  for (const auto& row : csv.rows) {
    if (row[f_col] > peak.force_n) peak = {row[f_col], row[t_col]};
  }
  return peak;
}

// `dropfit simulate --params fit.json --velocity 5.25`, with a parameter
// file holding the parameters that generated the session (the simulated
// peak is the generator's) and with the one `dropfit fit` wrote from the
// session: both close to the generator's peak at 5.25 m/s and plausible
// beside the paper's measured 7054 N (Table 1, trial 3).
TEST_F(CliCommands, SimulatePrintsAPlausibleForceCurve) {
  const auto& truth = synthetic().truth;
  ASSERT_EQ(truth.model, fitting::ModelKind::Model4);
  const synth::TrialTruth& at525 = truth.trials[0];
  ASSERT_EQ(at525.impact_velocity_m_s, 5.25);

  const fitting::MatParams& p = truth.params;
  const json fit = {{"model", "model4"},
                    {"parameters",
                     {{"k1_n_m", p.k1_n_m},
                      {"k2_n_m", p.k2_n_m},
                      {"k3_n_m", p.k3_n_m},
                      {"r1_n_s_m", p.r1_n_s_m},
                      {"r2_n_s_m", p.r2_n_s_m},
                      {"r3_n_s_m", p.r3_n_s_m},
                      {"m1_kg", p.m1_kg},
                      {"m2_kg", p.m2_kg}}}};
  const fs::path true_fit = dir_ / "true_fit.json";
  write_text(true_fit, fit.dump(2));
  const Peak exact =
      simulated_peak(run_dropfit({"simulate", "--params", true_fit.string(), "--velocity", "5.25"}, dir_.path()));
  // Sampled at 1 ms, the peak is read within half a sample of the true one.
  EXPECT_NEAR(exact.force_n, at525.peak_force_n, 0.005 * at525.peak_force_n);
  EXPECT_NEAR(exact.t_s, at525.time_to_peak_s, 0.0006);

  // The whole chain: fit the session's trials, then simulate.
  const CliRun fit_run = run_dropfit({"fit", session().string(), "--out", out().string()}, dir_.path());
  ASSERT_EQ(fit_run.exit_code, 0) << fit_run.describe();
  ASSERT_TRUE(fs::exists(out() / "fit.json")) << fit_run.describe();
  const Peak fitted = simulated_peak(
      run_dropfit({"simulate", "--params", (out() / "fit.json").string(), "--velocity", "5.25"}, dir_.path()));
  EXPECT_NEAR(fitted.force_n, at525.peak_force_n, 0.02 * at525.peak_force_n);
  EXPECT_NEAR(fitted.t_s, at525.time_to_peak_s, 0.0015);
  RecordProperty("peak_n", fmt::format("true params {:.1f} at {:.1f} ms, fitted {:.1f} at {:.1f} ms (generator {:.1f} "
                                       "at {:.2f} ms, paper 7054)",
                                       exact.force_n, 1e3 * exact.t_s, fitted.force_n, 1e3 * fitted.t_s,
                                       at525.peak_force_n, 1e3 * at525.time_to_peak_s));
  for (const Peak& peak : {exact, fitted}) {
    EXPECT_NEAR(peak.force_n, 7054.0, 0.15 * 7054.0);
    EXPECT_GT(peak.t_s, 0.015);
    EXPECT_LT(peak.t_s, 0.06);
  }
}

}  // namespace
}  // namespace dropfit::clitest

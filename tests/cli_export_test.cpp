// Exports for simulator authors: the MuJoCo MJCF of a layered mat
// (report::mjcf_xml) parsed back with a small well-formedness checker, and
// `dropfit simulate` with a fit's parameters reproducing that fit's own
// simulated curve (series/<trial>.csv) sample by sample.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cctype>
#include <cmath>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Dense>
#include <array>

#include "capture/io.h"
#include "core/error.h"
#include "samples/generator/synth.h"
#include "fitting/models.h"
#include "report/export.h"
#include "support/cli_harness.h"

namespace dropfit::clitest {
namespace {

// ---- A tiny XML well-formedness checker -------------------------------------
// Accepts: an optional <?xml ...?> declaration, comments, elements with
// name="value" / name='value' attributes (unique per element), self-closing
// tags, character data without '<'. Exactly one root element. Throws
// std::runtime_error naming the first fault.
struct XmlElement {
  std::string name;
  std::map<std::string, std::string> attrs;
  std::vector<std::unique_ptr<XmlElement>> children;
  XmlElement* parent = nullptr;
};

bool name_char(char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-' || c == ':' || c == '.'; }

std::unique_ptr<XmlElement> parse_xml(const std::string& s) {
  std::size_t i = 0;
  auto fail = [&](const std::string& why) { throw std::runtime_error(fmt::format("XML at {}: {}", i, why)); };
  auto skip_ws = [&] {
    while (i < s.size() && std::isspace(static_cast<unsigned char>(s[i]))) ++i;
  };
  auto read_name = [&] {
    const std::size_t b = i;
    while (i < s.size() && name_char(s[i])) ++i;
    if (i == b) fail("expected a name");
    return s.substr(b, i - b);
  };
  std::unique_ptr<XmlElement> root;
  XmlElement* open = nullptr;
  bool root_closed = false;
  if (s.compare(0, 5, "<?xml") == 0) {
    i = s.find("?>");
    if (i == std::string::npos) fail("unterminated declaration");
    i += 2;
  }
  while (true) {
    // Character data up to the next tag: only whitespace outside the root.
    const std::size_t lt = s.find('<', i);
    const std::string text = s.substr(i, (lt == std::string::npos ? s.size() : lt) - i);
    if (!open && text.find_first_not_of(" \t\r\n") != std::string::npos) fail("text outside the root element");
    if (text.find('>') != std::string::npos && !open) fail("stray '>'");
    if (lt == std::string::npos) break;
    i = lt;
    if (s.compare(i, 4, "<!--") == 0) {
      const std::size_t end = s.find("-->", i + 4);
      if (end == std::string::npos) fail("unterminated comment");
      i = end + 3;
      continue;
    }
    if (s.compare(i, 2, "</") == 0) {
      i += 2;
      const std::string name = read_name();
      skip_ws();
      if (i >= s.size() || s[i] != '>') fail("bad closing tag");
      ++i;
      if (!open || open->name != name) fail("closing tag </" + name + "> does not match");
      open = open->parent;
      if (!open) root_closed = true;
      continue;
    }
    ++i;
    if (root_closed) fail("a second root element");
    auto el = std::make_unique<XmlElement>();
    el->name = read_name();
    while (true) {
      const std::size_t before = i;
      skip_ws();
      if (i >= s.size()) fail("unterminated tag");
      if (s[i] == '>' || s.compare(i, 2, "/>") == 0) break;
      if (i == before) fail("attributes must be separated by space");
      const std::string attr = read_name();
      skip_ws();
      if (i >= s.size() || s[i] != '=') fail("attribute " + attr + " without '='");
      ++i;
      skip_ws();
      if (i >= s.size() || (s[i] != '"' && s[i] != '\'')) fail("attribute " + attr + " not quoted");
      const char q = s[i++];
      const std::size_t end = s.find(q, i);
      if (end == std::string::npos) fail("unterminated attribute value");
      const std::string value = s.substr(i, end - i);
      if (value.find('<') != std::string::npos) fail("'<' in an attribute value");
      if (!el->attrs.emplace(attr, value).second) fail("duplicate attribute " + attr);
      i = end + 1;
    }
    const bool self_closing = s[i] == '/';
    i += self_closing ? 2 : 1;
    XmlElement* raw = el.get();
    if (open) {
      el->parent = open;
      open->children.push_back(std::move(el));
    } else {
      root = std::move(el);
    }
    if (!self_closing) {
      open = raw;
    } else if (!raw->parent) {
      root_closed = true;
    }
  }
  if (open) fail("unclosed element <" + open->name + ">");
  if (!root) fail("no root element");
  return root;
}

void collect(const XmlElement& e, const std::string& name, std::vector<const XmlElement*>& out) {
  if (e.name == name) out.push_back(&e);
  for (const auto& c : e.children) collect(*c, name, out);
}

// The element named `tag` whose attribute name="..." is `name`.
const XmlElement* find_named(const XmlElement& root, const std::string& tag, const std::string& name) {
  std::vector<const XmlElement*> all;
  collect(root, tag, all);
  for (const auto* e : all) {
    auto it = e->attrs.find("name");
    if (it != e->attrs.end() && it->second == name) return e;
  }
  return nullptr;
}

double number(const XmlElement* e, const std::string& attr) {
  if (!e) throw std::runtime_error("element missing");
  return std::stod(e->attrs.at(attr));
}

// A body's mass: its direct <inertial> child.
double body_mass(const XmlElement& root, const std::string& body) {
  const XmlElement* b = find_named(root, "body", body);
  if (!b) throw std::runtime_error("body " + body + " missing");
  for (const auto& c : b->children)
    if (c->name == "inertial") return std::stod(c->attrs.at("mass"));
  throw std::runtime_error("body " + body + " has no inertial");
}

// The joint inside a body (its direct child).
const XmlElement* body_joint(const XmlElement& root, const std::string& body) {
  const XmlElement* b = find_named(root, "body", body);
  if (!b) return nullptr;
  for (const auto& c : b->children)
    if (c->name == "joint") return c.get();
  return nullptr;
}

TEST(XmlChecker, RejectsMalformedXml) {
  EXPECT_NO_THROW(parse_xml("<?xml version=\"1.0\"?>\n<!-- c --><a x=\"1\"><b y='2'/></a>\n"));
  EXPECT_THROW(parse_xml("<a><b></a></b>"), std::runtime_error);
  EXPECT_THROW(parse_xml("<a x=1></a>"), std::runtime_error);
  EXPECT_THROW(parse_xml("<a></a><b/>"), std::runtime_error);
  EXPECT_THROW(parse_xml("<a><b>"), std::runtime_error);
  EXPECT_THROW(parse_xml("<a x=\"1\" x=\"2\"/>"), std::runtime_error);
}

// mjcf_xml writes 9 significant digits ("{:.9g}"): a value read back is
// within half a unit of the 9th digit, 5e-9 relative. (1e-9 would need
// "{:.17g}" in report/export.cpp.)
void expect_rel(double got, double want, const std::string& what) {
  EXPECT_NEAR(got, want, 5e-9 * std::abs(want)) << what;
}

TEST(CliExport, MjcfOfModel4IsWellFormedAndCarriesTheFittedValues) {
  // Distinct, non-round values so a swapped element shows.
  fitting::MatParams p;
  p.k1_n_m = 72075.123456;
  p.k2_n_m = 1061532.98765;
  p.k3_n_m = 748625.5;
  p.r1_n_s_m = 263.25;
  p.r2_n_s_m = 761.125;
  p.r3_n_s_m = 1007.0625;
  p.m1_kg = 2.4412345;
  p.m2_kg = 3.6654321;
  const std::string xml = report::mjcf_xml(fitting::ModelKind::Model4, p, report::MatGeometry{});
  std::unique_ptr<XmlElement> root;
  ASSERT_NO_THROW(root = parse_xml(xml)) << xml;
  EXPECT_EQ(root->name, "mujoco");
  // Model 4: surface joint = element 1 (on m1), top joint = element 2 (m1 on
  // m2), bottom joint = element 3 (m2 on the ground).
  const struct {
    const char* body;
    double k, r;
  } joints[] = {{"mat_surface", p.k1_n_m, p.r1_n_s_m}, {"mat_top", p.k2_n_m, p.r2_n_s_m}, {"mat_bottom", p.k3_n_m, p.r3_n_s_m}};
  for (const auto& j : joints) {
    const XmlElement* joint = body_joint(*root, j.body);
    ASSERT_NE(joint, nullptr) << j.body;
    EXPECT_EQ(joint->attrs.at("type"), "slide") << j.body;
    EXPECT_EQ(joint->attrs.at("axis"), "0 0 1") << j.body;
    expect_rel(number(joint, "stiffness"), j.k, std::string(j.body) + " stiffness");
    expect_rel(number(joint, "damping"), j.r, std::string(j.body) + " damping");
  }
  expect_rel(body_mass(*root, "mat_top"), p.m1_kg, "m1");
  expect_rel(body_mass(*root, "mat_bottom"), p.m2_kg, "m2");
  // Nesting: the surface rides on the top layer, the top layer on the bottom.
  EXPECT_EQ(find_named(*root, "body", "mat_surface")->parent, find_named(*root, "body", "mat_top"));
  EXPECT_EQ(find_named(*root, "body", "mat_top")->parent, find_named(*root, "body", "mat_bottom"));
}

TEST(CliExport, MjcfOfModel3MapsItsTwoElements) {
  const fitting::MatParams p = fitting::paper_table2(fitting::ModelKind::Model3);
  const auto root = parse_xml(report::mjcf_xml(fitting::ModelKind::Model3, p, report::MatGeometry{}));
  EXPECT_EQ(root->name, "mujoco");
  expect_rel(number(body_joint(*root, "mat_top"), "stiffness"), p.k1_n_m, "model3 top = k1");
  expect_rel(number(body_joint(*root, "mat_bottom"), "stiffness"), p.k2_n_m, "model3 bottom = k2");
  EXPECT_EQ(find_named(*root, "body", "mat_surface"), nullptr);
}

TEST(CliExport, MjcfRefusesModels125) {
  for (auto kind : {fitting::ModelKind::Model1, fitting::ModelKind::Model2, fitting::ModelKind::Model5})
    EXPECT_THROW(report::mjcf_xml(kind, fitting::paper_table2(kind, 3.0), report::MatGeometry{}), Error)
        << fitting::model_name(kind);
}

// ---- simulate reproduces fit's own simulated curve ----------------------------

struct Table {
  std::vector<std::string> header;
  std::vector<std::vector<double>> rows;
  int col(const std::string& name) const {
    for (std::size_t i = 0; i < header.size(); ++i)
      if (header[i] == name) return static_cast<int>(i);
    return -1;
  }
};

Table read_csv(const std::string& text) {
  Table t;
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    std::vector<std::string> fields;
    std::string f;
    std::istringstream ls(line);
    while (std::getline(ls, f, ',')) fields.push_back(f);
    if (t.header.empty()) {
      t.header = fields;
    } else {
      std::vector<double> row;
      for (const auto& x : fields) row.push_back(std::stod(x));
      t.rows.push_back(row);
    }
  }
  return t;
}

TEST(CliExport, SimulateWithTheFittedParametersReproducesTheFitsCurve) {
  TempDir dir;
  const fs::path session = dir / "session", out = dir / "out";
  write_synthetic_session(session);
  const CliRun fit = run_dropfit({"fit", session.string(), "--model", "4", "--out", out.string()}, dir.path());
  ASSERT_EQ(fit.exit_code, 0) << fit.describe();
  const auto doc = nlohmann::json::parse(read_text(out / "fit.json"));
  ASSERT_FALSE(doc["train"].empty());
  const std::string train = doc["train"][0].get<std::string>();
  double velocity = NAN, shift = NAN;
  for (const auto& t : doc["trials"])
    if (t["id"] == train) {
      velocity = t["impact_velocity_m_s"].get<double>();
      shift = t["contact_shift_s"].get<double>();
    }
  ASSERT_TRUE(std::isfinite(velocity)) << train;
  ASSERT_TRUE(std::isfinite(shift)) << train;
  Table series = read_csv(read_text(out / "series" / (train + ".csv")));
  const int ct = series.col("t_s"), cf = series.col("simulated_fz_n");
  ASSERT_GE(ct, 0);
  ASSERT_GE(cf, 0);
  // The fit placed the trial's contact at contact_shift_s on its clock: the
  // series' force is the simulation from the first sample at or after it,
  // that sample's time from the fitted contact being the first output time.
  while (!series.rows.empty() && series.rows.front()[ct] - shift < 0.0) series.rows.erase(series.rows.begin());
  ASSERT_GT(series.rows.size(), 50u);
  const double t_first = series.rows.front()[ct] - shift, t_last = series.rows.back()[ct] - shift;
  const double dt = series.rows[1][ct] - series.rows[0][ct];
  const fs::path sim_path = dir / "sim.csv";
  const CliRun sim = run_dropfit({"simulate", "--params", (out / "fit.json").string(), "--velocity",
                                  fmt::format("{:.17g}", velocity), "--duration", fmt::format("{:.17g}", t_last + 0.5 * dt),
                                  "--dt", fmt::format("{:.17g}", dt), "--first-output", fmt::format("{:.17g}", t_first),
                                  "--out", sim_path.string()},
                                 dir.path());
  ASSERT_EQ(sim.exit_code, 0) << sim.describe();
  const Table s = read_csv(read_text(sim_path));
  const int st = s.col("t_s"), sf = s.col("grf_n");
  ASSERT_GE(st, 0);
  ASSERT_GE(sf, 0);
  ASSERT_GE(s.rows.size(), series.rows.size());
  double peak = 0.0;
  for (const auto& r : series.rows) peak = std::max(peak, std::abs(r[cf]));
  ASSERT_GT(peak, 1000.0);
  double worst = 0.0;
  for (std::size_t i = 0; i < series.rows.size(); ++i) {
    ASSERT_NEAR(s.rows[i][st], series.rows[i][ct] - shift, 1e-3 * dt) << "row " << i;
    worst = std::max(worst, std::abs(s.rows[i][sf] - series.rows[i][cf]));
  }
  EXPECT_LE(worst, 1e-6 * peak) << "largest |simulate - fit series| " << worst << " N, peak " << peak << " N";
  RecordProperty("worst_pct_of_peak", std::to_string(100.0 * worst / peak));
  RecordProperty("first_output_s", std::to_string(t_first));
  // Without --first-output the curve is sampled at i dt instead of
  // t_first + i dt (the fit samples on the plate's clock): what it costs.
  const fs::path naive_path = dir / "naive.csv";
  const CliRun naive = run_dropfit({"simulate", "--params", (out / "fit.json").string(), "--velocity",
                                    fmt::format("{:.17g}", velocity), "--duration", fmt::format("{:.17g}", t_last + 0.5 * dt),
                                    "--dt", fmt::format("{:.17g}", dt), "--out", naive_path.string()},
                                   dir.path());
  ASSERT_EQ(naive.exit_code, 0) << naive.describe();
  const Table nv = read_csv(read_text(naive_path));
  double naive_worst = 0.0;
  for (std::size_t i = 0; i < series.rows.size() && i < nv.rows.size(); ++i)
    naive_worst = std::max(naive_worst, std::abs(nv.rows[i][sf] - series.rows[i][cf]));
  RecordProperty("without_first_output_worst_pct_of_peak", std::to_string(100.0 * naive_worst / peak));
}


// ---- Version-2 outputs of `dropfit process` on a bottom-left session ----------

std::vector<std::string> split_on(const std::string& line, char sep) {
  std::vector<std::string> out;
  std::string f;
  std::istringstream in(line);
  while (std::getline(in, f, sep)) out.push_back(f);
  if (!line.empty() && line.back() == sep) out.emplace_back();
  return out;
}

std::vector<std::string> text_lines(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) out.push_back(line);
  return out;
}

// A bottom-left session (Argus, DLTdv 7): its xypts.csv has v measured up
// from the bottom edge; `process` writes everything a lab's other tools read.
class CliVersion2Outputs : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir;
    synth::SynthOptions o = short_session_options();
    synthetic_ = new synth::SyntheticSession(synth::make_session(o));
    synthetic_->session.manifest.video.image_origin = ImageOrigin::BottomLeft;
    synthetic_->session.manifest.video.image_height_px = 1024.0;
    capture::write_session((*dir_ / "session").string(), synthetic_->session);
    run_ = new CliRun(run_dropfit({"process", (*dir_ / "session").string(), "--out", (*dir_ / "out").string()},
                                  dir_->path()));
  }
  static void TearDownTestSuite() {
    delete run_;
    delete synthetic_;
    delete dir_;
  }
  static fs::path out() { return *dir_ / "out"; }
  static fs::path session() { return *dir_ / "session"; }
  static inline TempDir* dir_ = nullptr;
  static inline synth::SyntheticSession* synthetic_ = nullptr;
  static inline CliRun* run_ = nullptr;
};

// The written coefficients, projected through the reconstructed points,
// must land on the session's own bottom-left pixels: that is what Argus and
// DLTdv 7 do with them.
TEST_F(CliVersion2Outputs, DltCoefficientsReproduceTheSessionsBottomLeftPoints) {
  ASSERT_EQ(run_->exit_code, 0) << run_->describe();
  const auto lines = text_lines(read_text(out() / "dlt_coefficients.csv"));
  ASSERT_EQ(lines.size(), 11u) << "11 rows, no header";
  std::array<calibration::Dlt11, 2> dlt;
  for (int i = 0; i < 11; ++i) {
    const auto f = split_on(lines[i], ',');
    ASSERT_EQ(f.size(), 2u) << "one column per camera, row " << i + 1;
    for (int c = 0; c < 2; ++c) dlt[c][i] = std::stod(f[c]);  // a header would throw here
  }
  const std::string id = synthetic_->session.manifest.trials[0].id;
  const Table xyz = read_csv(read_text(out() / "trials" / id / "xyzpts.csv"));
  const Table uv = read_csv(read_text(session() / "trials" / id / "xypts.csv"));  // bottom-left, as written
  ASSERT_EQ(xyz.rows.size(), uv.rows.size());
  const int n_points = static_cast<int>(synthetic_->session.manifest.video.points.size());
  double sum_sq = 0.0, sum_sq_top = 0.0;
  int n = 0;
  for (std::size_t f = 0; f < xyz.rows.size(); ++f) {
    for (int p = 0; p < n_points; ++p) {
      const Eigen::Vector3d X(xyz.rows[f][3 * p], xyz.rows[f][3 * p + 1], xyz.rows[f][3 * p + 2]);
      if (!X.allFinite()) continue;
      for (int c = 0; c < 2; ++c) {
        const int col = 2 * (p * 2 + c);
        const Eigen::Vector2d file_px(uv.rows[f][col], uv.rows[f][col + 1]);
        if (!file_px.allFinite()) continue;
        const auto& L = dlt[c];
        const double d = L[8] * X.x() + L[9] * X.y() + L[10] * X.z() + 1.0;
        const Eigen::Vector2d px((L[0] * X.x() + L[1] * X.y() + L[2] * X.z() + L[3]) / d,
                                 (L[4] * X.x() + L[5] * X.y() + L[6] * X.z() + L[7]) / d);
        sum_sq += (px - file_px).squaredNorm();
        // The same with v read as top-left: what an unconverted file gives.
        sum_sq_top += std::pow(1024.0 - px.y() - file_px.y(), 2) + std::pow(px.x() - file_px.x(), 2);
        ++n;
      }
    }
  }
  ASSERT_GT(n, 500);
  const double rms_px = std::sqrt(sum_sq / n), rms_top_px = std::sqrt(sum_sq_top / n);
  RecordProperty("bottom_left_reprojection_rms_px", std::to_string(rms_px));
  // The pixels carry 0.25 px noise per coordinate; a point seen by two
  // cameras reprojects to within about that: 0.5 px leaves room, and a wrong
  // origin is off by hundreds of pixels.
  EXPECT_LT(rms_px, 0.5);
  EXPECT_GT(rms_top_px, 50.0);
}

TEST_F(CliVersion2Outputs, XyzresHoldsTheResidualsUnderThePointNames) {
  ASSERT_EQ(run_->exit_code, 0) << run_->describe();
  const std::string id = synthetic_->session.manifest.trials[0].id;
  const Table res = read_csv(read_text(out() / "trials" / id / "residuals.csv"));
  const Table xyzres = read_csv(read_text(out() / "trials" / id / "xyzres.csv"));
  const auto& names = synthetic_->session.manifest.video.points;
  ASSERT_EQ(xyzres.header.size(), names.size());
  for (std::size_t p = 0; p < names.size(); ++p) EXPECT_EQ(xyzres.header[p], names[p] + "_dltres");
  ASSERT_EQ(xyzres.rows.size(), res.rows.size());
  int finite = 0;
  for (std::size_t f = 0; f < res.rows.size(); ++f) {
    for (std::size_t p = 0; p < names.size(); ++p) {
      const double a = res.rows[f][p], b = xyzres.rows[f][p];
      EXPECT_EQ(std::isnan(a), std::isnan(b));
      if (std::isfinite(a)) {
        EXPECT_DOUBLE_EQ(a, b);
        EXPECT_LT(b, 2.0) << "pixels, not metres or mm";
        ++finite;
      }
    }
  }
  EXPECT_GT(finite, 500);
}

// markers.trc parsed back: the header, millimetres in OpenSim's frame, and
// each frame's time on the force clock against the generator's truth.
TEST_F(CliVersion2Outputs, TrcParsesBackToTheTrajectoriesOnTheForceClock) {
  ASSERT_EQ(run_->exit_code, 0) << run_->describe();
  for (std::size_t t = 0; t < synthetic_->truth.trials.size(); ++t) {
    const auto& truth = synthetic_->truth.trials[t];
    const std::string id = truth.id;
    const auto lines = text_lines(read_text(out() / "trials" / id / "markers.trc"));
    const Table xyz = read_csv(read_text(out() / "trials" / id / "xyzpts.csv"));
    const auto& names = synthetic_->session.manifest.video.points;
    ASSERT_EQ(lines.size(), 5 + xyz.rows.size());
    EXPECT_EQ(split_on(lines[0], '\t')[0], "PathFileType");
    const auto keys = split_on(lines[1], '\t'), values = split_on(lines[2], '\t');
    ASSERT_EQ(keys.size(), values.size());
    std::map<std::string, std::string> header;
    for (std::size_t i = 0; i < keys.size(); ++i) header[keys[i]] = values[i];
    EXPECT_EQ(std::stoul(header.at("NumFrames")), xyz.rows.size());
    EXPECT_EQ(std::stoul(header.at("NumMarkers")), names.size());
    EXPECT_EQ(header.at("Units"), "mm");
    EXPECT_DOUBLE_EQ(std::stod(header.at("DataRate")), synthetic_->session.manifest.video.frame_rate_hz);
    const auto labels = split_on(lines[3], '\t');
    for (std::size_t p = 0; p < names.size(); ++p) EXPECT_EQ(labels.at(2 + 3 * p), names[p]);
    double worst_time_s = 0.0;
    for (std::size_t f = 0; f < xyz.rows.size(); ++f) {
      const auto row = split_on(lines[5 + f], '\t');
      ASSERT_EQ(row.size(), 2 + 3 * names.size());
      // The frame's true force-clock time; synchronisation is good to about
      // 0.1-0.6 ms with a mat whose top layer has mass (trial/trial.h): 1 ms.
      worst_time_s = std::max(worst_time_s, std::abs(std::stod(row[1]) - truth.frame_force_time_s[f]));
      for (std::size_t p = 0; p < names.size(); ++p) {
        const double X = xyz.rows[f][3 * p], Y = xyz.rows[f][3 * p + 1], Z = xyz.rows[f][3 * p + 2];
        const double x = std::stod(row[2 + 3 * p]), y = std::stod(row[3 + 3 * p]), z = std::stod(row[4 + 3 * p]);
        if (std::isnan(X)) {
          EXPECT_TRUE(std::isnan(x));
          continue;
        }
        // 9 significant digits in both files: 1e-5 mm.
        ASSERT_NEAR(x, 1e3 * X, 1e-5);
        ASSERT_NEAR(y, 1e3 * Z, 1e-5);
        ASSERT_NEAR(z, -1e3 * Y, 1e-5);
      }
    }
    EXPECT_LT(worst_time_s, 1e-3) << id;
    RecordProperty(id + "_trc_worst_time_error_ms", std::to_string(worst_time_s * 1e3));
  }
}

// grf.mot parsed back: the header, vertical force = series.csv's Fz at the
// same force-clock time, and the generator's centre of pressure and shear.
TEST_F(CliVersion2Outputs, GrfMotParsesBackToThePlateForceAndTrueCop) {
  ASSERT_EQ(run_->exit_code, 0) << run_->describe();
  for (const auto& truth : synthetic_->truth.trials) {
    const auto lines = text_lines(read_text(out() / "trials" / truth.id / "grf.mot"));
    ASSERT_GT(lines.size(), 7u);
    EXPECT_EQ(lines[1], "version=1");
    const std::size_t n_rows = std::stoul(lines[2].substr(lines[2].find('=') + 1));
    EXPECT_EQ(lines[3], "nColumns=10");
    EXPECT_EQ(lines[5], "endheader");
    ASSERT_EQ(lines.size(), 7 + n_rows);
    const auto labels = split_on(lines[6], '\t');
    ASSERT_EQ(labels.size(), 10u);
    EXPECT_EQ(labels[2], "ground_force_vy");
    std::map<long, std::vector<double>> by_time;  // keyed by time in microseconds
    for (std::size_t i = 7; i < lines.size(); ++i) {
      std::vector<double> v;
      for (const auto& f : split_on(lines[i], '\t')) v.push_back(std::stod(f));
      ASSERT_EQ(v.size(), 10u);
      by_time[std::lround(v[0] * 1e6)] = v;
    }
    const Table series = read_csv(read_text(out() / "trials" / truth.id / "series.csv"));
    int matched = 0;
    double peak = 0.0;
    std::vector<double> at_peak;
    for (const auto& r : series.rows) {
      const auto it = by_time.find(std::lround(r[0] * 1e6));
      ASSERT_NE(it, by_time.end()) << "series time " << r[0] << " not in grf.mot";
      EXPECT_NEAR(it->second[2], r[1], 1e-6 * std::max(1.0, std::abs(r[1])));  // OpenSim y = lab Z = Fz
      ++matched;
      if (r[1] > peak) {
        peak = r[1];
        at_peak = it->second;
      }
    }
    EXPECT_GT(matched, 20);
    ASSERT_GT(peak, 1000.0);
    // At the peak (thousands of newtons against 1 N channel noise) the COP is
    // the generator's to well under a millimetre: 1 mm. OpenSim's px = lab X,
    // pz = -lab Y.
    EXPECT_NEAR(at_peak[4], truth.cop_m.x(), 1e-3);
    EXPECT_NEAR(at_peak[5], 0.0, 1e-12);
    EXPECT_NEAR(at_peak[6], -truth.cop_m.y(), 1e-3);
    // Shear: Fx / Fz and Fy / Fz as generated (noise 1 N on ~7 kN: 1e-3).
    EXPECT_NEAR(at_peak[1] / at_peak[2], truth.shear_fraction.x(), 1e-3);
    EXPECT_NEAR(-at_peak[3] / at_peak[2], truth.shear_fraction.y(), 1e-3);
  }
}

}  // namespace
}  // namespace dropfit::clitest

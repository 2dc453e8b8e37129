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

#include "core/error.h"
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
  double velocity = NAN;
  for (const auto& t : doc["trials"])
    if (t["id"] == train) velocity = t["impact_velocity_m_s"].get<double>();
  ASSERT_TRUE(std::isfinite(velocity)) << train;
  const Table series = read_csv(read_text(out / "series" / (train + ".csv")));
  ASSERT_GT(series.rows.size(), 50u);
  const int ct = series.col("t_s"), cf = series.col("simulated_fz_n");
  ASSERT_GE(ct, 0);
  ASSERT_GE(cf, 0);
  // The series starts at the first force sample at or after contact: its
  // time (from contact) is the simulation's first output time.
  const double t_first = series.rows.front()[ct], t_last = series.rows.back()[ct];
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
    ASSERT_NEAR(s.rows[i][st], series.rows[i][ct], 1e-3 * dt) << "row " << i;
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

}  // namespace
}  // namespace dropfit::clitest

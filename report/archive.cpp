// Many results folders into one archive table (report/archive.h).
#include "report/archive.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include "core/error.h"
#include "report/plot.h"

namespace dropfit::report {

namespace fs = std::filesystem;

namespace {

std::string read_file(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path.string(), 0, 0, "", "cannot read");
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// summary.csv: trials and accepted ("yes" in the second column).
void read_summary(const fs::path& path, ArchiveSession& row) {
  std::istringstream in(read_file(path));
  std::string line;
  int n = 0;
  if (!std::getline(in, line) || line.rfind("trial,accepted,", 0) != 0) {
    throw InputError(path.string(), 1, 1, "", "not a dropfit summary.csv (header 'trial,accepted,...')");
  }
  while (std::getline(in, line)) {
    ++n;
    if (line.empty()) continue;
    const auto a = line.find(','), b = a == std::string::npos ? a : line.find(',', a + 1);
    if (b == std::string::npos) throw InputError(path.string(), n + 1, 0, "accepted", "missing");
    const std::string accepted = line.substr(a + 1, b - a - 1);
    ++row.trials;
    row.accepted += accepted == "yes";
  }
}

ArchiveModel read_fit(const fs::path& path) {
  nlohmann::json doc;
  try {
    doc = nlohmann::json::parse(read_file(path));
  } catch (const nlohmann::json::exception&) {
    throw InputError(path.string(), 0, 0, "", "not valid JSON");
  }
  ArchiveModel m;
  auto field = [&](const char* name) -> const nlohmann::json& {
    if (!doc.is_object() || !doc.contains(name)) throw InputError(path.string(), 0, 0, name, "missing");
    return doc[name];
  };
  if (!field("model").is_string()) throw InputError(path.string(), 0, 0, "model", "not a string");
  m.model = doc["model"].get<std::string>();
  if (!field("parameters").is_object()) throw InputError(path.string(), 0, 0, "parameters", "not an object");
  for (const auto& [k, v] : doc["parameters"].items()) {
    if (!v.is_number()) throw InputError(path.string(), 0, 0, "parameters." + k, "not a number");
    m.parameters[k] = v.get<double>();
  }
  double sum = 0.0, worst = 0.0;
  int n = 0;
  if (doc.contains("trials") && doc["trials"].is_array()) {
    m.trials = static_cast<int>(doc["trials"].size());
    for (const auto& t : doc["trials"]) {
      if (t.is_object() && t.contains("rms_force_pct_peak") && t["rms_force_pct_peak"].is_number()) {
        const double r = t["rms_force_pct_peak"].get<double>();
        sum += r;
        worst = std::max(worst, r);
        ++n;
      }
    }
  }
  if (n > 0) m.mean_rms_force_pct = sum / n, m.max_rms_force_pct = worst;
  if (doc.contains("heldout_peak_force_pct_max") && doc["heldout_peak_force_pct_max"].is_number())
    m.heldout_peak_pct_max = doc["heldout_peak_force_pct_max"].get<double>();
  if (doc.contains("warnings") && doc["warnings"].is_array()) m.warnings = static_cast<int>(doc["warnings"].size());
  return m;
}

bool is_table_results(const fs::path& dir) {
  return !fs::exists(dir / "summary.csv") && fs::is_regular_file(dir / "fit.json") &&
         fs::is_regular_file(dir / "predictions.csv");
}

bool is_results(const fs::path& dir) { return fs::exists(dir / "summary.csv") || is_table_results(dir); }

std::string csv_field(const std::string& s) {
  if (s.find_first_of(",\"\n") == std::string::npos) return s;
  std::string out = "\"";
  for (char c : s) out += c == '"' ? std::string("\"\"") : std::string(1, c);
  return out + "\"";
}

std::string number(double v) { return std::isfinite(v) ? fmt::format("{:.6g}", v) : std::string(); }

}  // namespace

ArchiveSession read_results_folder(const fs::path& dir) {
  ArchiveSession row;
  row.dir = dir;
  if (is_table_results(dir)) {
    // `dropfit table`: one fit over the impacts of a table, none rejected.
    row.source = "table";
    ArchiveModel m = read_fit(dir / "fit.json");
    m.label = "table:" + m.model;
    row.trials = row.accepted = m.trials;
    row.models.push_back(std::move(m));
    return row;
  }
  read_summary(dir / "summary.csv", row);
  std::vector<fs::path> fits;
  if (fs::is_directory(dir / "fits")) {
    for (const auto& e : fs::directory_iterator(dir / "fits")) {
      if (fs::is_regular_file(e.path() / "fit.json")) fits.push_back(e.path() / "fit.json");
    }
  }
  std::sort(fits.begin(), fits.end());
  for (const auto& f : fits) {
    row.models.push_back(read_fit(f));
    row.models.back().label = f.parent_path().filename().string();
  }
  return row;
}

// An argument: a run's or a table's results, or a folder of them (one level down).
std::vector<fs::path> result_folders(const std::string& arg) {
  const fs::path dir(arg);
  if (!fs::is_directory(dir)) throw Error(fmt::format("{}: not a folder", arg));
  if (is_results(dir)) return {dir};
  std::vector<fs::path> found;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.is_directory() && is_results(e.path())) found.push_back(e.path());
  }
  std::sort(found.begin(), found.end());
  if (found.empty()) {
    throw Error(fmt::format("{}: no dropfit results here (no summary.csv, or fit.json and predictions.csv of a table, "
                            "in it or its sub-folders)",
                            arg));
  }
  return found;
}

Archive gather_results(const std::vector<std::string>& args, const fs::path& out_dir) {
  std::vector<ArchiveSession> rows;
  std::set<std::string> parameter_names;
  std::set<fs::path> seen;  // each results folder once, however it was reached
  for (const auto& arg : args) {
    for (const auto& dir : result_folders(arg)) {
      if (!seen.insert(fs::weakly_canonical(dir)).second) continue;
      rows.push_back(read_results_folder(dir));
      for (const auto& m : rows.back().models) {
        for (const auto& [k, v] : m.parameters) parameter_names.insert(k);
      }
    }
  }
  const fs::path out_abs = fs::absolute(out_dir);
  std::string csv = "session,results,source,trials,accepted,model,fitted_model";
  for (const auto& p : parameter_names) csv += "," + p;
  csv += ",mean_rms_force_pct_peak,max_rms_force_pct_peak,heldout_peak_force_pct_max,warnings\n";
  std::string table = "<tr><th>session</th><th>trials</th><th>accepted</th><th>model</th>";
  for (const auto& p : parameter_names) table += "<th>" + escape_xml(p) + "</th>";
  table += "<th>mean RMS force error (% of peak)</th><th>held-out peak error, largest (%)</th><th>warnings</th></tr>\n";
  int with_fits = 0;
  for (const auto& r : rows) {
    const std::string name = r.dir.filename().string();
    const std::string abs = fs::absolute(r.dir).lexically_normal().string();
    const std::string link = fs::relative(fs::absolute(r.dir) / "report.html", out_abs).string();
    with_fits += !r.models.empty();
    std::vector<ArchiveModel> models = r.models;
    if (models.empty()) models.push_back({});  // a row for a session without fits
    for (const auto& m : models) {
      csv += fmt::format("{},{},{},{},{},{},{}", csv_field(name), csv_field(abs), r.source, r.trials, r.accepted,
                         csv_field(m.label), csv_field(m.model));
      table += fmt::format("<tr><td><a href=\"{}\">{}</a></td><td>{}</td><td>{}</td><td>{}</td>", escape_xml(link),
                           escape_xml(name), r.trials, r.accepted,
                           escape_xml(m.label.empty() ? "no fit" : m.label));
      for (const auto& p : parameter_names) {
        const auto it = m.parameters.find(p);
        const std::string v = it == m.parameters.end() ? std::string() : number(it->second);
        csv += "," + v;
        table += "<td>" + v + "</td>";
      }
      csv += fmt::format(",{},{},{},{}\n", number(m.mean_rms_force_pct), number(m.max_rms_force_pct),
                         number(m.heldout_peak_pct_max), m.warnings);
      table += fmt::format("<td>{}</td><td>{}</td><td>{}</td></tr>\n", number(m.mean_rms_force_pct),
                           number(m.heldout_peak_pct_max), m.warnings);
    }
  }
  std::string html =
      "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>dropfit archive</title>\n"
      "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
      "td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}td:first-child,th{text-align:left}</style>"
      "</head><body>\n";
  html += fmt::format("<h1>dropfit archive</h1>\n<p>{} results folder(s), {} with fitted models. Each session links to its "
                      "report; archive.csv holds the same table.</p>\n<table>\n",
                      rows.size(), with_fits);
  html += table + "</table>\n</body></html>\n";
  Archive archive;
  archive.files.add("archive.csv", csv);
  archive.files.add("archive.html", html);
  archive.sessions = std::move(rows);
  return archive;
}

}  // namespace dropfit::report

#include "report/table.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>

#include "core/error.h"
#include "report/export.h"
#include "report/html.h"
#include "report/plot.h"
#include "report/results.h"

namespace dropfit::report {

namespace {

std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r\n");
  if (b == std::string::npos) return "";
  const auto e = s.find_last_not_of(" \t\r\n");
  return s.substr(b, e - b + 1);
}

std::vector<std::string> split_fields(const std::string& line, char sep) {
  std::vector<std::string> out;
  std::string f;
  std::istringstream in(line);
  while (std::getline(in, f, sep)) out.push_back(trim(f));
  if (!line.empty() && line.back() == sep) out.emplace_back();
  return out;
}

// A whole-field number; NaN for "", "NaN" or "nan" only when `missing_ok`.
double parse_number(const std::string& text, const std::string& path, int line, int column, const std::string& field,
                    bool missing_ok) {
  if (missing_ok && (text.empty() || text == "NaN" || text == "nan" || text == "NA")) return std::nan("");
  if (text.empty()) throw InputError(path, line, column, field, "empty: a number is needed");
  std::size_t used = 0;
  double v = 0.0;
  try {
    v = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != text.size() || !std::isfinite(v))
    throw InputError(path, line, column, field, fmt::format("'{}' is not a finite number", text));
  return v;
}

std::string num(double v, int decimals) {
  if (!std::isfinite(v)) return "-";
  return fmt::format("{:.{}f}", v, decimals);
}

using nlohmann::json;
json number_or_null(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

json named(fitting::ModelKind model, const fitting::MatParams& p) {
  json out = json::object();
  for (const auto& [name, value] : named_parameters(model, p)) out[name] = value;
  return out;
}

const TableHeldOut* held_out_of(const TableRun& run, const std::string& id) {
  for (const auto& h : run.leave_one_out)
    if (h.id == id) return &h;
  return nullptr;
}

}  // namespace

std::vector<fitting::TableTrial> parse_impact_table(const std::string& raw, const std::string& path) {
  std::string text = raw;
  if (text.rfind("\xEF\xBB\xBF", 0) == 0) text.erase(0, 3);  // UTF-8 byte-order mark
  std::istringstream in(text);
  std::string line;
  int line_no = 0;
  std::vector<std::string> header;
  char sep = ',';
  int c_id = -1, c_v = -1, c_d = -1, c_f = -1;
  std::vector<fitting::TableTrial> rows;
  std::set<std::string> ids;
  while (std::getline(in, line)) {
    ++line_no;
    const std::string t = trim(line);
    if (t.empty() || t[0] == '#') continue;
    if (header.empty()) {
      sep = t.find('\t') != std::string::npos && t.find(',') == std::string::npos ? '\t' : ',';
      header = split_fields(t, sep);
      for (std::size_t i = 0; i < header.size(); ++i) {
        const std::string& h = header[i];
        int* slot = h == "trial" || h == "id" ? &c_id
                    : h == "impact_velocity_m_s" ? &c_v
                    : h == "max_deformation_m"   ? &c_d
                    : h == "peak_force_n"        ? &c_f
                                                 : nullptr;
        if (!slot)
          throw InputError(path, line_no, static_cast<int>(i) + 1, h,
                           "unknown column (expected trial, impact_velocity_m_s, max_deformation_m, peak_force_n)");
        if (*slot >= 0) throw InputError(path, line_no, static_cast<int>(i) + 1, h, "duplicate column");
        *slot = static_cast<int>(i);
      }
      for (const auto& [col, name] : {std::pair{c_id, "trial"}, std::pair{c_v, "impact_velocity_m_s"},
                                      std::pair{c_f, "peak_force_n"}}) {
        if (col < 0) throw InputError(path, line_no, 0, name, "missing column");
      }
      continue;
    }
    const auto f = split_fields(t, sep);
    if (f.size() != header.size()) {
      throw InputError(path, line_no, 0, "",
                       fmt::format("{} fields where the header has {}", f.size(), header.size()));
    }
    fitting::TableTrial row;
    row.id = f[c_id];
    if (row.id.empty()) throw InputError(path, line_no, c_id + 1, header[c_id], "empty trial id");
    if (!ids.insert(row.id).second)
      throw InputError(path, line_no, c_id + 1, header[c_id], fmt::format("trial '{}' appears twice", row.id));
    row.impact_velocity_m_s = parse_number(f[c_v], path, line_no, c_v + 1, header[c_v], false);
    if (!(row.impact_velocity_m_s > 0.0))
      throw InputError(path, line_no, c_v + 1, header[c_v], "must be positive (downward speed at contact)");
    row.peak_force_n = parse_number(f[c_f], path, line_no, c_f + 1, header[c_f], false);
    if (!(row.peak_force_n > 0.0)) throw InputError(path, line_no, c_f + 1, header[c_f], "must be positive");
    if (c_d >= 0) {
      row.max_deformation_m = parse_number(f[c_d], path, line_no, c_d + 1, header[c_d], true);
      if (std::isfinite(row.max_deformation_m) && !(row.max_deformation_m > 0.0))
        throw InputError(path, line_no, c_d + 1, header[c_d], "must be positive (metres), or empty when not measured");
      if (row.max_deformation_m > 2.0)
        throw InputError(path, line_no, c_d + 1, header[c_d],
                         fmt::format("{} m is not a mat's deformation: millimetres written as metres?", row.max_deformation_m));
    }
    rows.push_back(row);
  }
  if (header.empty()) throw InputError(path, 0, 0, "", "no header line");
  if (rows.size() < 2) throw InputError(path, 0, 0, "", fmt::format("{} impacts; at least 2 are needed", rows.size()));
  return rows;
}

double heldout_peak_pct_max(const TableRun& run) {
  double m = 0.0;
  for (const auto& h : run.leave_one_out) m = std::max(m, std::abs(h.peak_force_pct_diff));
  return run.leave_one_out.empty() ? std::nan("") : m;
}

double heldout_peak_pct_rms(const TableRun& run) {
  double s = 0.0;
  for (const auto& h : run.leave_one_out) s += h.peak_force_pct_diff * h.peak_force_pct_diff;
  return run.leave_one_out.empty() ? std::nan("") : std::sqrt(s / static_cast<double>(run.leave_one_out.size()));
}

std::string table_fit_json(const TableRun& run) {
  json trials = json::array();
  for (const auto& t : run.fit.trials) {
    const double ddef = 1e3 * (t.simulated_max_deformation_m - t.max_deformation_m);
    trials.push_back({{"id", t.id},
                      {"train", t.train},
                      {"impact_velocity_m_s", t.impact_velocity_m_s},
                      {"rms_force_pct_peak", nullptr},
                      {"peak_force_pct_diff", t.peak_force_pct_diff},
                      {"time_to_peak_ms_diff", nullptr},
                      {"max_deformation_mm_diff", number_or_null(ddef)},
                      {"peak_force_n", t.peak_force_n},
                      {"simulated_peak_force_n", t.simulated_peak_force_n},
                      {"max_deformation_m", number_or_null(t.max_deformation_m)},
                      {"simulated_max_deformation_m", t.simulated_max_deformation_m}});
  }
  json loo = json::array();
  for (const auto& h : run.leave_one_out) {
    loo.push_back({{"held_out", h.id},
                   {"parameters", named(run.model, h.params)},
                   {"impact_velocity_m_s", h.impact_velocity_m_s},
                   {"peak_force_n", h.peak_force_n},
                   {"simulated_peak_force_n", h.simulated_peak_force_n},
                   {"peak_force_pct_diff", h.peak_force_pct_diff},
                   {"max_deformation_m", number_or_null(h.max_deformation_m)},
                   {"simulated_max_deformation_m", h.simulated_max_deformation_m}});
  }
  json alternatives = json::array();
  for (const auto& p : run.fit.alternatives) alternatives.push_back(named(run.model, p));
  json doc = {{"model", fitting::model_name(run.model)},
              {"source", "table"},
              {"table", run.table_path},
              {"train", run.train_ids},
              {"free", run.free},
              {"impactor_mass_kg", run.impactor_mass_kg},
              {"gravity_m_s2", run.gravity_m_s2},
              {"parameters", named(run.model, run.fit.params)},
              {"trials", trials},
              {"leave_one_out", loo},
              {"heldout_peak_force_pct_max", number_or_null(heldout_peak_pct_max(run))},
              {"heldout_peak_force_pct_rms", number_or_null(heldout_peak_pct_rms(run))},
              {"alternatives", alternatives},
              {"warnings", run.fit.warnings}};
  return doc.dump(2) + "\n";
}

std::string table_predictions_csv(const TableRun& run) {
  std::string out =
      "trial,train,impact_velocity_m_s,peak_force_n,simulated_peak_force_n,peak_force_pct_diff,"
      "heldout_simulated_peak_force_n,heldout_peak_force_pct_diff,max_deformation_m,simulated_max_deformation_m\n";
  for (const auto& t : run.fit.trials) {
    const TableHeldOut* h = held_out_of(run, t.id);
    out += fmt::format("{},{},{},{},{},{},{},{},{},{}\n", t.id, t.train ? "yes" : "no",
                       csv_number(t.impact_velocity_m_s), csv_number(t.peak_force_n),
                       csv_number(t.simulated_peak_force_n), csv_number(t.peak_force_pct_diff, 6),
                       csv_number(h ? h->simulated_peak_force_n : NAN), csv_number(h ? h->peak_force_pct_diff : NAN, 6),
                       csv_number(t.max_deformation_m), csv_number(t.simulated_max_deformation_m));
  }
  return out;
}

std::string table_report_html(const TableRun& run) {
  HtmlDocument doc("dropfit report: " + run.table_path);
  doc.paragraph(fmt::format(
      "Impact table {}: {} impacts of a {} kg impactor, only per-impact summaries (velocity, maximum deformation, "
      "peak force), as the paper's Table 1. Mat {} fitted to {} ({}), every impact predicted from its own "
      "velocity; models after Mills, Pain & Yeadon (2006).",
      run.table_path, run.trials.size(), num(run.impactor_mass_kg, 1), fitting::model_name(run.model),
      run.train_ids.size() == 1 ? "impact " + run.train_ids.front() : fmt::format("{} impacts", run.train_ids.size()),
      fmt::format("free: {}", fmt::join(run.free, ", "))));
  for (const auto& n : run.notes) doc.note(n);
  for (const auto& w : run.fit.warnings) doc.note(w);

  doc.heading("Impacts and predictions");
  std::vector<std::vector<std::string>> rows;
  for (const auto& t : run.fit.trials) {
    const TableHeldOut* h = held_out_of(run, t.id);
    rows.push_back({t.id, t.train ? "train" : "predicted", num(t.impact_velocity_m_s, 2), num(t.max_deformation_m, 3),
                    num(t.simulated_max_deformation_m, 3), num(t.peak_force_n, 0), num(t.simulated_peak_force_n, 0),
                    fmt::format("{:+.1f}", t.peak_force_pct_diff), h ? fmt::format("{:+.1f}", h->peak_force_pct_diff) : "-"});
  }
  doc.table({"impact", "role", "velocity (m/s)", "deformation (m)", "simulated (m)", "peak force (N)", "simulated (N)",
             "peak error (%)", "left out: peak error (%)"},
            rows, "Measured and simulated per impact (simulated minus measured, % of measured)", 2);

  doc.heading("Fitted parameters");
  std::vector<std::vector<std::string>> prow;
  for (const auto& [name, value] : named_parameters(run.model, run.fit.params)) {
    const bool free = std::find(run.free.begin(), run.free.end(), name) != run.free.end();
    prow.push_back({name, fmt::format("{:.6g}", value), free ? "fitted" : "fixed"});
  }
  doc.table({"parameter", "value", ""}, prow, fmt::format("{} (units in the names)", fitting::model_name(run.model)), 1);
  if (!run.fit.alternatives.empty()) {
    doc.note(fmt::format("{} other parameter sets fit the training impacts as well: the summaries do not pin the "
                         "model down (fit.json lists them).",
                         run.fit.alternatives.size()));
  }

  doc.heading("Leave one out");
  doc.paragraph(fmt::format(
      "Each impact left out in turn: the model fitted to every other impact, then its peak force predicted from its "
      "velocity. Largest |error| {} %, RMS {} %.",
      num(heldout_peak_pct_max(run), 1), num(heldout_peak_pct_rms(run), 1)));
  std::vector<std::vector<std::string>> lrows;
  for (const auto& h : run.leave_one_out) {
    lrows.push_back({h.id, num(h.impact_velocity_m_s, 2), num(h.peak_force_n, 0), num(h.simulated_peak_force_n, 0),
                     fmt::format("{:+.1f}", h.peak_force_pct_diff)});
  }
  doc.table({"left out", "velocity (m/s)", "measured peak (N)", "predicted peak (N)", "peak error (%)"}, lrows,
            "Leave-one-out peak-force errors (predicted minus measured, % of measured)", 1);

  LinePlot plot{"Peak force against impact velocity", "impact velocity (m/s)", "peak force (N)", {}, 640, 360};
  LineSeries measured{"measured", {}, {}, "#111827", false, true};
  LineSeries held{"left out, predicted", {}, {}, "#d62728", false, true};
  for (const auto& t : run.trials) {
    measured.x.push_back(t.impact_velocity_m_s);
    measured.y.push_back(t.peak_force_n);
  }
  for (const auto& h : run.leave_one_out) {
    held.x.push_back(h.impact_velocity_m_s);
    held.y.push_back(h.simulated_peak_force_n);
  }
  plot.series.push_back({fitting::model_name(run.model) + " (trained)", run.curve_velocity_m_s, run.curve_peak_force_n,
                         "#1f77b4", false, false});
  plot.series.push_back(measured);
  if (!held.x.empty()) plot.series.push_back(held);
  doc.figure(svg(plot), "Measured peaks, the trained model's prediction over the velocity range, and each impact's "
                        "peak predicted with that impact left out.");

  if (run.loop_run) {
    append_loop_section(doc, run.loop_baseline_model, run.loop_effects, run.loop_unexplained);
    doc.paragraph("The loop's held-out errors come from diagnosis' table stage: Model 1 refitted without each impact, "
                  "with each velocity allowed its measurement uncertainty (errors in variables), so they differ from "
                  "the leave-one-out table above, which takes the velocities as exact.");
  }
  return doc.str();
}

}  // namespace dropfit::report

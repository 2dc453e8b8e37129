#include "report/plot.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace dropfit::report {
namespace {

const char* kPalette[] = {"#1f2937", "#d62728", "#1f77b4", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#17becf"};

std::string colour(const std::string& given, size_t index) {
  return given.empty() ? kPalette[index % (sizeof(kPalette) / sizeof(kPalette[0]))] : given;
}

std::string tick_label(double v, double step) {
  const int decimals = step >= 1.0 ? 0 : std::min(6, static_cast<int>(std::ceil(-std::log10(step))));
  if (std::abs(v) < step * 1e-9) v = 0.0;
  return fmt::format("{:.{}f}", v, decimals);
}

double nice_number(double range, bool round) {
  const double exponent = std::floor(std::log10(range));
  const double fraction = range / std::pow(10.0, exponent);
  double nice;
  if (round) {
    nice = fraction < 1.5 ? 1 : fraction < 3 ? 2 : fraction < 7 ? 5 : 10;
  } else {
    nice = fraction <= 1 ? 1 : fraction <= 2 ? 2 : fraction <= 5 ? 5 : 10;
  }
  return nice * std::pow(10.0, exponent);
}

struct Frame {
  double left = 70, right = 20, top = 36, bottom = 52;
  double width, height;
  double x0, x1, y0, y1;
  double px(double x) const { return left + (x - x0) / (x1 - x0) * (width - left - right); }
  double py(double y) const { return height - bottom - (y - y0) / (y1 - y0) * (height - top - bottom); }
};

std::string axes(const Frame& f, const std::vector<double>& xt, const std::vector<double>& yt,
                 const std::string& title, const std::string& x_label, const std::string& y_label,
                 bool x_ticks_numeric = true) {
  std::string s;
  const double step_x = xt.size() > 1 ? xt[1] - xt[0] : 1.0;
  const double step_y = yt.size() > 1 ? yt[1] - yt[0] : 1.0;
  for (double y : yt) {
    const double p = f.py(y);
    s += fmt::format(R"(<line x1="{:.1f}" y1="{:.1f}" x2="{:.1f}" y2="{:.1f}" stroke="#e5e7eb"/>)", f.left, p,
                     f.width - f.right, p);
    s += fmt::format(R"(<text x="{:.1f}" y="{:.1f}" text-anchor="end" class="tick">{}</text>)", f.left - 6, p + 4,
                     tick_label(y, step_y));
  }
  if (x_ticks_numeric) {
    for (double x : xt) {
      const double p = f.px(x);
      s += fmt::format(R"(<line x1="{:.1f}" y1="{:.1f}" x2="{:.1f}" y2="{:.1f}" stroke="#f3f4f6"/>)", p, f.top, p,
                       f.height - f.bottom);
      s += fmt::format(R"(<text x="{:.1f}" y="{:.1f}" text-anchor="middle" class="tick">{}</text>)", p,
                       f.height - f.bottom + 16, tick_label(x, step_x));
    }
  }
  s += fmt::format(R"(<rect x="{:.1f}" y="{:.1f}" width="{:.1f}" height="{:.1f}" fill="none" stroke="#6b7280"/>)",
                   f.left, f.top, f.width - f.left - f.right, f.height - f.top - f.bottom);
  s += fmt::format(R"(<text x="{:.1f}" y="20" text-anchor="middle" class="title">{}</text>)", f.width / 2,
                   escape_xml(title));
  s += fmt::format(R"(<text x="{:.1f}" y="{:.1f}" text-anchor="middle" class="label">{}</text>)",
                   (f.left + f.width - f.right) / 2, f.height - 12, escape_xml(x_label));
  s += fmt::format(
      R"~(<text x="16" y="{:.1f}" text-anchor="middle" class="label" transform="rotate(-90 16 {:.1f})">{}</text>)~",
      (f.top + f.height - f.bottom) / 2, (f.top + f.height - f.bottom) / 2, escape_xml(y_label));
  return s;
}

std::string legend(const Frame& f, const std::vector<std::pair<std::string, std::string>>& entries,
                   const std::vector<bool>& dashed) {
  std::string s;
  double y = f.top + 14;
  for (size_t i = 0; i < entries.size(); ++i) {
    const double x = f.width - f.right - 160;
    s += fmt::format(R"(<line x1="{:.1f}" y1="{:.1f}" x2="{:.1f}" y2="{:.1f}" stroke="{}" stroke-width="2"{}/>)", x,
                     y - 4, x + 22, y - 4, entries[i].second, dashed[i] ? R"( stroke-dasharray="5 3")" : "");
    s += fmt::format(R"(<text x="{:.1f}" y="{:.1f}" class="legend">{}</text>)", x + 28, y,
                     escape_xml(entries[i].first));
    y += 16;
  }
  return s;
}

std::string open_svg(int width, int height, const std::string& kind) {
  return fmt::format(
      R"(<svg xmlns="http://www.w3.org/2000/svg" class="plot {}" width="{}" height="{}" viewBox="0 0 {} {}" role="img">)"
      R"(<style>.tick{{font:11px sans-serif;fill:#374151}}.label{{font:12px sans-serif;fill:#111827}})"
      R"(.title{{font:bold 13px sans-serif;fill:#111827}}.legend{{font:11px sans-serif;fill:#111827}}</style>)",
      kind, width, height, width, height);
}

}  // namespace

std::string escape_xml(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  for (char c : text) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

std::vector<double> nice_ticks(double lo, double hi, int target) {
  if (!(hi > lo)) {
    const double pad = std::max(1.0, std::abs(lo) * 0.1);
    lo -= pad;
    hi += pad;
  }
  const double range = nice_number(hi - lo, false);
  const double step = nice_number(range / std::max(1, target - 1), true);
  std::vector<double> ticks;
  for (double v = std::floor(lo / step) * step; v <= std::ceil(hi / step) * step + step * 0.5; v += step) {
    ticks.push_back(v);
  }
  return ticks;
}

std::string svg(const LinePlot& plot) {
  double xmin = std::numeric_limits<double>::infinity(), xmax = -xmin, ymin = xmin, ymax = -xmin;
  for (const auto& s : plot.series) {
    for (size_t i = 0; i < std::min(s.x.size(), s.y.size()); ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) continue;
      xmin = std::min(xmin, s.x[i]);
      xmax = std::max(xmax, s.x[i]);
      ymin = std::min(ymin, s.y[i]);
      ymax = std::max(ymax, s.y[i]);
    }
  }
  if (!std::isfinite(xmin)) xmin = 0, xmax = 1, ymin = 0, ymax = 1;
  const auto xt = nice_ticks(xmin, xmax);
  const auto yt = nice_ticks(ymin, ymax);
  Frame f;
  f.width = plot.width_px;
  f.height = plot.height_px;
  f.x0 = xt.front();
  f.x1 = xt.back();
  f.y0 = yt.front();
  f.y1 = yt.back();

  std::string s = open_svg(plot.width_px, plot.height_px, "line-plot");
  s += axes(f, xt, yt, plot.title, plot.x_label, plot.y_label);
  std::vector<std::pair<std::string, std::string>> entries;
  std::vector<bool> dashed;
  for (size_t k = 0; k < plot.series.size(); ++k) {
    const auto& series = plot.series[k];
    const std::string c = colour(series.color, k);
    const size_t n = std::min(series.x.size(), series.y.size());
    if (series.points) {
      for (size_t i = 0; i < n; ++i) {
        if (!std::isfinite(series.x[i]) || !std::isfinite(series.y[i])) continue;
        s += fmt::format(R"(<circle cx="{:.1f}" cy="{:.1f}" r="3.5" fill="{}"/>)", f.px(series.x[i]),
                         f.py(series.y[i]), c);
      }
    } else {
      std::string d;
      bool pen_down = false;
      for (size_t i = 0; i < n; ++i) {
        if (!std::isfinite(series.x[i]) || !std::isfinite(series.y[i])) {
          pen_down = false;
          continue;
        }
        d += fmt::format("{}{:.1f},{:.1f}", pen_down ? " L" : " M", f.px(series.x[i]), f.py(series.y[i]));
        pen_down = true;
      }
      s += fmt::format(R"(<path class="series" d="{}" fill="none" stroke="{}" stroke-width="1.6"{}/>)", d, c,
                       series.dashed ? R"( stroke-dasharray="5 3")" : "");
    }
    entries.emplace_back(series.label, c);
    dashed.push_back(series.dashed);
  }
  s += legend(f, entries, dashed);
  s += "</svg>";
  return s;
}

std::string svg(const BarPlot& plot) {
  double ymin = 0.0, ymax = 0.0;
  for (const auto& g : plot.groups) {
    for (double v : g.values) {
      if (!std::isfinite(v)) continue;
      ymin = std::min(ymin, v);
      ymax = std::max(ymax, v);
    }
  }
  if (ymax == ymin) ymax = ymin + 1.0;
  const auto yt = nice_ticks(ymin, ymax);
  Frame f;
  f.width = plot.width_px;
  f.height = plot.height_px;
  f.x0 = 0;
  f.x1 = std::max<size_t>(1, plot.categories.size());
  f.y0 = yt.front();
  f.y1 = yt.back();
  std::string s = open_svg(plot.width_px, plot.height_px, "bar-plot");
  s += axes(f, {}, yt, plot.title, "", plot.y_label, false);
  const double slot = (f.px(1) - f.px(0));
  const double bar = slot * 0.8 / std::max<size_t>(1, plot.groups.size());
  for (size_t c = 0; c < plot.categories.size(); ++c) {
    const double x_slot = f.px(static_cast<double>(c));
    for (size_t g = 0; g < plot.groups.size(); ++g) {
      if (c >= plot.groups[g].values.size() || !std::isfinite(plot.groups[g].values[c])) continue;
      const double v = plot.groups[g].values[c];
      const double y_top = f.py(std::max(v, 0.0)), y_bottom = f.py(std::min(v, 0.0));
      s += fmt::format(R"(<rect class="bar" x="{:.1f}" y="{:.1f}" width="{:.1f}" height="{:.1f}" fill="{}"/>)",
                       x_slot + slot * 0.1 + bar * g, y_top, bar * 0.95, std::max(0.5, y_bottom - y_top),
                       colour(plot.groups[g].color, g + 1));
    }
    s += fmt::format(R"(<text x="{:.1f}" y="{:.1f}" text-anchor="middle" class="tick">{}</text>)", x_slot + slot / 2,
                     f.height - f.bottom + 16, escape_xml(plot.categories[c]));
  }
  const double zero = f.py(0.0);
  s += fmt::format(R"(<line x1="{:.1f}" y1="{:.1f}" x2="{:.1f}" y2="{:.1f}" stroke="#111827"/>)", f.left, zero,
                   f.width - f.right, zero);
  std::vector<std::pair<std::string, std::string>> entries;
  for (size_t g = 0; g < plot.groups.size(); ++g) entries.emplace_back(plot.groups[g].label, colour(plot.groups[g].color, g + 1));
  s += legend(f, entries, std::vector<bool>(entries.size(), false));
  s += "</svg>";
  return s;
}

}  // namespace dropfit::report

#pragma once
// Plots as inline SVG, so the HTML report is one self-contained file with
// no scripts, fonts or network: line plots with axes, ticks, units and a
// legend (the paper's force-time figures), and grouped bar plots with error
// bars (calibration accuracy per marker).
#include <string>
#include <vector>

namespace dropfit::report {

struct LineSeries {
  std::string label;
  std::vector<double> x, y;  // NaN breaks the line (gaps stay gaps)
  std::string color;         // CSS colour; empty = from the palette
  bool dashed = false;
  bool points = false;       // draw markers instead of a line
};

struct LinePlot {
  std::string title;
  std::string x_label;  // with units, e.g. "time (ms)"
  std::string y_label;
  std::vector<LineSeries> series;
  int width_px = 640;
  int height_px = 360;
};

struct BarGroup {
  std::string label;           // legend entry
  std::vector<double> values;  // one per category
  std::string color;
};

struct BarPlot {
  std::string title;
  std::string y_label;
  std::vector<std::string> categories;
  std::vector<BarGroup> groups;
  int width_px = 640;
  int height_px = 320;
};

std::string svg(const LinePlot& plot);
std::string svg(const BarPlot& plot);

// "Nice" axis ticks covering [lo, hi] (Heckbert 1990), about `target` of them.
std::vector<double> nice_ticks(double lo, double hi, int target = 6);

// Escapes &, <, >, " for HTML and SVG text.
std::string escape_xml(const std::string& text);

}  // namespace dropfit::report

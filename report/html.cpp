#include "report/html.h"

#include <fmt/format.h>

#include "report/plot.h"

namespace dropfit::report {

HtmlDocument::HtmlDocument(std::string title) : title_(std::move(title)) {}

void HtmlDocument::heading(const std::string& text, int level) {
  body_ += fmt::format("<h{0}>{1}</h{0}>\n", level, escape_xml(text));
}

void HtmlDocument::paragraph(const std::string& text) { body_ += "<p>" + escape_xml(text) + "</p>\n"; }

void HtmlDocument::note(const std::string& text) { body_ += "<p class=\"note\">" + escape_xml(text) + "</p>\n"; }

void HtmlDocument::table(const std::vector<std::string>& header, const std::vector<std::vector<std::string>>& rows,
                         const std::string& caption, size_t numeric_from) {
  body_ += "<table>";
  if (!caption.empty()) body_ += "<caption>" + escape_xml(caption) + "</caption>";
  body_ += "<thead><tr>";
  for (const auto& h : header) body_ += "<th>" + escape_xml(h) + "</th>";
  body_ += "</tr></thead><tbody>\n";
  for (const auto& row : rows) {
    body_ += "<tr>";
    for (size_t i = 0; i < row.size(); ++i) {
      body_ += (i >= numeric_from ? "<td class=\"num\">" : "<td>") + escape_xml(row[i]) + "</td>";
    }
    body_ += "</tr>\n";
  }
  body_ += "</tbody></table>\n";
}

void HtmlDocument::figure(const std::string& svg, const std::string& caption) {
  ++figures_;
  body_ += fmt::format("<figure>{}<figcaption>Figure {}. {}</figcaption></figure>\n", svg, figures_,
                       escape_xml(caption));
}

void HtmlDocument::raw(const std::string& html) { body_ += html; }

std::string HtmlDocument::str() const {
  return fmt::format(R"(<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{0}</title>
<style>
body{{font:14px/1.45 system-ui,sans-serif;color:#111827;max-width:1000px;margin:2em auto;padding:0 1em}}
h1{{font-size:1.6em;border-bottom:2px solid #111827;padding-bottom:.2em}}
h2{{font-size:1.25em;margin-top:2em;border-bottom:1px solid #d1d5db}}
h3{{font-size:1.05em;margin-top:1.4em}}
table{{border-collapse:collapse;margin:.8em 0;font-size:13px}}
caption{{caption-side:top;text-align:left;font-weight:600;padding:.3em 0}}
th,td{{border:1px solid #d1d5db;padding:.25em .6em}}
th{{background:#f3f4f6}}
td.num{{text-align:right;font-variant-numeric:tabular-nums}}
figure{{margin:1em 0}}
figcaption{{font-size:12px;color:#374151}}
.note{{background:#fef3c7;border-left:4px solid #f59e0b;padding:.4em .8em}}
.ok{{color:#065f46}} .bad{{color:#991b1b}}
</style></head>
<body>
<h1>{0}</h1>
{1}</body></html>
)",
                     escape_xml(title_), body_);
}

}  // namespace dropfit::report

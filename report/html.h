#pragma once
// The report a person reads: one self-contained HTML file (inline CSS and
// SVG, no scripts, no external files, no network), built section by section.
#include <string>
#include <vector>

namespace dropfit::report {

class HtmlDocument {
 public:
  explicit HtmlDocument(std::string title);

  void heading(const std::string& text, int level = 2);
  void paragraph(const std::string& text);           // escaped
  void note(const std::string& text);                // escaped, styled as a remark
  // A table; `numeric_from` columns and beyond are right-aligned.
  void table(const std::vector<std::string>& header, const std::vector<std::vector<std::string>>& rows,
             const std::string& caption = "", size_t numeric_from = 1);
  // A figure: an SVG string from report/plot.h and its caption.
  void figure(const std::string& svg, const std::string& caption);
  void raw(const std::string& html);                 // trusted markup

  std::string str() const;

 private:
  std::string title_;
  std::string body_;
  int figures_ = 0;
};

}  // namespace dropfit::report

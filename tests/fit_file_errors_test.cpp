// Errors in a fit.json name the file, line, column and field in dropfit's
// words, not the JSON library's.
#include <gtest/gtest.h>

#include <string>

#include "core/error.h"
#include "report/export.h"

namespace dropfit {
namespace {

TEST(FitFileErrors, NumberOverflowNamesFileLineAndField) {
  const std::string text = "{\n  \"model\": \"model4\",\n  \"parameters\": {\n    \"k1_n_m\": 1e999\n  }\n}\n";
  try {
    report::parse_fit_json(text, "out/fit.json");
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), "out/fit.json");
    EXPECT_EQ(e.line(), 4);  // the line of the number
    EXPECT_EQ(e.field(), "k1_n_m");
    EXPECT_NE(std::string(e.what()).find("number too large"), std::string::npos) << e.what();
    EXPECT_EQ(std::string(e.what()).find("json.exception"), std::string::npos) << e.what();
  }
}

TEST(FitFileErrors, SyntaxErrorNamesLine) {
  try {
    report::parse_fit_json("{\n\"model\": \"model4\",\n\"parameters\": {,}\n}", "fit.json");
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(e.line(), 3);
    EXPECT_EQ(std::string(e.what()).find("json.exception"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace dropfit

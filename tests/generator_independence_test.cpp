// A generator that is not the fitter: samples/generator shares no
// simulation code with fitting/. Three checks, each of which fails if the
// dependency comes back: the generator's sources include no fitting/ header
// and name no fitting:: symbol, its CMakeLists links no dropfit_fitting, and
// the built library has no undefined reference into dropfit::fitting.
// (samples/generator/CMakeLists.txt refuses to configure in the same cases.)
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;

std::string read(const fs::path& p) {
  std::ifstream f(p);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

// C++ code lines (comments stripped) that include a fitting/ header or call
// into fitting::.
std::vector<std::string> fitting_uses(const std::string& text) {
  std::vector<std::string> hits;
  std::istringstream in(text);
  std::string line;
  bool block = false;
  static const std::regex use(R"((#\s*include\s*[<"]fitting/)|(\bfitting::))");
  while (std::getline(in, line)) {
    std::string code;
    for (std::size_t i = 0; i < line.size(); ++i) {
      if (block) {
        if (line.compare(i, 2, "*/") == 0) block = false, ++i;
        continue;
      }
      if (line.compare(i, 2, "/*") == 0) {
        block = true, ++i;
        continue;
      }
      if (line.compare(i, 2, "//") == 0) break;
      code += line[i];
    }
    if (std::regex_search(code, use)) hits.push_back(line);
  }
  return hits;
}

// target_link_libraries(...) calls of a CMakeLists.txt (comment lines
// dropped) that name dropfit_fitting.
std::vector<std::string> fitting_links(const std::string& cmake) {
  std::string text;
  std::istringstream in(cmake);
  std::string line;
  while (std::getline(in, line))
    if (line.find_first_not_of(" \t") == std::string::npos || line[line.find_first_not_of(" \t")] != '#')
      text += line.substr(0, line.find(" #")) + "\n";
  std::vector<std::string> hits;
  static const std::regex call(R"(target_link_libraries\s*\([^)]*\))");
  for (auto it = std::sregex_iterator(text.begin(), text.end(), call); it != std::sregex_iterator(); ++it)
    if (std::regex_search(it->str(), std::regex(R"(\bdropfit_fitting\b)"))) hits.push_back(it->str());
  return hits;
}

TEST(GeneratorIndependence, TheScannerSeesADependency) {
  // So that the real check below can fail.
  EXPECT_EQ(fitting_uses("#include \"fitting/models.h\"\n").size(), 1u);
  EXPECT_EQ(fitting_uses("  auto s = fitting::simulate(k, p, i);\n").size(), 1u);
  EXPECT_TRUE(fitting_uses("// not fitting::simulate\n/* fitting::x */ int a;\n").empty());
  EXPECT_EQ(fitting_links("target_link_libraries(dropfit_synth PUBLIC dropfit_capture\n  dropfit_fitting Eigen3::Eigen)\n")
                .size(),
            1u);
  EXPECT_TRUE(fitting_links("# target_link_libraries(x dropfit_fitting)\nif(dropfit_fitting IN_LIST l)\n").empty());
}

TEST(GeneratorIndependence, SourcesAndBuildRuleDoNotUseFitting) {
  const fs::path dir = fs::path(DROPFIT_SOURCE_DIR) / "samples" / "generator";
  ASSERT_TRUE(fs::is_directory(dir)) << dir;
  int scanned = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    const fs::path p = entry.path();
    const std::string ext = p.extension().string();
    if (ext != ".h" && ext != ".cpp" && p.filename() != "CMakeLists.txt") continue;
    ++scanned;
    const std::vector<std::string> hits =
        p.filename() == "CMakeLists.txt" ? fitting_links(read(p)) : fitting_uses(read(p));
    for (const std::string& hit : hits) ADD_FAILURE() << p << ": " << hit;
  }
  EXPECT_GE(scanned, 6);  // CMakeLists, physics, synth, render (.h, .cpp), main
}

TEST(GeneratorIndependence, BuiltLibraryHasNoReferenceIntoFitting) {
  // DROPFIT_CLI is <build>/cli/dropfit; the library sits beside it.
  const fs::path lib = fs::path(DROPFIT_CLI).parent_path().parent_path() / "samples" / "generator" / "libdropfit_synth.a";
  if (!fs::exists(lib)) GTEST_SKIP() << "no " << lib;
  const std::string cmd = "nm -C --undefined-only '" + lib.string() + "' 2>/dev/null";
  FILE* pipe = popen(cmd.c_str(), "r");
  if (!pipe) GTEST_SKIP() << "cannot run nm";
  std::string out;
  char buf[4096];
  while (std::fgets(buf, sizeof buf, pipe)) out += buf;
  const int rc = pclose(pipe);
  if (rc != 0 || out.empty()) GTEST_SKIP() << "nm unavailable";
  EXPECT_EQ(out.find("dropfit::fitting::"), std::string::npos) << "dropfit_synth calls into fitting";
  EXPECT_NE(out.find("std::"), std::string::npos);  // nm did list the library's references
}

}  // namespace

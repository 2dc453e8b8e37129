// The main run on the bundled sample session, and its report rendered in
// headless Chromium (Debian's package, installed by scripts/setup): the page
// loads, every plot is in the rendered DOM with something drawn in it, and
// the screenshot is not blank.
#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>

#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>

namespace fs = std::filesystem;

namespace {

struct ProcessResult {
  int exit_code = -1;
  std::string output;
};

ProcessResult run_command(const std::string& command) {
  ProcessResult r;
  FILE* pipe = popen((command + " 2>&1").c_str(), "r");
  if (!pipe) return r;
  char buffer[4096];
  while (fgets(buffer, sizeof buffer, pipe)) r.output += buffer;
  const int status = pclose(pipe);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

std::string read_text(const fs::path& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

size_t count(const std::string& text, const std::string& what) {
  size_t n = 0;
  for (size_t pos = text.find(what); pos != std::string::npos; pos = text.find(what, pos + 1)) ++n;
  return n;
}

class MainRun : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    // CTest runs each test in its own process, in parallel: one folder each.
    out_ = fs::temp_directory_path() / ("dropfit-cli-report-test-" + std::to_string(::getpid()));
    fs::remove_all(out_);
    result_ = run_command(std::string(DROPFIT_CLI) + " run " + DROPFIT_SOURCE_DIR + "/samples/demo-session --out " +
                  out_.string());
  }
  static fs::path out_;
  static ProcessResult result_;
};
fs::path MainRun::out_;
ProcessResult MainRun::result_;

TEST_F(MainRun, SucceedsAndWritesEveryOutput) {
  ASSERT_EQ(result_.exit_code, 0) << result_.output;
  for (const char* file : {"calibration.json", "dlt_coefficients.csv", "summary.csv", "fit.json", "report.html",
                           "mat.mjcf.xml", "fits/model4/mat.mjcf.xml", "trials/trial3/trial.json", "trials/trial3/series.csv"}) {
    EXPECT_TRUE(fs::exists(out_ / file)) << file;
  }
  for (int m = 1; m <= 5; ++m) EXPECT_TRUE(fs::exists(out_ / "fits" / ("model" + std::to_string(m)) / "fit.json")) << m;
  // The summary at the end says where the report is.
  EXPECT_NE(result_.output.find("report.html"), std::string::npos) << result_.output;
}

TEST_F(MainRun, ReportIsSelfContained) {
  ASSERT_EQ(result_.exit_code, 0) << result_.output;
  const std::string html = read_text(out_ / "report.html");
  EXPECT_EQ(html.find("<script"), std::string::npos);
  EXPECT_EQ(html.find("http://"), html.find("http://www.w3.org/2000/svg"));  // only the SVG namespace
  EXPECT_EQ(html.find("https://"), std::string::npos);
  EXPECT_EQ(html.find("<link"), std::string::npos);
  EXPECT_EQ(html.find("<img"), std::string::npos);
}

TEST_F(MainRun, ReportRendersInChromiumWithEveryPlotDrawn) {
  ASSERT_EQ(result_.exit_code, 0) << result_.output;
  ASSERT_TRUE(fs::exists("/usr/bin/chromium")) << "chromium is installed by scripts/setup";
  const std::string html = read_text(out_ / "report.html");
  const size_t plots_in_file = count(html, "<svg xmlns");
  // Summary, calibration (3 plots), and per trial force and travel: at least 3 + 2 x 5.
  EXPECT_GE(plots_in_file, 13u);

  const fs::path profile = out_ / "chromium-profile";
  const std::string flags = "--headless --no-sandbox --disable-gpu --disable-quic --no-first-run "
                            "--disable-background-networking --disable-component-update --disable-sync "
                            "--user-data-dir=" + profile.string();
  const std::string url = "file://" + (out_ / "report.html").string();
  const ProcessResult dom = run_command("timeout 120 /usr/bin/chromium " + flags + " --dump-dom " + url);
  ASSERT_EQ(dom.exit_code, 0) << dom.output.substr(0, 2000);
  // Every plot survived parsing into the DOM, and each has drawn content:
  // a line plot's paths have points, a bar plot has bars.
  std::regex svg_re("<svg[^>]*class=\"plot ([a-z-]+)\"[^>]*>([\\s\\S]*?)</svg>");
  size_t plots = 0, drawn = 0;
  for (std::sregex_iterator it(dom.output.begin(), dom.output.end(), svg_re), end; it != end; ++it) {
    ++plots;
    const std::string kind = (*it)[1], body = (*it)[2];
    if (kind == "line-plot") {
      std::regex path_re("class=\"series\" d=\" M[0-9.]+,[0-9.]+ L");
      if (std::regex_search(body, path_re)) ++drawn;
    } else if (body.find("class=\"bar\"") != std::string::npos) {
      ++drawn;
    }
  }
  EXPECT_EQ(plots, plots_in_file);
  EXPECT_EQ(drawn, plots);

  const fs::path png = out_ / "report.png";
  const ProcessResult shot = run_command("timeout 120 /usr/bin/chromium " + flags + " --window-size=1100,2400 --screenshot=" +
                       png.string() + " " + url);
  ASSERT_EQ(shot.exit_code, 0) << shot.output.substr(0, 2000);
  const cv::Mat image = cv::imread(png.string(), cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(image.empty());
  EXPECT_EQ(image.cols, 1100);
  const double ink = static_cast<double>(cv::countNonZero(image < 200)) / (image.rows * image.cols);
  EXPECT_GT(ink, 0.02);  // text, tables and plot lines: not a blank page
  EXPECT_LT(ink, 0.60);  // nor an error-coloured one
}

}  // namespace

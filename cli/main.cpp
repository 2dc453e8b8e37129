// dropfit: from a drop-test session folder to fitted, validated mat parameters.
// main only parses the command line; each subcommand is a cli/*_command.cpp.
#include <fmt/format.h>

#include <algorithm>
#include <exception>
#include <string>
#include <utility>
#include <vector>

#include "cli/command.h"

namespace dropfit::cli {
namespace {
std::vector<std::pair<int, CommandFactory>>& registry() {
  static std::vector<std::pair<int, CommandFactory>> commands;
  return commands;
}
}  // namespace

bool register_command(int order, CommandFactory factory) {
  registry().emplace_back(order, factory);
  return true;
}

void add_registered_commands(CLI::App& app, CommandContext& ctx) {
  auto commands = registry();
  std::stable_sort(commands.begin(), commands.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  for (const auto& [order, factory] : commands) factory(app, ctx);
}
}  // namespace dropfit::cli

int main(int argc, char** argv) {
  CLI::App app{"dropfit: drop-test sessions to fitted landing-mat models"};
  app.require_subcommand(1);
  dropfit::cli::CommandContext ctx;
  dropfit::cli::add_registered_commands(app, ctx);
  // Every error is one line on stderr, "dropfit: error: REASON".
  auto one_line = [](std::string text) {
    for (char& c : text)
      if (c == '\n' || c == '\r') c = ' ';
    return text;
  };
  // CLI11's range check prints the largest double as the upper bound of an
  // open range: "VALUE not in range 0.000000 to 1797...(309 digits).000000".
  // Said as "'VALUE' is not a number >= 0" instead (field and value named).
  auto readable_range = [](std::string text) {
    const std::string marker = "Value ", range = " not in range ", to = " to ";
    const auto r = text.find(range);
    const auto v = text.rfind(marker, r);
    const auto t = r == std::string::npos ? r : text.find(to, r + range.size());
    if (v == std::string::npos || t == std::string::npos) return text;
    const auto upper_end = text.find_first_not_of("0123456789.", t + to.size());
    const std::size_t upper_len = (upper_end == std::string::npos ? text.size() : upper_end) - (t + to.size());
    if (upper_len < 300) return text;  // a real upper bound: keep CLI11's wording
    std::string lower = text.substr(r + range.size(), t - r - range.size());
    if (const auto dot = lower.find('.'); dot != std::string::npos && lower.find_first_not_of('0', dot + 1) == std::string::npos) {
      lower.erase(dot);
    }
    const std::string value = text.substr(v + marker.size(), r - v - marker.size());
    return text.substr(0, v) + "'" + value + "' is not a number >= " + lower +
           (upper_end == std::string::npos ? std::string() : text.substr(upper_end));
  };
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help and --version print as CLI11 does; a usage error (a missing
    // session folder, a missing option) is one line like any other error.
    if (e.get_exit_code() == static_cast<int>(CLI::ExitCodes::Success)) return app.exit(e);
    fmt::print(stderr, "dropfit: error: {} (see dropfit --help)\n", one_line(readable_range(e.what())));
    return e.get_exit_code();
  } catch (const std::exception& e) {
    fmt::print(stderr, "dropfit: error: {}\n", one_line(e.what()));
    return 1;
  }
  return ctx.exit_code;
}

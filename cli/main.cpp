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
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help and --version print as CLI11 does; a usage error (a missing
    // session folder, a missing option) is one line like any other error.
    if (e.get_exit_code() == static_cast<int>(CLI::ExitCodes::Success)) return app.exit(e);
    fmt::print(stderr, "dropfit: error: {} (see dropfit --help)\n", one_line(e.what()));
    return e.get_exit_code();
  } catch (const std::exception& e) {
    fmt::print(stderr, "dropfit: error: {}\n", one_line(e.what()));
    return 1;
  }
  return ctx.exit_code;
}

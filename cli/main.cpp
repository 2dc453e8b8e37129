// dropfit: from a drop-test session folder to fitted, validated mat parameters.
#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include <exception>

#include "core/error.h"

int main(int argc, char** argv) {
  CLI::App app{"dropfit: drop-test sessions to fitted landing-mat models"};
  app.require_subcommand(1);
  int exit_code = 0;
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const std::exception& e) {
    fmt::print(stderr, "dropfit: error: {}\n", e.what());
    return 1;
  }
  return exit_code;
}

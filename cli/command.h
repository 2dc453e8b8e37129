#pragma once
// Each subcommand lives in its own cli/*_command.cpp and registers itself:
//
//   void add_calibrate(CLI::App& app, CommandContext& ctx) {
//     auto* sub = app.add_subcommand("calibrate", "...");
//     ... options ...
//     sub->callback([&ctx, ...] { ...; ctx.exit_code = 0; });
//   }
//   DROPFIT_COMMAND(10, add_calibrate);
//
// A callback reports user errors by throwing (dropfit::Error and friends);
// main prints the reason on one line and exits non-zero. A command that
// finishes with some failures (a rejected session in a batch) sets
// ctx.exit_code instead.
#include <CLI/CLI.hpp>

namespace dropfit::cli {

struct CommandContext {
  int exit_code = 0;
};

using CommandFactory = void (*)(CLI::App&, CommandContext&);

// Registers a subcommand; `order` sorts them in --help.
bool register_command(int order, CommandFactory factory);
void add_registered_commands(CLI::App& app, CommandContext& ctx);

}  // namespace dropfit::cli

#define DROPFIT_COMMAND(order, factory) \
  static const bool dropfit_registered_##factory = ::dropfit::cli::register_command(order, factory)

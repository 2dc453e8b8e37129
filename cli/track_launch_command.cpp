// dropfit track ...: runs dropfit-track, installed beside dropfit.
//
// Tracking reads footage through OpenCV's imgcodecs and videoio, whose
// shared libraries (and theirs: FFmpeg, GStreamer, codecs; about 230 in
// all) a process loads at start when it links them. So `track` is its own
// executable (cli/track_command.cpp with dropfit_video), and this command,
// which links none of it, replaces itself with it (execv: same arguments,
// same output streams, same exit code). Every other command starts without
// the video stack.
#include <fmt/format.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include "cli/command.h"
#include "core/error.h"

namespace dropfit::cli {
namespace {

void add_track_launcher(CLI::App& app, CommandContext& /*ctx*/) {
  auto* sub = app.add_subcommand("track", "find the markers in the video frames and write the trial's xypts.csv");
  sub->prefix_command();  // every argument after "track" goes to dropfit-track as it is
  sub->set_help_flag();   // so does --help
  sub->callback([sub] {
    namespace fs = std::filesystem;
    std::error_code ec;
    const fs::path self = fs::read_symlink("/proc/self/exe", ec);
    const fs::path exe = (ec ? fs::path(".") : self.parent_path()) / "dropfit-track";
    if (!fs::exists(exe, ec))
      throw Error(fmt::format("track: {} is missing (dropfit-track is installed beside dropfit)", exe.string()));
    // argv[0] stays dropfit's own, so usage lines read "dropfit track".
    std::vector<std::string> args{ec ? std::string("dropfit") : self.string(), "track"};
    for (const std::string& a : sub->remaining()) args.push_back(a);
    std::vector<char*> argv;
    for (std::string& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    ::execv(exe.c_str(), argv.data());
    throw Error(fmt::format("track: cannot run {}: {}", exe.string(), std::strerror(errno)));
  });
}

}  // namespace
DROPFIT_COMMAND(15, add_track_launcher);
}  // namespace dropfit::cli

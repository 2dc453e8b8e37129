#pragma once
// Shared by the fuzz targets: the readers take paths, so each input is
// written to a file in a per-process scratch folder first. The contract
// under test: any input either reads or throws dropfit::Error (a message
// for the user); any other exception, a crash, a sanitizer report, a hang
// or unbounded memory is a finding.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <string>

#include "core/session.h"
#include "core/error.h"

namespace dropfit::fuzz {

inline std::string scratch_file(const std::string& name, const uint8_t* data, size_t size) {
  static const std::filesystem::path dir = [] {
    auto d = std::filesystem::temp_directory_path() / ("dropfit-fuzz-" + std::to_string(::getpid()));
    std::filesystem::create_directories(d);
    return d;
  }();
  const auto path = dir / name;
  std::ofstream(path, std::ios::binary | std::ios::trunc).write(reinterpret_cast<const char*>(data),
                                                                static_cast<std::streamsize>(size));
  return path.string();
}

// Runs `read`; dropfit::Error is the expected refusal, anything else aborts.
template <typename F>
int expect_read_or_error(F&& read) {
  try {
    read();
  } catch (const Error&) {
  } catch (const std::exception& e) {
    std::fprintf(stderr, "not a dropfit::Error: %s\n", e.what());
    std::abort();
  }
  return 0;
}

// The demo session's video and plate (samples/demo-session/session.toml).
inline VideoSpec demo_video() {
  VideoSpec v;
  v.cameras = {"cam1", "cam2"};
  v.frame_rate_hz = 1000.0;
  v.points = {"imp_base_front", "imp_base_back", "mat_n", "mat_s", "mat_e", "mat_w"};
  v.trigger_frame = 200;
  return v;
}
inline ForcePlateSpec demo_plate() {
  ForcePlateSpec p;
  p.sample_rate_hz = 1000.0;
  p.trigger_threshold_n = 25.0;
  p.pretrigger_fraction = 0.1;
  return p;
}

}  // namespace dropfit::fuzz

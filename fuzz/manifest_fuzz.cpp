// session.toml (capture::read_manifest): toml++ plus the spec's checks.
#include "capture/io.h"
#include "fuzz/fuzz_common.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = dropfit::fuzz::scratch_file("session.toml", data, size);
  return dropfit::fuzz::expect_read_or_error([&] { dropfit::capture::read_manifest(path); });
}

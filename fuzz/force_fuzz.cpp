// force.txt in both layouts (capture::read_force): Kistler eight channels and
// BioWare resultants, at the demo plate's 1000 Hz.
#include "capture/io.h"
#include "fuzz/fuzz_common.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace dropfit;
  const std::string path = fuzz::scratch_file("force.txt", data, size);
  return fuzz::expect_read_or_error([&] { capture::read_force(path, fuzz::demo_plate()); });
}

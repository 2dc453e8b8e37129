// fit.json (report::parse_fit_json): what simulate and co-simulation load.
#include "fuzz/fuzz_common.h"
#include "report/export.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  return dropfit::fuzz::expect_read_or_error([&] { dropfit::report::parse_fit_json(text, "fit.json"); });
}

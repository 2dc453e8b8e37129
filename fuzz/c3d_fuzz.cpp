// C3D files (capture/c3d.h): parse_c3d from the bytes in memory, then what
// the pipeline builds from a file that parses: the scaled analog channels,
// the force record of plate 1 and 2 (capture::force_record_from_c3d, at the
// file's own analog rate so that the rate check does not stop every input
// there) and the marker trajectories of the first POINT:LABELS.
#include <string_view>

#include "capture/c3d.h"
#include "capture/force_io.h"
#include "fuzz/fuzz_common.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace dropfit;
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  capture::C3dFile file;
  bool parsed = false;
  fuzz::expect_read_or_error([&] {
    file = capture::parse_c3d(bytes, "fuzz.c3d");
    parsed = true;
  });
  if (!parsed) return 0;
  fuzz::expect_read_or_error([&] { capture::c3d_analog_scaled(file); });
  for (int plate = 1; plate <= 2; ++plate) {
    fuzz::expect_read_or_error([&] {
      ForcePlateSpec spec = fuzz::demo_plate();
      spec.sample_rate_hz = file.analog_rate_hz();
      spec.plate = plate;
      capture::force_record_from_c3d(file, spec);
    });
  }
  fuzz::expect_read_or_error([&] {
    std::vector<std::string> points;
    if (const capture::C3dParameter* labels = file.find("POINT", "LABELS"))
      for (std::size_t k = 0; k < labels->strings.size() && k < 4; ++k) points.push_back(labels->strings[k]);
    capture::markers_from_c3d(file, points);
  });
  return 0;
}

// calibration/frame.csv and calibration/<camera>.csv (capture::read_frame_csv,
// read_camera_csv). The first byte picks the reader; the camera file is read
// against the demo session's frame (samples/demo-session).
#include "capture/io.h"
#include "fuzz/fuzz_common.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace dropfit;
  if (size == 0) return 0;
  const bool camera = data[0] & 1;
  const std::string path = fuzz::scratch_file(camera ? "cam1.csv" : "frame.csv", data + 1, size - 1);
  return fuzz::expect_read_or_error([&] {
    if (!camera) {
      capture::read_frame_csv(path);
      return;
    }
    static const std::vector<CalibrationMarker> frame = [] {
      std::vector<CalibrationMarker> f;
      for (int i = 1; i <= 20; ++i) {
        CalibrationMarker m;
        m.id = (i < 10 ? "c0" : "c") + std::to_string(i);
        m.lab_m = Eigen::Vector3d(0.1 * i, -0.05 * i, 0.03 * (i % 5));
        m.role = i % 2 ? MarkerRole::Fit : MarkerRole::Check;
        f.push_back(m);
      }
      return f;
    }();
    capture::read_camera_csv(path, "cam1", frame);
  });
}

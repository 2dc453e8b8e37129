// xypts.csv in its three layouts (capture::read_xypts) with the demo
// session's cameras and points; the first byte picks the image origin
// (bottom-left needs the image height, Argus files use it).
#include "capture/io.h"
#include "fuzz/fuzz_common.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace dropfit;
  if (size == 0) return 0;
  VideoSpec video = fuzz::demo_video();
  video.trigger_frame = data[0] >> 1;  // 0-127: small files can reach it
  if (data[0] & 1) {
    video.image_origin = ImageOrigin::BottomLeft;
    video.image_height_px = 1024.0;
  }
  const std::string path = fuzz::scratch_file("xypts.csv", data + 1, size - 1);
  return fuzz::expect_read_or_error([&] { capture::read_xypts(path, video); });
}

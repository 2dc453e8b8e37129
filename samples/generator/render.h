#pragma once
// Synthetic footage of bright round markers with known centres, to test the
// marker tracker (capture/tracking.h) against truth. Small enough to make at
// test time; never committed.
//
// Image formation, per pixel (pixel (i, j) covers [i, i+1) x [j, j+1), top-
// left origin, v down, as in capture/tracking.h):
//   - the background: a static low-contrast pattern (value noise at three
//     scales, smooth-step interpolated) of mean background_grey and standard
//     deviation about texture_grey;
//   - each marker an opaque disc of radius r at a sub-pixel centre c, its edge
//     blurred by the optics' Gaussian (sigma blur_px): coverage at distance d
//     from the centre 0.5 erfc((d - r) / (sqrt(2) sigma)) (the straight-edge
//     approximation, good for r >> sigma); the pixel is
//     background (1 - coverage) + marker_grey coverage;
//   - motion blur: coverage averaged over the exposure, the centre moving
//     along the frame's velocity ((c[f+1] - c[f-1]) / 2); c[f] is the centre
//     at mid-exposure;
//   - all of it averaged over supersample x supersample points in the pixel;
//   - occluders (rectangles in front of the markers), anti-aliased by their
//     pixel coverage;
//   - sensor noise: zero-mean, about Gaussian (sum of four uniforms), sigma
//     noise_grey, independent per pixel and frame; rounded and clipped to 8 bits.
#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "capture/tracking.h"

namespace dropfit::synth {

struct FootageOptions {
  int width_px = 1024;
  int height_px = 1024;
  double background_grey = 60.0;
  double texture_grey = 8.0;        // standard deviation of the background pattern
  double texture_scale_px = 24.0;   // size of its coarsest features (finer octaves at 1/3 and 1/9)
  double marker_grey = 230.0;
  double blur_px = 0.8;             // Gaussian sigma of the optics
  double noise_grey = 2.0;          // sensor noise sigma
  int supersample = 4;              // sub-samples per pixel side
  double exposure_frames = 0.0;     // shutter open time as a share of the frame interval; 0: no motion blur
  std::uint64_t seed = 1;
};

// A rectangle in front of the markers, [u0, u1) x [v0, v1) in pixels.
struct Occluder {
  double u0_px = 0, v0_px = 0, u1_px = 0, v1_px = 0;
  double grey = 30.0;
};

struct MarkerFootage {
  // n_frames x (2 n_markers): marker k's true centre (u, v) in columns 2k,
  // 2k+1. NaN: the marker is not in view in that frame (not drawn).
  Eigen::MatrixXd centres_px;
  std::vector<double> radius_px;  // per marker
  std::vector<Occluder> occluders;

  int n_frames() const { return static_cast<int>(centres_px.rows()); }
  int n_markers() const { return static_cast<int>(centres_px.cols() / 2); }
};

class FootageRenderer {
 public:
  // Makes the background pattern once (deterministic from options.seed).
  explicit FootageRenderer(FootageOptions options = {});

  // Frame `frame` of the footage; deterministic for (options.seed, frame).
  capture::Image8 render(const MarkerFootage& footage, int frame) const;
  void render(const MarkerFootage& footage, int frame, capture::Image8& out) const;

  const FootageOptions& options() const { return opt_; }

 private:
  FootageOptions opt_;
  std::vector<float> background_;
};

// Renders every frame into `folder` (created if needed) as
// PREFIX000000.png, PREFIX000001.png, ...; returns the file paths.
std::vector<std::string> write_footage_png(const std::string& folder, const MarkerFootage& footage,
                                           const FootageOptions& options, const std::string& prefix = "frame_");

// The same as 16-bit TIFF files holding 12-bit data (grey g written as
// round(g * 4095 / 255)), as high-speed cameras export them:
// PREFIX000000.tif, ...
std::vector<std::string> write_footage_tiff12(const std::string& folder, const MarkerFootage& footage,
                                              const FootageOptions& options, const std::string& prefix = "frame_");

// Renders every frame into one video file through OpenCV (`fourcc` e.g.
// "FFV1", lossless, in .avi or .mkv). Throws dropfit::Error when no
// installed backend can write it.
void write_footage_video(const std::string& path, const MarkerFootage& footage, const FootageOptions& options,
                         const std::string& fourcc = "FFV1", double frame_rate_hz = 1000.0);

}  // namespace dropfit::synth

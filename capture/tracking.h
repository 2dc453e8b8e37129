#pragma once
// Markers found in the video itself: bright round markers detected with
// sub-pixel centres, followed frame to frame in one camera's footage, and
// labelled with the manifest's point names from a seed.
//
// Detection (in a window of the image): the local background is the median
// of the window's border pixels; pixels brighter than background + a
// fraction of the marker's contrast form 4-connected blobs; a blob is kept
// when its area, its roundness (minor / major axis of its second moments)
// and its contrast are plausible for a marker. Its centre is the
// thresholded intensity-weighted centroid ("centre of gravity" with the
// weight I - threshold, which falls to zero at the blob's edge, so the
// pixelated edge does not bias it; e.g. Shortis, Clarke & Short 1994,
// "A comparison of some techniques for the subpixel location of discrete
// target images", Proc. SPIE 2350).
//
// Tracking: after the seed frame each marker is searched for only in a
// window around its predicted position (constant velocity from the last two
// detections, or a constant-acceleration least-squares fit of the last six),
// gated by distance: the usual prediction-and-gating of point tracking
// (e.g. Bar-Shalom & Fortmann 1988, "Tracking and data association"). A
// marker with no acceptable blob in its gate is a gap (NaN), flagged, never
// invented; it is searched for again around its coasting (constant velocity)
// prediction with a gate that widens with the time since it was lost, and
// re-acquired only when one candidate is clearly nearer than any other and
// no marker still being tracked claims it. Two candidates at similar
// distance, or two tracked markers claiming one blob (markers overlapping in
// the image), make gaps with a warning rather than a guess.
//
// Image coordinates: pixels, origin at the top-left pixel corner, u to the
// right, v downwards; pixel (i, j) (column i, row j) covers [i, i+1) x
// [j, j+1), so its centre is (i + 0.5, j + 0.5). MarkerTracker numbers
// frames from 0 in the order given; footage whose file names number its
// frames from N (frame_00399.png) is tracked by track_footage
// (capture/footage.h), whose rows and seed frames are the file names'
// numbers: frame k is row k of xypts.csv.
//
// Seed file (CSV, one row per point, header required):
//
//   point,frame,u_px,v_px
//   imp_base_front,0,512.3,101.8
//   mat_n,0,300.0,840.5
//
// `point` is a name from [video].points, `frame` the 0-based frame where the
// point is first visible in this camera (tracking starts there; earlier
// frames are gaps), u_px and v_px its approximate centre in that frame
// (within TrackingOptions::seed_radius_px of the true centre: the seed snaps
// to the one marker there). Blank lines and lines starting with '#' are
// ignored. A point of the manifest without a seed row is left NaN (e.g. not
// visible to this camera).
#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "core/session.h"

namespace dropfit {
class Progress;
}

namespace dropfit::capture {

// ---- Images ----------------------------------------------------------------

// A read-only view of an 8-bit grey image; row y starts at data + y * stride.
struct ImageView8 {
  const std::uint8_t* data = nullptr;
  int width = 0;
  int height = 0;
  std::ptrdiff_t stride = 0;  // bytes between the starts of two rows

  const std::uint8_t* row(int y) const { return data + y * stride; }
  std::uint8_t at(int x, int y) const { return row(y)[x]; }
};

// An owned 8-bit grey image, rows packed.
struct Image8 {
  int width = 0;
  int height = 0;
  std::vector<std::uint8_t> pixels;  // width * height, row-major

  ImageView8 view() const { return {pixels.data(), width, height, width}; }
};

// A rectangle of pixels [x0, x1) x [y0, y1).
struct PixelWindow {
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;
};

// ---- Detection -------------------------------------------------------------

struct Blob {
  Eigen::Vector2d centre_px = Eigen::Vector2d::Zero();  // thresholded weighted centroid
  double area_px2 = 0.0;      // pixels above the threshold
  double axis_ratio = 1.0;    // minor / major axis of the second moments; 1 for a disc
  double contrast = 0.0;      // brightest pixel minus the local background (grey levels)
  bool touches_image_edge = false;  // its centre is then unreliable
};

struct DetectionOptions {
  // threshold = background + threshold_fraction * contrast, where contrast
  // is the brightest pixel of the window above its background (detect_blobs)
  // or the marker's own contrast learnt from the seed (tracking).
  double threshold_fraction = 0.5;
  double min_contrast = 20.0;      // grey levels; fainter blobs are not markers
  double min_area_px2 = 3.0;
  double max_area_px2 = 5000.0;
  double min_axis_ratio = 0.5;     // motion blur elongates; a half-hidden disc is about 0.5

  // Throws dropfit::Error naming the field and value when one is out of
  // range (NaN, a fraction outside 0-1, a negative contrast or area, a
  // largest area below the smallest); detect_blobs and the tracker call it.
  void validate() const;
};

// All plausible marker blobs in `window` of the image (the whole image when
// the window is empty), brightest first. Blobs cut by the window's border
// are dropped. For seeding and inspection; the tracker searches windows.
std::vector<Blob> detect_blobs(const ImageView8& image, const DetectionOptions& options = {},
                               PixelWindow window = {});

// ---- Tracking --------------------------------------------------------------

struct Seed {
  std::string point;
  int frame = 0;
  Eigen::Vector2d uv_px = Eigen::Vector2d::Zero();
  // Where the seed came from, for error messages (empty and 0 when made in code).
  std::string source;
  int line = 0;
};

enum class MotionModel { ConstantVelocity, ConstantAcceleration };

struct TrackingOptions {
  DetectionOptions detection;
  MotionModel motion = MotionModel::ConstantVelocity;
  double gate_px = 6.0;             // largest prediction-to-centre distance while tracked
  double widen_px_per_frame = 1.0;  // gate growth per frame since the marker was lost
  double max_gate_px = 40.0;
  int max_lost_frames = 250;        // stop searching for a marker lost longer than this
  double seed_radius_px = 12.0;     // a seed snaps to the one marker within this distance
  // The nearest candidate wins only when every other is at least this many
  // times as far from the prediction (distances below 0.5 px count as 0.5).
  double ambiguity_ratio = 2.0;
  // Plausible blobs relative to the marker's own size and contrast (learnt
  // at the seed, then followed slowly).
  // A partly hidden marker's centroid is pulled towards its visible part
  // (by 0.25 px when 6 % of a disc is covered, 0.9 px at 23 %), so a blob
  // that shrinks or loses its roundness suddenly is a gap, not a centre.
  double min_area_ratio = 0.8;
  double max_area_ratio = 1.5;      // two markers merging in the image
  double max_axis_ratio_drop = 0.15;
  double min_contrast_ratio = 0.4;

  // Throws dropfit::Error naming the field and value when one is out of
  // range (detection.validate(), a non-positive gate or seed radius, a
  // largest gate below the gate, an ambiguity ratio below 1, ratios outside
  // their side of 1); the MarkerTracker constructor calls it.
  void validate() const;
};

// What happened to a point in a frame.
enum class TrackFlag : std::uint8_t {
  BeforeSeed,  // before the point's seed frame (or no seed): NaN
  Tracked,     // found near its prediction
  Reacquired,  // found again after a gap
  Missing,     // gap: no marker near the prediction
  Rejected,    // gap: a blob there, but of the wrong size, shape or contrast, or at the image edge
  Ambiguous,   // gap: two candidates at similar distance, or the only one belongs to another marker
  Shared,      // gap: two tracked markers claim one blob (overlapping in the image)
  GivenUp,     // gap: lost for longer than max_lost_frames; no longer searched for
};
const char* to_string(TrackFlag flag);
inline bool is_gap(TrackFlag flag) {
  return flag != TrackFlag::Tracked && flag != TrackFlag::Reacquired && flag != TrackFlag::BeforeSeed;
}

// Something a user should look at: a point, frames first..last, and why.
struct TrackWarning {
  std::string point;
  int frame = 0;
  int last_frame = 0;
  std::string reason;
};

struct TrackGap {
  std::string point;
  int first_frame = 0;
  int last_frame = 0;
  bool reacquired = false;  // found again after last_frame
};

struct TrackingResult {
  // One camera's tracks: `points` as given, `cameras` = {camera}; NaN in gaps.
  MarkerTracks2D tracks;
  // n_frames x n_points, row-major: flags[frame * n_points + point].
  std::vector<TrackFlag> flags;
  // Consecutive frames with the same point and reason are one warning.
  std::vector<TrackWarning> warnings;
  int image_width_px = 0, image_height_px = 0;  // the frames' size

  TrackFlag flag(int frame, int point) const { return flags[frame * tracks.n_points() + point]; }
  std::vector<TrackGap> gaps() const;
  std::string report() const;  // a few human lines
};

// Follows the seeded markers of one camera through frames given in order.
// Numeric core: takes image views, does no file I/O.
class MarkerTracker {
 public:
  // Throws dropfit::InputError (naming the seed's source) for a seed that
  // names a point not in `points`, a point seeded twice, or a negative frame;
  // dropfit::Error for options out of range (TrackingOptions::validate).
  MarkerTracker(std::string camera, std::vector<std::string> points, std::vector<Seed> seeds,
                TrackingOptions options = {});
  ~MarkerTracker();
  MarkerTracker(MarkerTracker&&) noexcept;
  MarkerTracker& operator=(MarkerTracker&&) noexcept;

  // The next frame (0, 1, 2, ...). Throws dropfit::InputError for a seed
  // outside the image or with no (or no single) marker near it, and
  // dropfit::Error when the frame size changes.
  void add_frame(const ImageView8& frame);
  int n_frames() const;

  // Throws dropfit::InputError for a seed whose frame was never reached.
  TrackingResult result() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Copies one camera's tracks into `all` (matched by point and camera names;
// rows added as NaN when `camera_tracks` is longer). Points of
// `camera_tracks` absent from `all` are an error; columns of other cameras
// are left untouched. This is how per-camera runs merge into one xypts.csv.
void merge_camera_tracks(MarkerTracks2D& all, const MarkerTracks2D& camera_tracks);

// ---- Seeds (the I/O edge; footage is read by capture/footage.h) -------------

// The seed file (format at the top). Throws dropfit::InputError naming the
// file, line and field on a malformed row, an unknown point or a repeated one.
std::vector<Seed> read_seed_csv(const std::string& path, const std::vector<std::string>& points);
void write_seed_csv(const std::string& path, const std::vector<Seed>& seeds);

// A seed for every camera at once: the point's approximate lab position in
// its first frame (`point,frame,x_m,y_m,z_m`, header required, blank and '#'
// lines skipped), projected into each camera through the session's
// calibration (pipeline/track.h) and snapped to the marker near there.
struct LabSeed {
  std::string point;
  int frame = 0;
  Eigen::Vector3d lab_m = Eigen::Vector3d::Zero();
  int line = 0;
};
std::vector<LabSeed> read_lab_seed_csv(const std::string& path, const std::vector<std::string>& points);

// A camera's result with its rows renumbered from `first_frame`: rows
// 0..first_frame-1 are prepended as NaN (flag BeforeSeed) and the warnings'
// frames shifted, so that row k is the footage's frame k.
TrackingResult shift_frames(TrackingResult result, int first_frame);

}  // namespace dropfit::capture

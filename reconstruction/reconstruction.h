#pragma once
// 3-D reconstruction of points seen by two or more calibrated cameras:
// the linear DLT triangulation (Hartley & Zisserman 2003, sec. 12.2) in
// least squares over all cameras that see the point, undistorting first when
// a camera has lens distortion, optionally refined by minimising the
// reprojection error (Gauss-Newton). A point seen by fewer than two cameras
// in a frame is a gap (NaN), never interpolated. The per-point method lives
// in calibration/triangulation.h (calibrate() needs it for its check
// markers, and this library depends on calibration); this stage applies it
// to whole trials.
#include <Eigen/Core>
#include <limits>
#include <string>
#include <vector>

#include "calibration/calibration.h"
#include "calibration/triangulation.h"

namespace dropfit::reconstruction {

using calibration::Triangulation;  // lab_m, residual_px (RMS reprojection error), n_cameras

// image_px[i] is the pixel in cameras[i], NaN when not seen. Throws
// dropfit::Error when the two lengths differ. Same as calibration::triangulate.
Triangulation triangulate(const std::vector<calibration::Camera>& cameras,
                          const std::vector<Eigen::Vector2d>& image_px, bool refine = true);

// Whether the cameras' rows are the same instants. Two cameras that are not
// synchronised (one started a few frames late, or lost a frame) see a moving
// marker at different instants: the rays no longer meet, and the
// reprojection residual grows with the marker's image speed (at 5 m/s and
// 1 kHz a frame is 5 mm of travel, several pixels, against the 0.2-0.5 px a
// digitised track reprojects to). For each camera c >= 1 paired with camera
// 0, the given points are triangulated from those two cameras with camera
// c's row k + lag read beside camera 0's row k, for every lag in
// [-max_lag, max_lag]; mean_sq_px[lag + max_lag] is the mean squared
// reprojection residual over the frames both cameras see (NaN with fewer
// than kMinLagFrames of them). best_lag minimises it.
struct CameraLag {
  int camera = 0;  // index into the cameras (>= 1; paired with camera 0)
  std::string name, reference;  // the two cameras' names
  int max_lag = 0;
  int best_lag = 0;
  std::vector<double> mean_sq_px;
  double rms_px(int lag) const;  // sqrt of mean_sq_px at that lag (NaN outside the range)
  // The rows are not the same instants: the best lag is not 0 and the
  // residual at lag 0 is more than kLagResidualFactor times the residual at
  // the best lag (RMS). A sub-frame offset (cameras not genlocked) leaves
  // lags 0 and +-1 within that factor of each other; a whole frame of a
  // moving marker is several times the digitising noise.
  bool desynchronised() const;
  // One camera losing or repeating a frame part-way through the trial
  // changes the lag at that row: the rows before keep one lag, the rows
  // from change_row on another. The split (every row tried) that leaves the
  // smallest mean squared residual with each part at its own best lag;
  // split_rms_px its RMS. -1 when no split leaves kMinLagFrames frames on
  // each side.
  int change_row = -1;
  int lag_before = 0, lag_after = 0;
  double split_rms_px = std::numeric_limits<double>::quiet_NaN();
  // The lag changes part-way: the two parts' best lags differ and the one
  // lag of the whole trial leaves more than kLagResidualFactor times the
  // split's RMS.
  bool changes_part_way() const;
};
constexpr int kMinLagFrames = 20;
constexpr double kLagResidualFactor = 2.0;

// A marker digitised on the wrong point in one camera for a stretch of rows
// (a slip of the digitiser's click, an auto-tracker locked on a nearby
// feature). Two cameras' rays through one point meet; a pixel moved off it
// in one camera moves its ray off the other's, by the move's component
// across the epipolar line (the component along the line only moves the
// triangulated point). So the signed distance of camera 1's pixel from the
// epipolar line of camera 0's (camera 1's pixels, lens distortion removed)
// steps at the stretch's first row and back at its end. What else moves that
// distance moves it without a jump: a lens term the calibration lacks (the
// marker sweeping across the image), and cameras a fraction of a frame apart
// (the offset times the marker's image velocity across the line: a hump
// through the contact, which the test below would read as a shift; that
// part, one offset for every point, is fitted and taken out first,
// subframe_offset). At every row the two straight lines through the
// kSlipEdgeRows rows before and after it are compared at the boundary; a
// step beyond kSlipEdgeZ SEs there (noise from the second differences,
// robust to the steps) starts a stretch, one of the other sign within
// kMaxSlipRows rows ends it. The stretch is a slip when it is at least
// kMinSlipRows long and its mean departs from the line through the rows
// before it and from the one through those after it (as many rows as the
// stretch, from kSlipSideRows to kMaxSlipSideRows), each by more than
// kSlipMeanZ SEs and the same way. Which of the two cameras slipped the distance
// does not tell: the point's positions over the stretch are untrustworthy in
// 3-D either way.
struct MarkerSlip {
  int point = 0;
  int first_row = 0, last_row = 0;  // the stretch, inclusive
  double step_px = 0.0;             // its mean epipolar distance from the lines beside it
  double noise_px = 0.0;            // the distance's frame-to-frame noise (SD)
  double z = 0.0;                   // the smaller departure, in SEs
};
constexpr int kSlipEdgeRows = 12;
constexpr int kSlipSideRows = 24;
constexpr int kMaxSlipSideRows = 60;
constexpr int kMinSlipRows = 8;
constexpr int kMaxSlipRows = 400;
constexpr double kSlipEdgeZ = 3.0;
constexpr double kSlipMeanZ = 6.0;

struct Trajectories {
  // n_frames x (3 * n_points): x, y, z of point p in columns 3p..3p+2; NaN in gaps.
  Eigen::MatrixXd lab_m;
  // n_frames x n_points RMS reprojection residual; NaN in gaps.
  Eigen::MatrixXd residual_px;
  // camera_lags() of the impactor's markers, set by the pipeline (empty for
  // markers that did not come through these cameras).
  std::vector<CameraLag> camera_lags;
  // marker_slips() of the trial, set by the pipeline, which leaves their
  // rows as gaps in lab_m and residual_px.
  std::vector<MarkerSlip> slips;
  int n_frames() const { return static_cast<int>(residual_px.rows()); }
  int n_points() const { return static_cast<int>(residual_px.cols()); }
  Eigen::Vector3d point(int frame, int p) const { return lab_m.row(frame).segment<3>(3 * p).transpose(); }
};

// Camera 1's signed distance from camera 0's epipolar line, per row (NaN
// where either camera does not see point p), in camera 1's pixels; and
// camera 1's pixel velocity across that line (pixels per row, central
// differences; NaN at the ends and beside a gap). Camera 1 seeing the
// instants a fraction s of a row later than camera 0 adds s times that
// velocity to the distance.
struct EpipolarSeries {
  std::vector<double> distance_px;
  std::vector<double> normal_velocity_px;
};
EpipolarSeries epipolar_distance(const calibration::Camera& cam0, const calibration::Camera& cam1,
                                 const Eigen::MatrixXd& uv_px, int n_points, int n_cameras, int p);

// Cameras that are not genlocked expose a fraction of a frame apart: camera
// 1's row k shows the instant of camera 0's row k + s. The offset s common
// to the points is the least squares of distance = a_p + s velocity over
// every point's rows (a_p each point's own mean); its SE from the scatter
// about that fit (which a lens term the calibration lacks inflates, never
// shrinks). It matters where the markers move: at 5 m/s and 1 kHz half a
// frame is 2.5 mm between the instants the two rays are drawn at, and the
// rays miss by pixels in the fall and meet at the bottom. It is taken out
// (resample_camera) when significant(): at least kMinSubframeRows and
// kSubframeZ SEs, and under one row (a whole row and more is a lag between
// the cameras' rows, camera_lags, or rays that do not meet at all).
struct SubframeOffset {
  double rows = 0.0;
  double se_rows = std::numeric_limits<double>::quiet_NaN();
  double rms_before_px = std::numeric_limits<double>::quiet_NaN();  // distance RMS, each point's mean removed
  double rms_after_px = std::numeric_limits<double>::quiet_NaN();   // ... and s times the velocity
  bool significant() const;
};
constexpr double kMinSubframeRows = 0.1;
constexpr double kSubframeZ = 5.0;
SubframeOffset subframe_offset(const std::vector<EpipolarSeries>& series);

// epipolar_distance() of every point, cameras 0 and 1; empty with fewer
// than two cameras. Throws dropfit::Error when the column count does not
// match.
std::vector<EpipolarSeries> epipolar_series(const std::vector<calibration::Camera>& cameras,
                                            const Eigen::MatrixXd& uv_px, int n_points);
// subframe_offset() of epipolar_series(): rows 0 with fewer than two cameras.
SubframeOffset subframe_offset(const std::vector<calibration::Camera>& cameras, const Eigen::MatrixXd& uv_px,
                               int n_points);

// The tracks with `camera`'s pixels moved to the instants of camera 0's
// rows, it being `late_rows` late: its row k becomes its track at
// fractional row k - late_rows, interpolated linearly between the two rows
// about it (a gap where either is missing or outside the record). Over one
// frame the marker's path is a straight line to within a fraction of a
// micrometre in free fall and about 20 um at 15 g.
Eigen::MatrixXd resample_camera(const Eigen::MatrixXd& uv_px, int n_points, int n_cameras, int camera,
                                double late_rows);

// Whether the two cameras' rays meet as a calibration's rays do, up to the
// small departures the checks above read: the median |distance| over every
// point and row within kRaysMeetPx. Rays that miss by more are a camera
// whose pixels do not match its calibration as a whole (the cameras' order,
// a pixel axis that runs the other way, another session's calibration): the
// sub-frame offset and the slips have nothing to read there and are not
// looked for, and the reprojection gate names the trial's fault
// (trial::apply_calibration_gates). False when no distance is known.
constexpr double kRaysMeetPx = 5.0;
bool rays_meet(const std::vector<EpipolarSeries>& series);

// The slips (above) of every point of the series (point p = series[p]), in
// point then row order; none where the rays do not meet (rays_meet).
std::vector<MarkerSlip> marker_slips(const std::vector<EpipolarSeries>& series);
// marker_slips() of epipolar_series(): none with fewer than two cameras.
std::vector<MarkerSlip> marker_slips(const std::vector<calibration::Camera>& cameras, const Eigen::MatrixXd& uv_px,
                                     int n_points);

// uv_px in the DLTdv layout of core/session.h (MarkerTracks2D::uv_px):
// n_frames x (2 * n_points * cameras.size()), u of point p in camera c in
// column 2 (p n_cameras + c), v in the next. Throws dropfit::Error when the
// column count does not match or there are no cameras.
Trajectories reconstruct(const std::vector<calibration::Camera>& cameras, const Eigen::MatrixXd& uv_px,
                         int n_points, bool refine = true);

// CameraLag (above) of every camera against camera 0, over `points`. Throws
// dropfit::Error when the column count does not match.
std::vector<CameraLag> camera_lags(const std::vector<calibration::Camera>& cameras, const Eigen::MatrixXd& uv_px,
                                   int n_points, const std::vector<int>& points, int max_lag = 8);

}  // namespace dropfit::reconstruction

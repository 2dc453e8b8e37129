#pragma once
// Camera calibration by the 11-parameter direct linear transformation (DLT)
// (Abdel-Aziz & Karara 1971), solved linearly with Hartley's coordinate
// normalisation (Hartley 1997, "In defense of the eight-point algorithm";
// Hartley & Zisserman 2003, sec. 7.1, algorithm 7.1) and refined by
// minimising the reprojection error with Ceres (Levenberg-Marquardt).
//
//   u = (L1 X + L2 Y + L3 Z + L4) / (L9 X + L10 Y + L11 Z + 1)
//   v = (L5 X + L6 Y + L7 Z + L8) / (L9 X + L10 Y + L11 Z + 1)
//
// so image_from_lab = [L1..L4; L5..L8; L9 L10 L11 1] (3 x 4, homogeneous),
// the layout of DLTdv, easyWand and Argus coefficient files. Pixels have the
// origin at the top-left pixel corner, v down; the lab frame is in metres.
//
// Optional lens distortion (the "dlt16" model): Bouguet's k1, k2, p1, p2, k3
// (Bouguet's Camera Calibration Toolbox; OpenCV's order and signs) applied to
// the DLT-projected point (u, v), about the centre c = principal_point_px
// and with the radius normalised by focal_px:
//
//   x = (u - cu) / f,  y = (v - cv) / f,  r2 = x^2 + y^2
//   xd = x (1 + k1 r2 + k2 r2^2 + k3 r2^3) + 2 p1 x y + p2 (r2 + 2 x^2)
//   yd = y (1 + k1 r2 + k2 r2^2 + k3 r2^3) + p1 (r2 + 2 y^2) + 2 p2 x y
//   measured pixel = c + f (xd, yd)
//
// c and f are the DLT's own principal point and mean focal length (u0 =
// (L1 L9 + L2 L10 + L3 L11) / (L9^2 + L10^2 + L11^2), likewise v0; f the mean
// of the two focal lengths), moving with the DLT while it is fitted: the
// lens distorts about its optical axis. They are not extra parameters, and
// a single f ignores the small aspect ratio and skew a DLT may carry. The
// fit starts from the distortion about the linear DLT's principal point
// held fixed and from several k1 (the linear DLT's centre, bent by a
// strong lens, can lie 150 px from the axis; from there alone the fit
// stayed in a poor optimum). Stored with the camera, c and f are constants
// for projecting and undistorting; a camera read from a file keeps its own.
//
// With the usual 10 fit markers the full 16-parameter fit has only 20
// equations for 16 unknowns, and k2 and k3 do not identify: on the test
// scene (tests/support/cameras.h, k1 = -0.2, 0.25 px noise, 20 seeds) the
// per-axis check RMS was 0.5-0.6 mm fitting k1 p1 p2, 1.1-1.7 mm fitting
// k1 k2 p1 p2, and about 100 mm with k3 as well (dlt11: 4-7 mm). So by
// default only k1, p1 and p2 are fitted (DltOptions::radial_terms); fit k2
// and k3 only with a few dozen markers or more.
#include <Eigen/Core>
#include <limits>
#include <string>
#include <utility>
#include <vector>

namespace dropfit::calibration {

using Dlt11 = Eigen::Matrix<double, 11, 1>;
using Matrix34d = Eigen::Matrix<double, 3, 4>;

struct Camera {
  std::string name;
  Dlt11 dlt = Dlt11::Zero();
  // Empty, or k1 k2 p1 p2 k3 (see above).
  std::vector<double> distortion;
  Eigen::Vector2d principal_point_px = Eigen::Vector2d::Zero();  // distortion centre
  double focal_px = 1.0;                                          // distortion radius scale

  // [L1..L4; L5..L8; L9 L10 L11 1].
  Matrix34d image_from_lab() const;
  // Projects a lab point to pixels (with distortion when present).
  Eigen::Vector2d project(const Eigen::Vector3d& lab_m) const;
  // Removes the lens distortion from a measured pixel (identity without it),
  // by Newton iteration on the model above. NaN when the iteration does not
  // converge (a pixel beyond the fold of a strong barrel distortion).
  Eigen::Vector2d undistort(const Eigen::Vector2d& image_px) const;
  bool has_distortion() const { return !distortion.empty(); }

  // A distortion-free camera from a 3 x 4 projection matrix, scaled so that
  // its last element is 1. Throws dropfit::Error when that element is
  // (nearly) zero: the lab origin then lies in the camera's principal plane
  // and the 11-coefficient form cannot express the camera.
  static Camera from_image_from_lab(std::string name, const Matrix34d& image_from_lab);
};

// The principal point and mean focal length (pixels) of a DLT, the
// decomposition above: the lens distortion's centre and radius scale. False
// when the DLT has none (L9..L11 zero, or a negative squared focal length).
bool principal_point_and_focal(const Dlt11& dlt, Eigen::Vector2d* principal_px, double* focal_px);

// One correspondence of a calibration marker in one camera.
struct Correspondence {
  std::string id;
  Eigen::Vector3d lab_m;
  Eigen::Vector2d image_px;
};

struct DltOptions {
  bool refine = true;           // Ceres refinement of the reprojection error
  bool fit_distortion = false;  // add Bouguet lens distortion (dlt16; implies refine)
  // With fit_distortion: the radial terms fitted, 1 (k1), 2 (k1 k2) or 3
  // (k1 k2 k3), and whether p1 p2 are; the others are held at zero.
  int radial_terms = 1;
  bool tangential = true;
  // With fit_distortion: a camera fitted to nearly the same points (the
  // leave-one-out folds start from the fit on all of them). The fit then
  // runs once, from it, instead of from the several starts above; the
  // starts are the fallback when that fails. Not owned.
  const Camera* start = nullptr;

  // Throws dropfit::Error naming the field and value when radial_terms is
  // outside 0-3, or distortion is asked for with no term to fit.
  void validate() const;
};

struct DltFit {
  Camera camera;
  double fit_rms_px = 0.0;  // RMS reprojection distance over the fit points
  int n_fit_points = 0;
  std::vector<Eigen::Vector2d> residuals_px;  // per fit correspondence, measured minus projected
};

// Fits one camera. Throws dropfit::Error, naming the camera, when fewer
// points are given than the model needs (more equations than unknowns: 6
// for dlt11, 8 with the default distortion terms), when a coordinate is not
// finite, or when the lab points are (nearly) coplanar or collinear.
DltFit fit_dlt(const std::string& camera_name, const std::vector<Correspondence>& points,
               const DltOptions& options = {});

// ---- The whole calibration with its accuracy report ----------------------

struct Marker {
  std::string id;
  Eigen::Vector3d lab_m;
  bool is_check = false;  // held out from the fit
};

struct CameraView {
  std::string name;
  // Observed markers: id -> pixel. Markers a camera cannot see are absent
  // (or NaN).
  std::vector<std::pair<std::string, Eigen::Vector2d>> observations;
};

struct CheckPoint {
  std::string id;
  Eigen::Vector3d error_m;  // reconstructed minus known, lab frame
  int n_cameras = 0;        // cameras it was reconstructed from
};

struct LeaveOneOut {
  std::string id;
  // 3-D error of this fit marker, triangulated with every camera that sees
  // it refitted without it; NaN when fewer than two cameras see it or a
  // camera would be left with too few points.
  double residual_m = 0.0;
};

// Outliers (mislabelled or misdigitised fit markers). With 10 fit markers
// and 11 parameters one gross error bends every fit it is in, so it inflates
// the other markers' leave-one-out residuals too and the plain test (its own
// residual against the median of the others) misses it. So calibrate()
// first sets aside, one at a time and up to max_outliers, the fit marker
// whose removal leaves the best-fitting DLTs (the lowest reprojection RMS of
// all cameras' fits without it), keeping at least 2 more markers than the
// model needs; then, with every set-aside marker out of every fit, a
// set-aside marker is an outlier when its 3-D error exceeds outlier_ratio
// times the median leave-one-out residual of the markers kept, and
// min_outlier_m. Clean markers set aside this way fail that test and are
// not reported. When the distortion model leaves too few spare markers (10
// fit markers, 15 parameters), the search uses the DLT without distortion,
// which finds gross errors only; with too few markers even for that, no
// outlier is named.
//
// Measured on the test scene (tests/support/cameras.h, 10 fit markers,
// 0.25 px noise, dlt11): outlier_ratio 8 named a clean marker in 2 of 200
// calibrations (ratio 5: in 6), and found one marker misdigitised by 5 px
// (8 px) in 90 % (100 %) of 50. A mislabelled marker (100 px and more) or
// a swapped pair stands out by a factor of 20 and more. With dlt16 (the
// search then without distortion) a 30 px error was found in 47 of 50.
struct CalibrationOptions {
  DltOptions dlt = {};
  double outlier_ratio = 8.0;
  double min_outlier_m = 0.002;
  int max_outliers = 2;
  bool leave_one_out = true;  // leave-one-out and outliers; most of the time

  // Throws dropfit::Error naming the field and value when one is out of
  // range (NaN, a ratio of 1 or less, a negative distance or count), and
  // dlt.validate(); calibrate() calls it.
  void validate() const;
};

struct CalibrationResult {
  std::vector<DltFit> cameras;  // in the order of the views
  // Check markers seen by two or more cameras, reconstructed by
  // calibration::triangulate (triangulation.h) with refinement.
  std::vector<CheckPoint> check_points;
  std::vector<std::string> check_unseen;  // check markers seen by fewer than two cameras
  Eigen::Vector3d check_rms_m = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
  double check_max_m = std::numeric_limits<double>::quiet_NaN();  // largest per-axis absolute error
  std::vector<LeaveOneOut> leave_one_out;  // per fit marker, in frame order
  std::vector<std::string> outliers;       // in frame order (see above)
  std::vector<double> outlier_error_m;     // each outlier's 3-D error from the fits without them
  double outlier_baseline_m = std::numeric_limits<double>::quiet_NaN();  // the median it is compared with

  std::string model() const;   // "dlt11" or "dlt16"
  std::string report() const;  // a few human lines
};

// Fits every camera on the fit markers it sees, then reports the check
// markers' 3-D errors, the leave-one-out residuals and the outliers.
// Throws dropfit::Error for fewer than two cameras, duplicate or unknown
// marker ids, and whatever fit_dlt throws (prefixed with the camera).
CalibrationResult calibrate(const std::vector<Marker>& markers, const std::vector<CameraView>& views,
                            const CalibrationOptions& options = {});

// A calibration given as coefficients (easyWand, Argus, DLTdv), checked on
// whatever frame markers the views show: the check markers are
// triangulated with `cameras` and reported as calibrate() reports them;
// each camera's fit_rms_px is the RMS reprojection distance of every frame
// marker it sees (fit and check; NaN when it sees none) and n_fit_points is
// 0 (nothing was fitted). No leave-one-out, no outliers. With no markers
// the result carries the cameras only and says that accuracy was not
// checked. `views` are empty or one per camera, in the same order. Throws
// dropfit::Error for fewer than two cameras, duplicate or unknown marker ids.
CalibrationResult given_calibration(const std::vector<Camera>& cameras, const std::vector<Marker>& markers,
                                    const std::vector<CameraView>& views);

}  // namespace dropfit::calibration

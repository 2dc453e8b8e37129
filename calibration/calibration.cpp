#include "calibration/calibration.h"

#include <ceres/ceres.h>
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <Eigen/Geometry>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <functional>
#include <cmath>
#include <limits>
#include <unordered_map>

#include "calibration/triangulation.h"
#include "core/error.h"
#include "core/validate.h"
#include "core/median.h"

namespace dropfit::calibration {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Bouguet's distortion of a normalised image point (x, y) (header comment);
// d = k1 k2 p1 p2 k3. Templated for Ceres' Jets.
template <typename T>
void distort_normalised(const T* d, const T& x, const T& y, T* xd, T* yd) {
  const T r2 = x * x + y * y;
  const T radial = T(1.0) + r2 * (d[0] + r2 * (d[1] + r2 * d[4]));
  *xd = x * radial + T(2.0) * d[2] * x * y + d[3] * (r2 + T(2.0) * x * x);
  *yd = y * radial + d[2] * (r2 + T(2.0) * y * y) + T(2.0) * d[3] * x * y;
}

// Hartley's isotropic normalisation: centroid to the origin, mean distance
// from it sqrt(dim). normalised = scale * (p - centroid).
template <int Dim>
struct Normalisation {
  Eigen::Matrix<double, Dim, 1> centroid;
  double scale = 1.0;
};

template <int Dim>
Normalisation<Dim> normalisation(const std::vector<Eigen::Matrix<double, Dim, 1>>& points) {
  Normalisation<Dim> n;
  n.centroid.setZero();
  for (const auto& p : points) n.centroid += p;
  n.centroid /= static_cast<double>(points.size());
  double mean_distance = 0.0;
  for (const auto& p : points) mean_distance += (p - n.centroid).norm();
  mean_distance /= static_cast<double>(points.size());
  n.scale = mean_distance > 0.0 ? std::sqrt(static_cast<double>(Dim)) / mean_distance : 0.0;
  return n;
}

// Reprojection error of one calibration marker for the DLT in Hartley-
// normalised coordinates, Q = [q0..q3; q4..q7; q8 q9 q10 1] (11 parameters):
//
//   [a, b, w]^T = Q [Xn; 1]                    Xn: normalised lab point
//   (u, v) = c2 + (a / w, b / w) / s2           back to pixels
//   residual = (u, v) - measured pixel          [px]
struct DltReprojection {
  DltReprojection(const Eigen::Vector3d& lab_n, const Eigen::Vector2d& image_px,
                  const Normalisation<2>& image_norm)
      : lab_n_(lab_n), image_px_(image_px), centroid_(image_norm.centroid), scale_(image_norm.scale) {}

  template <typename T>
  bool operator()(const T* q, T* residual) const {
    T u, v;
    if (!project(q, lab_n_, centroid_, scale_, &u, &v)) return false;
    residual[0] = u - image_px_.x();
    residual[1] = v - image_px_.y();
    return true;
  }

  // False for a point on the camera's principal plane (w = 0).
  template <typename T>
  static bool project(const T* q, const Eigen::Vector3d& x, const Eigen::Vector2d& centroid, double scale,
                      T* u, T* v) {
    const T a = q[0] * x.x() + q[1] * x.y() + q[2] * x.z() + q[3];
    const T b = q[4] * x.x() + q[5] * x.y() + q[6] * x.z() + q[7];
    const T w = q[8] * x.x() + q[9] * x.y() + q[10] * x.z() + T(1.0);
    if (w == T(0.0)) return false;
    *u = centroid.x() + a / (w * scale);
    *v = centroid.y() + b / (w * scale);
    return true;
  }

  static ceres::CostFunction* Create(const Eigen::Vector3d& lab_n, const Eigen::Vector2d& image_px,
                                     const Normalisation<2>& image_norm) {
    return new ceres::AutoDiffCostFunction<DltReprojection, 2, 11>(
        new DltReprojection(lab_n, image_px, image_norm));
  }

  Eigen::Vector3d lab_n_;
  Eigen::Vector2d image_px_;
  Eigen::Vector2d centroid_;
  double scale_;
};

// The same with Bouguet's distortion (d = k1 k2 p1 p2 k3) about the DLT's
// own principal point c with its mean focal length f as the radius scale
// (header comment), both derived from q at every evaluation:
//
//   (u, v) as in DltReprojection
//   x = (u - cu) / f, y = (v - cv) / f; (xd, yd) = distort(x, y)
//   residual = c + f (xd, yd) - measured pixel   [px]
//
// The centre moves with the DLT, so the fitted model is the one a camera
// with its distortion about its optical axis makes. Held fixed at the
// linear DLT's principal point instead (which the distortion itself bends),
// the centre was 113 px off on a strongly distorted camera (k1 -0.65) and
// left 0.74 px of reprojection error against 0.2 px of noise.
struct DistortedDltReprojection {
  // fixed_focal_px > 0: the centre and radius scale held at fixed_centre_px
  // and fixed_focal_px instead (the linear DLT's; see fit_dlt).
  DistortedDltReprojection(const Eigen::Vector3d& lab_n, const Eigen::Vector2d& image_px,
                           const Normalisation<2>& image_norm, const Eigen::Vector2d& fixed_centre_px,
                           double fixed_focal_px)
      : lab_n_(lab_n),
        image_px_(image_px),
        centroid_(image_norm.centroid),
        scale_(image_norm.scale),
        fixed_centre_px_(fixed_centre_px),
        fixed_focal_px_(fixed_focal_px) {}

  template <typename T>
  bool operator()(const T* q, const T* d, T* residual) const {
    T u, v, cu, cv, f;
    if (!DltReprojection::project(q, lab_n_, centroid_, scale_, &u, &v)) return false;
    if (fixed_focal_px_ > 0.0) {
      cu = T(fixed_centre_px_.x());
      cv = T(fixed_centre_px_.y());
      f = T(fixed_focal_px_);
    } else if (!centre_of(q, centroid_, scale_, &cu, &cv, &f)) {
      return false;
    }
    const T x = (u - cu) / f;
    const T y = (v - cv) / f;
    T xd, yd;
    distort_normalised(d, x, y, &xd, &yd);
    residual[0] = cu + f * xd - image_px_.x();
    residual[1] = cv + f * yd - image_px_.y();
    return true;
  }

  // principal_point_and_focal() on the pixel DLT of the normalised q:
  // its rows' left 3 x 3 are a = qa / s + cx qc, b = qb / s + cy qc, c = qc
  // (the lab points' scaling multiplies all three alike and cancels).
  template <typename T>
  static bool centre_of(const T* q, const Eigen::Vector2d& centroid, double scale, T* cu, T* cv, T* f) {
    T a[3], b[3], c[3];
    for (int i = 0; i < 3; ++i) {
      c[i] = q[8 + i];
      a[i] = q[i] / scale + centroid.x() * c[i];
      b[i] = q[4 + i] / scale + centroid.y() * c[i];
    }
    const T D = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
    if (!(D > T(0.0))) return false;
    *cu = (a[0] * c[0] + a[1] * c[1] + a[2] * c[2]) / D;
    *cv = (b[0] * c[0] + b[1] * c[1] + b[2] * c[2]) / D;
    const T fu2 = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]) / D - *cu * *cu;
    const T fv2 = (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]) / D - *cv * *cv;
    if (!(fu2 > T(0.0) && fv2 > T(0.0))) return false;
    using std::sqrt;
    *f = 0.5 * (sqrt(fu2) + sqrt(fv2));
    return true;
  }

  static ceres::CostFunction* Create(const Eigen::Vector3d& lab_n, const Eigen::Vector2d& image_px,
                                     const Normalisation<2>& image_norm, const Eigen::Vector2d& fixed_centre_px,
                                     double fixed_focal_px) {
    return new ceres::AutoDiffCostFunction<DistortedDltReprojection, 2, 11, 5>(
        new DistortedDltReprojection(lab_n, image_px, image_norm, fixed_centre_px, fixed_focal_px));
  }

  Eigen::Vector3d lab_n_;
  Eigen::Vector2d image_px_;
  Eigen::Vector2d centroid_;
  double scale_;
  Eigen::Vector2d fixed_centre_px_;
  double fixed_focal_px_;
};

// The k1 the moving-centre refinement starts from besides the fixed-centre
// optimum (radius normalised by the focal length): barrel to pincushion
// across real lenses.
constexpr double kDistortionSeedsK1[] = {-1.0, -0.6, -0.3, 0.3, 0.6};

// Levenberg-Marquardt on the reprojection error of every point: q (the 11
// normalised DLT coefficients) and, with distortion, d (k1 k2 p1 p2 k3, the
// terms not asked for held at zero), both updated in place; the distortion
// about the DLT's own centre, or about a fixed one when fixed_focal_px > 0.
// Returns the final cost (half the sum of squared pixel residuals).
double refine(const std::string& label, const std::vector<Eigen::Vector3d>& lab_n,
              const std::vector<Eigen::Vector2d>& image, const Normalisation<2>& image_norm,
              const DltOptions& options, double* q, double* d, const Eigen::Vector2d& fixed_centre_px = {0.0, 0.0},
              double fixed_focal_px = 0.0) {
  ceres::Problem problem;
  for (std::size_t i = 0; i < lab_n.size(); ++i) {
    if (options.fit_distortion)
      problem.AddResidualBlock(
          DistortedDltReprojection::Create(lab_n[i], image[i], image_norm, fixed_centre_px, fixed_focal_px), nullptr,
          q, d);
    else
      problem.AddResidualBlock(DltReprojection::Create(lab_n[i], image[i], image_norm), nullptr, q);
  }
  if (options.fit_distortion) {
    std::vector<int> held;
    if (options.radial_terms < 1) held.push_back(0);
    if (options.radial_terms < 2) held.push_back(1);
    if (!options.tangential) held.insert(held.end(), {2, 3});
    if (options.radial_terms < 3) held.push_back(4);
    if (!held.empty()) problem.SetManifold(d, new ceres::SubsetManifold(5, held));
  }
  ceres::Solver::Options solver;
  solver.linear_solver_type = ceres::DENSE_QR;
  solver.logging_type = ceres::SILENT;
  solver.minimizer_progress_to_stdout = false;
  solver.num_threads = 1;
  solver.max_num_iterations = 100;
  solver.function_tolerance = 1e-12;
  solver.gradient_tolerance = 1e-14;
  solver.parameter_tolerance = 1e-12;
  ceres::Solver::Summary summary;
  ceres::Solve(solver, &problem, &summary);
  if (!summary.IsSolutionUsable())
    throw Error(fmt::format("{}: the DLT refinement failed ({})", label, summary.message));
  return summary.final_cost;
}

int parameter_count(const DltOptions& options) {
  return 11 + (options.fit_distortion ? options.radial_terms + (options.tangential ? 2 : 0) : 0);
}

// More equations than unknowns.
int min_fit_points(const DltOptions& options) { return parameter_count(options) / 2 + 1; }

std::string label_of(const std::string& camera_name) {
  return camera_name.empty() ? std::string("camera") : camera_name;
}

// Millimetres for a report line: 0.47, 951.1, 2.46e+16.
std::string mm(double metres) {
  const double v = 1e3 * metres;
  return std::abs(v) < 100.0 ? fmt::format("{:.2f}", v) : std::abs(v) < 1e5 ? fmt::format("{:.1f}", v) : fmt::format("{:.3g}", v);
}


}  // namespace

// ---- Camera ----------------------------------------------------------------

Matrix34d Camera::image_from_lab() const {
  Matrix34d P;
  P << dlt[0], dlt[1], dlt[2], dlt[3],  //
      dlt[4], dlt[5], dlt[6], dlt[7],   //
      dlt[8], dlt[9], dlt[10], 1.0;
  return P;
}

Eigen::Vector2d Camera::project(const Eigen::Vector3d& lab_m) const {
  const Eigen::Vector3d h = image_from_lab() * lab_m.homogeneous();
  const Eigen::Vector2d ideal = h.head<2>() / h.z();
  if (distortion.empty()) return ideal;
  if (distortion.size() != 5)
    throw Error(fmt::format("{}: lens distortion needs 5 terms (k1 k2 p1 p2 k3), {} given", label_of(name),
                            distortion.size()));
  const Eigen::Vector2d x = (ideal - principal_point_px) / focal_px;
  Eigen::Vector2d xd;
  distort_normalised(distortion.data(), x.x(), x.y(), &xd.x(), &xd.y());
  return principal_point_px + focal_px * xd;
}

Eigen::Vector2d Camera::undistort(const Eigen::Vector2d& image_px) const {
  if (distortion.empty() || !image_px.allFinite()) return image_px;
  if (distortion.size() != 5)
    throw Error(fmt::format("{}: lens distortion needs 5 terms (k1 k2 p1 p2 k3), {} given", label_of(name),
                            distortion.size()));
  const double* d = distortion.data();
  const double k1 = d[0], k2 = d[1], p1 = d[2], p2 = d[3], k3 = d[4];
  const Eigen::Vector2d target = (image_px - principal_point_px) / focal_px;
  // Newton on distort(x) = target, from x = target; the analytic Jacobian of
  // the model in the header comment.
  Eigen::Vector2d x = target;
  const double tolerance = 1e-10 / focal_px;  // 1e-10 px
  for (int iteration = 0; iteration < 30; ++iteration) {
    const double r2 = x.squaredNorm();
    const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
    const double dradial = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3);  // d radial / d r2
    Eigen::Vector2d f;
    distort_normalised(d, x.x(), x.y(), &f.x(), &f.y());
    f -= target;
    if (f.norm() < tolerance) return principal_point_px + focal_px * x;
    Eigen::Matrix2d J;
    const double xy = x.x() * x.y();
    J(0, 0) = radial + 2.0 * x.x() * x.x() * dradial + 2.0 * p1 * x.y() + 6.0 * p2 * x.x();
    J(0, 1) = 2.0 * xy * dradial + 2.0 * p1 * x.x() + 2.0 * p2 * x.y();
    J(1, 0) = J(0, 1);
    J(1, 1) = radial + 2.0 * x.y() * x.y() * dradial + 6.0 * p1 * x.y() + 2.0 * p2 * x.x();
    const double det = J.determinant();
    if (!(std::abs(det) > 1e-12)) break;  // at the fold: no local inverse
    x -= J.inverse() * f;
  }
  return Eigen::Vector2d::Constant(kNaN);
}

Camera Camera::from_image_from_lab(std::string name, const Matrix34d& image_from_lab) {
  const double scale = image_from_lab(2, 3);
  if (!(std::abs(scale) > 1e-12 * image_from_lab.norm()))
    throw Error(fmt::format(
        "{}: the lab origin lies in the camera's principal plane, so the camera cannot be written as 11 DLT "
        "coefficients (L12 = 1); move the lab origin in front of the camera",
        label_of(name)));
  const Matrix34d P = image_from_lab / scale;
  Camera camera;
  camera.name = std::move(name);
  camera.dlt << P(0, 0), P(0, 1), P(0, 2), P(0, 3), P(1, 0), P(1, 1), P(1, 2), P(1, 3), P(2, 0), P(2, 1),
      P(2, 2);
  return camera;
}

// Principal point and mean focal length of a DLT (the standard decomposition,
// e.g. Kwon's DLT notes): with D = L9^2 + L10^2 + L11^2,
//   u0 = (L1 L9 + L2 L10 + L3 L11) / D,  v0 = (L5 L9 + L6 L10 + L7 L11) / D
//   fu^2 = (L1^2 + L2^2 + L3^2) / D - u0^2, likewise fv.
bool principal_point_and_focal(const Dlt11& L, Eigen::Vector2d* principal_px, double* focal_px) {
  const Eigen::Vector3d a(L[0], L[1], L[2]), b(L[4], L[5], L[6]), c(L[8], L[9], L[10]);
  const double D = c.squaredNorm();
  if (!(D > 0.0)) return false;
  const double u0 = a.dot(c) / D, v0 = b.dot(c) / D;
  const double fu2 = a.squaredNorm() / D - u0 * u0, fv2 = b.squaredNorm() / D - v0 * v0;
  if (!(fu2 > 0.0 && fv2 > 0.0)) return false;
  *principal_px = {u0, v0};
  *focal_px = 0.5 * (std::sqrt(fu2) + std::sqrt(fv2));
  return true;
}

// ---- fit_dlt ----------------------------------------------------------------

namespace {

// The lab points' geometry for a DLT (fit_dlt): the principal axes of their
// scatter, whose eigenvalues are the squared RMS spreads along them (the
// singular values of the centred points, squared, over n). Throws naming the
// camera when the points are at one position, collinear or coplanar.
void check_fit_geometry(const std::string& label, const char* model, const std::vector<Eigen::Vector3d>& lab,
                        const Normalisation<3>& lab_norm) {
  const int n = static_cast<int>(lab.size());
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (const auto& X : lab) scatter.noalias() += (X - lab_norm.centroid) * (X - lab_norm.centroid).transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen;
  eigen.computeDirect(scatter / n, Eigen::EigenvaluesOnly);
  // RMS spread along the principal axes, largest first.
  const Eigen::Vector3d s = eigen.eigenvalues().cwiseMax(0.0).cwiseSqrt().reverse();
  constexpr double kFlat = 0.01;  // RMS off-axis spread below 1 % of the largest
  if (!(s[0] > 0.0))
    throw Error(fmt::format("{}: the {} calibration points all lie at one lab position", label, n));
  if (s[1] < kFlat * s[0])
    throw Error(fmt::format(
        "{}: the {} calibration points are (nearly) collinear (RMS {:.1f} mm off their line over an RMS "
        "spread of {:.0f} mm); the {} needs points spread in three dimensions",
        label, n, 1e3 * std::hypot(s[1], s[2]), 1e3 * s[0], model));
  if (s[2] < kFlat * s[0])
    throw Error(fmt::format(
        "{}: the {} calibration points are (nearly) coplanar (RMS {:.1f} mm off their plane over an RMS "
        "spread of {:.0f} mm); the {} needs points off one plane",
        label, n, 1e3 * s[2], 1e3 * s[0], model));
}

// The linear DLT of fit_dlt in normalised coordinates: q[0..10] of Q with
// Q(2,3) = 1. Throws naming the camera when the points do not determine it.
void linear_dlt(const std::string& label, const std::vector<Eigen::Vector3d>& lab,
                const std::vector<Eigen::Vector2d>& image, const Normalisation<3>& lab_norm,
                const Normalisation<2>& image_norm, double q[11]) {
  const int n = static_cast<int>(lab.size());
  // Linear DLT in normalised coordinates: the homogeneous 2n x 12 system
  // A p = 0 solved in the least-squares sense with |p| = 1 (p the right
  // singular vector of the smallest singular value; H&Z algorithm 7.1).
  // Chosen over the inhomogeneous 11-unknown form (L12 fixed at 1) because
  // it treats all twelve entries alike and assumes nothing about which one
  // is safely non-zero; Q = Pn / Pn(2,3) afterwards is safe in normalised
  // coordinates, where Pn(2,3) is proportional to the depth of the points'
  // centroid. The normal matrix A^T A (12 x 12) is accumulated row by row;
  // its eigenvector of the smallest eigenvalue is that singular vector.
  // Squaring the condition number is harmless because the normalisation
  // keeps A well scaled (Hartley 1997's very point), and it is 10 times
  // faster than an SVD of A.
  Eigen::Matrix<double, 12, 12> AtA = Eigen::Matrix<double, 12, 12>::Zero();
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector4d X = (lab_norm.scale * (lab[i] - lab_norm.centroid)).homogeneous();
    const Eigen::Vector2d x = image_norm.scale * (image[i] - image_norm.centroid);
    Eigen::Matrix<double, 12, 1> row_u, row_v;
    row_u << X, Eigen::Vector4d::Zero(), -x.x() * X;
    row_v << Eigen::Vector4d::Zero(), X, -x.y() * X;
    AtA.noalias() += row_u * row_u.transpose() + row_v * row_v.transpose();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 12, 12>> eigen(AtA);
  const auto& ev = eigen.eigenvalues();  // ascending
  // A second (nearly) null direction: the points do not determine the DLT,
  // e.g. all but one of them in one plane. Good sets of 7 to 10 markers
  // give ev[1] / ev[11] of 4e-3 and more, such sets 1e-8 and less.
  if (eigen.info() != Eigen::Success || !(ev[1] > 1e-5 * ev[11]))
    throw Error(fmt::format(
        "{}: the {} calibration points do not determine the DLT (degenerate geometry: too few points off the "
        "plane of the others?)",
        label, n));
  const Eigen::Matrix<double, 12, 1> p = eigen.eigenvectors().col(0);  // |p| = 1
  if (!(std::abs(p[11]) > 1e-8))
    throw Error(fmt::format("{}: the calibration points' centroid lies in the camera's principal plane", label));
  for (int k = 0; k < 11; ++k) q[k] = p[k] / p[11];
}

}  // namespace

namespace {

// The options and points a fit can start from: a distortion model that
// exists, enough points for its parameters, every coordinate finite.
void check_fit_input(const std::string& label, const char* model, const std::vector<Correspondence>& points,
                     const DltOptions& options) {
  const int n = static_cast<int>(points.size());
  if (options.fit_distortion &&
      (options.radial_terms < 0 || options.radial_terms > 3 || (options.radial_terms == 0 && !options.tangential)))
    throw Error(fmt::format("{}: lens distortion needs 1 to 3 radial terms or the tangential ones ({} radial given)",
                            label, options.radial_terms));
  const int n_params = parameter_count(options);
  const int min_points = min_fit_points(options);
  if (n < min_points)
    throw Error(fmt::format("{}: {} calibration point{} given; the {} ({} parameters) needs at least {}", label,
                            n, n == 1 ? "" : "s", model, n_params, min_points));
  for (const auto& p : points)
    if (!p.lab_m.allFinite() || !p.image_px.allFinite())
      throw Error(fmt::format("{}: calibration point '{}' has a coordinate that is not a finite number", label,
                              p.id));
}

// The distortion about the DLT's own centre from several starts; q, d (the
// linear DLT's normalised coefficients and zero distortion on entry) and the
// centre and focal length (the linear DLT's on entry) become the best fit's.
void distortion_multistart(const std::string& label, const std::vector<Eigen::Vector3d>& lab_n,
                           const std::vector<Eigen::Vector2d>& image, const Normalisation<2>& image_norm,
                           const DltOptions& options, const std::function<Camera(const double*)>& to_camera, double* q,
                           double* d, Eigen::Vector2d* best_centre, double* best_focal) {
  // The distortion about the DLT's own centre is a hard landscape: the
  // linear DLT's principal point, bent by the distortion, can sit far from
  // the optical axis, and from there k1 stays near 0 in a poor optimum.
  // So: the distortion about the linear DLT's centre held fixed (a
  // well-posed start), then the moving centre from that optimum and from
  // the linear DLT with k1 seeded across the range of real lenses; the
  // lowest cost is kept (every start fits the same parameters).
  const Eigen::Vector2d centre0 = *best_centre;
  const double focal0 = *best_focal;
  double q_linear[11];
  std::copy(q, q + 11, q_linear);
  double best_cost = refine(label, lab_n, image, image_norm, options, q, d, centre0, focal0);
  double q_fixed[11], d_fixed[5];
  std::copy(q, q + 11, q_fixed);
  std::copy(d, d + 5, d_fixed);
  auto from = [&](const double* q_start, const double* d_start) {
    double qs[11], ds[5];
    std::copy(q_start, q_start + 11, qs);
    std::copy(d_start, d_start + 5, ds);
    double cost = std::numeric_limits<double>::infinity();
    try {
      cost = refine(label, lab_n, image, image_norm, options, qs, ds);
    } catch (const Error&) {
      return;
    }
    Eigen::Vector2d centre;
    double focal = 0.0;
    if (!(cost < best_cost) || !principal_point_and_focal(to_camera(qs).dlt, &centre, &focal)) return;
    best_cost = cost;
    *best_centre = centre;
    *best_focal = focal;
    std::copy(qs, qs + 11, q);
    std::copy(ds, ds + 5, d);
  };
  from(q_fixed, d_fixed);
  if (options.radial_terms >= 1)  // k1 free
    for (double k1 : kDistortionSeedsK1) {
      const double d_seed[5] = {k1, 0.0, 0.0, 0.0, 0.0};
      from(q_linear, d_seed);
    }
}

// Each point's reprojection residual and their RMS.
void set_residuals(const std::vector<Eigen::Vector3d>& lab, const std::vector<Eigen::Vector2d>& image, DltFit& fit) {
  fit.residuals_px.resize(lab.size());
  double sum_sq = 0.0;
  for (std::size_t i = 0; i < lab.size(); ++i) {
    fit.residuals_px[i] = image[i] - fit.camera.project(lab[i]);
    sum_sq += fit.residuals_px[i].squaredNorm();
  }
  fit.fit_rms_px = std::sqrt(sum_sq / static_cast<double>(lab.size()));
}

}  // namespace

DltFit fit_dlt(const std::string& camera_name, const std::vector<Correspondence>& points,
               const DltOptions& options) {
  const std::string label = label_of(camera_name);
  const int n = static_cast<int>(points.size());
  const char* model = options.fit_distortion ? "DLT with lens distortion" : "11-parameter DLT";
  check_fit_input(label, model, points, options);

  std::vector<Eigen::Vector3d> lab(points.size());
  std::vector<Eigen::Vector2d> image(points.size());
  for (int i = 0; i < n; ++i) {
    lab[i] = points[i].lab_m;
    image[i] = points[i].image_px;
  }
  const Normalisation<3> lab_norm = normalisation(lab);
  const Normalisation<2> image_norm = normalisation(image);
  check_fit_geometry(label, model, lab, lab_norm);
  if (!(image_norm.scale > 0.0))
    throw Error(fmt::format("{}: the {} calibration points all have the same pixel position", label, n));
  double q[11];
  linear_dlt(label, lab, image, lab_norm, image_norm, q);

  // Back to lab metres and pixels: P = U^-1 Q T.
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  T.topLeftCorner<3, 3>() *= lab_norm.scale;
  T.topRightCorner<3, 1>() = -lab_norm.scale * lab_norm.centroid;
  Eigen::Matrix3d U_inv = Eigen::Matrix3d::Identity();
  U_inv.topLeftCorner<2, 2>() /= image_norm.scale;
  U_inv.topRightCorner<2, 1>() = image_norm.centroid;
  const auto to_camera = [&](const double* qq) {
    Matrix34d Q;
    Q << qq[0], qq[1], qq[2], qq[3], qq[4], qq[5], qq[6], qq[7], qq[8], qq[9], qq[10], 1.0;
    return Camera::from_image_from_lab(camera_name, U_inv * Q * T);
  };

  DltFit fit;
  fit.camera = to_camera(q);
  fit.n_fit_points = n;

  double d[5] = {0.0, 0.0, 0.0, 0.0, 0.0};
  if (options.fit_distortion) {
    if (!principal_point_and_focal(fit.camera.dlt, &fit.camera.principal_point_px, &fit.camera.focal_px))
      throw Error(fmt::format("{}: the linear DLT has no principal point and focal length (degenerate fit)", label));
  }
  if (options.refine || options.fit_distortion) {
    std::vector<Eigen::Vector3d> lab_n(points.size());
    for (int i = 0; i < n; ++i) lab_n[i] = lab_norm.scale * (lab[i] - lab_norm.centroid);
    if (!options.fit_distortion) {
      refine(label, lab_n, image, image_norm, options, q, d);
      fit.camera = to_camera(q);
    } else {
      // The fitted camera from normalised coefficients, distortion, centre, focal.
      auto adopt = [&](const double* qq, const double* dd, const Eigen::Vector2d& centre, double focal) {
        fit.camera = to_camera(qq);
        fit.camera.distortion.assign(dd, dd + 5);
        fit.camera.principal_point_px = centre;
        fit.camera.focal_px = focal;
      };
      // From the given start (its terms that these options hold, zeroed):
      // one refinement.
      bool warm = false;
      if (options.start && options.start->distortion.size() == 5) {
        // Q = U P T^-1, scaled to Q(2,3) = 1 (the inverse of to_camera).
        Eigen::Matrix3d U = Eigen::Matrix3d::Identity();
        U.topLeftCorner<2, 2>() *= image_norm.scale;
        U.topRightCorner<2, 1>() = -image_norm.scale * image_norm.centroid;
        const Matrix34d Q = U * options.start->image_from_lab() * T.inverse();
        if (std::abs(Q(2, 3)) > 0.0) {
          double qs[11], ds[5];
          for (int k = 0; k < 11; ++k) qs[k] = Q(k / 4, k % 4) / Q(2, 3);
          for (int k = 0; k < 5; ++k) ds[k] = options.start->distortion[static_cast<std::size_t>(k)];
          if (options.radial_terms < 1) ds[0] = 0.0;
          if (options.radial_terms < 2) ds[1] = 0.0;
          if (!options.tangential) ds[2] = ds[3] = 0.0;
          if (options.radial_terms < 3) ds[4] = 0.0;
          try {
            refine(label, lab_n, image, image_norm, options, qs, ds);
            Eigen::Vector2d centre;
            double focal = 0.0;
            if (principal_point_and_focal(to_camera(qs).dlt, &centre, &focal)) {
              adopt(qs, ds, centre, focal);
              warm = true;
            }
          } catch (const Error&) {
          }
        }
      }
      if (!warm) {
        Eigen::Vector2d best_centre = fit.camera.principal_point_px;
        double best_focal = fit.camera.focal_px;
        distortion_multistart(label, lab_n, image, image_norm, options, to_camera, q, d, &best_centre, &best_focal);
        adopt(q, d, best_centre, best_focal);
      }
    }
  }

  set_residuals(lab, image, fit);
  return fit;
}

// ---- calibrate --------------------------------------------------------------

namespace {

// The markers as every camera saw them, for calibrate: fits, triangulation
// errors and the leave-one-out passes.
class Calibrator {
 public:
  Calibrator(const std::vector<Marker>& markers, const std::vector<CameraView>& views)
      : markers_(markers), views_(views), n_markers_(static_cast<int>(markers.size())),
        n_cameras_(static_cast<int>(views.size())) {
    std::unordered_map<std::string, int> index;
    for (int m = 0; m < n_markers_; ++m) {
      if (!index.emplace(markers[m].id, m).second)
        throw Error(fmt::format("calibration marker '{}' is listed twice", markers[m].id));
      if (!markers[m].lab_m.allFinite())
        throw Error(fmt::format("calibration marker '{}' has a lab coordinate that is not a finite number",
                                markers[m].id));
    }
    // seen_[c][m]: marker m's pixel in camera c, NaN when not seen.
    seen_.assign(n_cameras_, std::vector<Eigen::Vector2d>(n_markers_, Eigen::Vector2d::Constant(kNaN)));
    for (int c = 0; c < n_cameras_; ++c) {
      for (const auto& [id, px] : views[c].observations) {
        const auto it = index.find(id);
        if (it == index.end())
          throw Error(fmt::format("{}: observes marker '{}', which the calibration frame does not list",
                                  label_of(views[c].name), id));
        if (seen_[c][it->second].allFinite())
          throw Error(fmt::format("{}: marker '{}' is observed twice", label_of(views[c].name), id));
        if (px.allFinite()) seen_[c][it->second] = px;
      }
    }
    px_.resize(n_cameras_);
  }

  int n_markers() const { return n_markers_; }
  int n_cameras() const { return n_cameras_; }
  bool seen(int c, int m) const { return seen_[c][m].allFinite(); }

  // Camera c fitted on the fit markers it sees, less those excluded.
  DltFit fit_camera(int c, const std::vector<char>& excluded, const DltOptions& dlt) const {
    std::vector<Correspondence> fit_points;
    for (int m = 0; m < n_markers_; ++m)
      if (!markers_[m].is_check && !excluded[m] && seen_[c][m].allFinite())
        fit_points.push_back({markers_[m].id, markers_[m].lab_m, seen_[c][m]});
    return fit_dlt(views_[c].name, fit_points, dlt);
  }

  // Marker m triangulated with `cameras`: reconstructed minus known.
  Eigen::Vector3d error_of(int m, const std::vector<Camera>& cameras) {
    for (int c = 0; c < n_cameras_; ++c) px_[c] = seen_[c][m];
    return triangulate(cameras, px_, true).lab_m - markers_[m].lab_m;
  }

  // One leave-one-out pass with the `excluded` markers out of every fit: per
  // fit marker m (not excluded), every camera that sees it is refitted
  // without it; residual_m[m] is m's 3-D error with those refits and
  // refit_rms_px[m] the reprojection RMS of all cameras' fits without m.
  struct Pass {
    bool ok = false;
    std::vector<Camera> base;  // every camera fitted without the excluded markers
    std::vector<double> residual_m, refit_rms_px;
  };
  Pass leave_each_out(const std::vector<char>& excluded, const DltOptions& dlt) {
    Pass pass;
    pass.residual_m.assign(n_markers_, kNaN);
    pass.refit_rms_px.assign(n_markers_, kNaN);
    std::vector<DltFit> base_fits;
    try {
      for (int c = 0; c < n_cameras_; ++c) base_fits.push_back(fit_camera(c, excluded, dlt));
    } catch (const Error&) {
      return pass;  // too few markers left
    }
    for (const auto& f : base_fits) pass.base.push_back(f.camera);
    pass.ok = true;
    std::vector<char> without = excluded;
    for (int m = 0; m < n_markers_; ++m) {
      if (markers_[m].is_check || excluded[m]) continue;
      without[m] = 1;
      std::vector<Camera> refitted = pass.base;
      double sum_sq_px = 0.0;
      int count = 0;
      bool ok = true;
      for (int c = 0; c < n_cameras_ && ok; ++c) {
        DltFit refit;
        const DltFit* fit = &base_fits[c];
        if (seen_[c][m].allFinite()) {
          try {
            DltOptions warm = dlt;  // a fold starts from the fit on all the markers
            warm.start = &pass.base[static_cast<std::size_t>(c)];
            refit = fit_camera(c, without, warm);
          } catch (const Error&) {
            ok = false;  // too few points left, or degenerate without this one
            break;
          }
          refitted[c] = refit.camera;
          fit = &refit;
        }
        for (const auto& r : fit->residuals_px) sum_sq_px += r.squaredNorm();
        count += fit->n_fit_points;
      }
      without[m] = 0;
      if (!ok) continue;
      pass.refit_rms_px[m] = std::sqrt(sum_sq_px / count);
      const Eigen::Vector3d error = error_of(m, refitted);
      if (error.allFinite()) pass.residual_m[m] = error.norm();
    }
    return pass;
  }

 private:
  const std::vector<Marker>& markers_;
  const std::vector<CameraView>& views_;
  int n_markers_, n_cameras_;
  std::vector<std::vector<Eigen::Vector2d>> seen_;
  std::vector<Eigen::Vector2d> px_;  // scratch for error_of
};

// One check marker's error into result (sum_sq accumulates per axis), and
// the per-axis RMS once all are in: shared by calibrate() and the report of
// given cameras.
void add_check_point(CalibrationResult& result, const std::string& id, const Eigen::Vector3d& error, int n_seeing,
                     Eigen::Vector3d& sum_sq) {
  result.check_points.push_back({id, error, n_seeing});
  sum_sq += error.cwiseAbs2();
  const double largest = error.cwiseAbs().maxCoeff();
  result.check_max_m = std::isnan(result.check_max_m) ? largest : std::max(result.check_max_m, largest);
}

void finish_check(CalibrationResult& result, const Eigen::Vector3d& sum_sq) {
  if (!result.check_points.empty())
    result.check_rms_m = (sum_sq / static_cast<double>(result.check_points.size())).cwiseSqrt();
}

// The check markers' errors with `cameras` into result.
void check_marker_errors(Calibrator& cal, const std::vector<Marker>& markers, const std::vector<Camera>& cameras,
                         CalibrationResult& result) {
  Eigen::Vector3d sum_sq = Eigen::Vector3d::Zero();
  for (int m = 0; m < cal.n_markers(); ++m) {
    if (!markers[m].is_check) continue;
    const Eigen::Vector3d error = cal.error_of(m, cameras);
    if (!error.allFinite()) {
      result.check_unseen.push_back(markers[m].id);
      continue;
    }
    int n_seeing = 0;
    for (int c = 0; c < cal.n_cameras(); ++c) n_seeing += cal.seen(c, m) ? 1 : 0;
    add_check_point(result, markers[m].id, error, n_seeing, sum_sq);
  }
  finish_check(result, sum_sq);
}

// Leave-one-out residuals and outliers (calibration.h) into result.
void leave_one_out_and_outliers(Calibrator& cal, const std::vector<Marker>& markers,
                                const CalibrationOptions& options, CalibrationResult& result) {
  const int n_markers = cal.n_markers();
  std::vector<char> excluded(n_markers, 0);
  Calibrator::Pass pass = cal.leave_each_out(excluded, options.dlt);
  int n_fit = 0;
  for (int m = 0; m < n_markers; ++m) {
    if (markers[m].is_check) continue;
    ++n_fit;
    result.leave_one_out.push_back({markers[m].id, pass.residual_m[m]});
  }

  // Outliers (header comment): set aside, one at a time, the marker whose
  // removal leaves the best-fitting DLTs ...
  DltOptions screen = options.dlt;
  if (screen.fit_distortion && n_fit - (min_fit_points(screen) + 2) < 1) {
    screen.fit_distortion = false;  // too few markers to screen with distortion
    pass = cal.leave_each_out(excluded, screen);
  }
  const int steps = std::min(options.max_outliers, n_fit - (min_fit_points(screen) + 2));
  std::vector<int> aside;
  for (int k = 0; k < steps; ++k) {
    int best = -1;
    for (int m = 0; m < n_markers; ++m)
      if (std::isfinite(pass.refit_rms_px[m]) && (best < 0 || pass.refit_rms_px[m] < pass.refit_rms_px[best]))
        best = m;
    if (best < 0) break;
    excluded[best] = 1;
    Calibrator::Pass next = cal.leave_each_out(excluded, screen);
    if (!next.ok) break;
    aside.push_back(best);
    pass = std::move(next);
  }
  // ... then test each against the leave-one-out residuals of those kept,
  // with all set-aside markers out of every fit.
  std::vector<double> kept;
  for (int m = 0; m < n_markers; ++m)
    if (!markers[m].is_check && !excluded[m] && std::isfinite(pass.residual_m[m])) kept.push_back(pass.residual_m[m]);
  if (kept.size() < 2) return;
  result.outlier_baseline_m = median(kept);
  std::sort(aside.begin(), aside.end());  // frame order
  for (int m : aside) {
    const Eigen::Vector3d error = cal.error_of(m, pass.base);
    if (!error.allFinite()) continue;
    const double e = error.norm();
    if (e > options.outlier_ratio * result.outlier_baseline_m && e > options.min_outlier_m) {
      result.outliers.push_back(markers[m].id);
      result.outlier_error_m.push_back(e);
    }
  }
}

}  // namespace

void DltOptions::validate() const {
  constexpr std::string_view w = "calibration options";
  check::int_in_range(w, "dlt.radial_terms", radial_terms, 0, 3);
  if (fit_distortion && radial_terms == 0 && !tangential)
    throw Error("calibration options: dlt.fit_distortion with dlt.radial_terms = 0 and dlt.tangential = false "
                "(no distortion term to fit)");
}

void CalibrationOptions::validate() const {
  constexpr std::string_view w = "calibration options";
  dlt.validate();
  if (!(std::isfinite(outlier_ratio) && outlier_ratio > 1.0))
    throw Error(fmt::format("calibration options: outlier_ratio = {} (must be a finite number above 1: an "
                            "outlier's error is that many times the median)",
                            outlier_ratio));
  check::non_negative(w, "min_outlier_m", min_outlier_m);
  check::at_least(w, "max_outliers", max_outliers, 0);
}

CalibrationResult calibrate(const std::vector<Marker>& markers, const std::vector<CameraView>& views,
                            const CalibrationOptions& options) {
  options.validate();
  if (views.size() < 2)
    throw Error(fmt::format("calibration needs two or more cameras to reconstruct points; {} given", views.size()));
  Calibrator cal(markers, views);
  CalibrationResult result;
  std::vector<Camera> cameras;
  const std::vector<char> none(cal.n_markers(), 0);
  for (int c = 0; c < cal.n_cameras(); ++c) {
    result.cameras.push_back(cal.fit_camera(c, none, options.dlt));
    cameras.push_back(result.cameras.back().camera);
  }
  check_marker_errors(cal, markers, cameras, result);
  if (!options.leave_one_out) return result;
  leave_one_out_and_outliers(cal, markers, options, result);
  return result;
}

std::string CalibrationResult::model() const {
  for (const auto& c : cameras)
    if (c.camera.has_distortion()) return "dlt16";
  return "dlt11";
}

std::string CalibrationResult::report() const {
  std::string out = fmt::format("calibration ({}), {} cameras\n", model(), cameras.size());
  for (const auto& c : cameras) {
    if (c.n_fit_points == 0)  // given coefficients (given_calibration)
      out += std::isnan(c.fit_rms_px)
                 ? fmt::format("  {}: coefficients given, no frame markers seen", label_of(c.camera.name))
                 : fmt::format("  {}: coefficients given, reprojection RMS {:.2f} px on the frame markers",
                               label_of(c.camera.name), c.fit_rms_px);
    else
      out += fmt::format("  {}: {} fit markers, reprojection RMS {:.2f} px", label_of(c.camera.name),
                         c.n_fit_points, c.fit_rms_px);
    if (c.camera.has_distortion())
      out += fmt::format(", k1 {:.4f} k2 {:.4f} p1 {:.5f} p2 {:.5f} k3 {:.4f}", c.camera.distortion[0],
                         c.camera.distortion[1], c.camera.distortion[2], c.camera.distortion[3],
                         c.camera.distortion[4]);
    out += "\n";
  }
  if (check_points.empty()) {
    out += check_unseen.empty() ? "  check markers: none, so the accuracy was not checked\n"
                                : "  check markers: none reconstructed\n";
  } else {
    out += fmt::format("  check markers: {} reconstructed, RMS x {} y {} z {} mm, max {} mm\n", check_points.size(),
                       mm(check_rms_m.x()), mm(check_rms_m.y()), mm(check_rms_m.z()), mm(check_max_m));
  }
  if (!check_unseen.empty())
    out += fmt::format("  check markers seen by fewer than two cameras: {}\n", fmt::join(check_unseen, ", "));
  std::vector<double> loo;
  const LeaveOneOut* worst = nullptr;
  for (const auto& l : leave_one_out) {
    if (!std::isfinite(l.residual_m)) continue;
    loo.push_back(l.residual_m);
    if (worst == nullptr || l.residual_m > worst->residual_m) worst = &l;
  }
  if (worst != nullptr)
    out += fmt::format("  leave-one-out: median {} mm, max {} mm ({})\n", mm(median(loo)), mm(worst->residual_m),
                       worst->id);
  if (!leave_one_out.empty()) {
    if (outliers.empty()) out += "  outliers: none\n";
    for (std::size_t i = 0; i < outliers.size(); ++i)
      out += fmt::format("  outlier: {}, {} mm from the fits without the outliers ({:.0f} x the median {} mm)\n",
                         outliers[i], mm(outlier_error_m[i]), outlier_error_m[i] / outlier_baseline_m,
                         mm(outlier_baseline_m));
  }
  return out;
}

CalibrationResult given_calibration(const std::vector<Camera>& cameras, const std::vector<Marker>& markers,
                                    const std::vector<CameraView>& views) {
  const int n_cameras = static_cast<int>(cameras.size());
  if (n_cameras < 2)
    throw Error(fmt::format("calibration needs two or more cameras to reconstruct points; {} given", n_cameras));
  if (!views.empty() && static_cast<int>(views.size()) != n_cameras)
    throw Error(fmt::format("{} camera views for {} cameras", views.size(), n_cameras));
  const int n_markers = static_cast<int>(markers.size());
  std::unordered_map<std::string, int> index;
  for (int m = 0; m < n_markers; ++m)
    if (!index.emplace(markers[m].id, m).second)
      throw Error(fmt::format("calibration marker '{}' is listed twice", markers[m].id));
  std::vector<std::vector<Eigen::Vector2d>> seen(
      n_cameras, std::vector<Eigen::Vector2d>(n_markers, Eigen::Vector2d::Constant(kNaN)));
  for (int c = 0; c < static_cast<int>(views.size()); ++c) {
    for (const auto& [id, px] : views[c].observations) {
      const auto it = index.find(id);
      if (it == index.end())
        throw Error(fmt::format("{}: observes marker '{}', which the calibration frame does not list",
                                label_of(views[c].name), id));
      if (px.allFinite()) seen[c][it->second] = px;
    }
  }
  CalibrationResult result;
  for (int c = 0; c < n_cameras; ++c) {
    DltFit fit;
    fit.camera = cameras[c];
    double sum_sq = 0.0;
    int n = 0;
    for (int m = 0; m < n_markers; ++m) {
      if (!seen[c][m].allFinite()) continue;
      sum_sq += (seen[c][m] - cameras[c].project(markers[m].lab_m)).squaredNorm();
      ++n;
    }
    fit.fit_rms_px = n > 0 ? std::sqrt(sum_sq / n) : kNaN;
    result.cameras.push_back(std::move(fit));
  }
  std::vector<Eigen::Vector2d> px(n_cameras);
  Eigen::Vector3d sum_sq = Eigen::Vector3d::Zero();
  for (int m = 0; m < n_markers; ++m) {
    if (!markers[m].is_check) continue;
    int n_seeing = 0;
    for (int c = 0; c < n_cameras; ++c) {
      px[c] = seen[c][m];
      n_seeing += px[c].allFinite() ? 1 : 0;
    }
    const Eigen::Vector3d error = triangulate(cameras, px, true).lab_m - markers[m].lab_m;
    if (!error.allFinite()) {
      result.check_unseen.push_back(markers[m].id);
      continue;
    }
    add_check_point(result, markers[m].id, error, n_seeing, sum_sq);
  }
  finish_check(result, sum_sq);
  return result;
}

}  // namespace dropfit::calibration

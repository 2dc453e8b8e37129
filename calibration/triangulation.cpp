#include "calibration/triangulation.h"

#include <array>
#include <cassert>
#include <cmath>
#include <limits>
#include <vector>

namespace dropfit::calibration {
namespace {

// The views of one point that a solve uses: the camera, its projection
// matrix, the measured pixel and the pixel with the distortion removed.
struct View {
  const Camera* camera;
  Matrix34d image_from_lab;
  Eigen::Vector2d measured_px;
  Eigen::Vector2d ideal_px;
};

// Solves the symmetric 3 x 3 system A x = b by its cofactors (Cramer's
// rule), several times faster than a general factorisation at this size.
// False when det(A) is not above `min_det`.
bool solve_symmetric3(const Eigen::Matrix3d& A, const Eigen::Vector3d& b, double min_det, Eigen::Vector3d* x) {
  const double c00 = A(1, 1) * A(2, 2) - A(1, 2) * A(1, 2);
  const double c01 = A(0, 2) * A(1, 2) - A(0, 1) * A(2, 2);
  const double c02 = A(0, 1) * A(1, 2) - A(0, 2) * A(1, 1);
  const double det = A(0, 0) * c00 + A(0, 1) * c01 + A(0, 2) * c02;
  if (!(det > min_det)) return false;
  const double c11 = A(0, 0) * A(2, 2) - A(0, 2) * A(0, 2);
  const double c12 = A(0, 1) * A(0, 2) - A(0, 0) * A(1, 2);
  const double c22 = A(0, 0) * A(1, 1) - A(0, 1) * A(0, 1);
  *x = Eigen::Vector3d(c00 * b(0) + c01 * b(1) + c02 * b(2), c01 * b(0) + c11 * b(1) + c12 * b(2),
                       c02 * b(0) + c12 * b(1) + c22 * b(2)) /
       det;
  return x->allFinite();
}

// Linear least squares over the views (header comment, step 2). False when
// the normal matrix is (nearly) singular: rays (nearly) parallel.
bool intersect(const View* views, int n, Eigen::Vector3d* lab_m) {
  Eigen::Matrix3d M = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  for (int i = 0; i < n; ++i) {
    const Matrix34d& P = views[i].image_from_lab;
    const Eigen::RowVector4d a_u = P.row(0) - views[i].ideal_px.x() * P.row(2);
    const Eigen::RowVector4d a_v = P.row(1) - views[i].ideal_px.y() * P.row(2);
    M.noalias() += a_u.head<3>().transpose() * a_u.head<3>() + a_v.head<3>().transpose() * a_v.head<3>();
    b.noalias() -= a_u.head<3>().transpose() * a_u(3) + a_v.head<3>().transpose() * a_v(3);
  }
  // det(M) / (trace(M) / 3)^3 ~ the ratio of the smallest eigenvalue to the
  // others, about the squared angle between the rays: 1e-10 is 1e-5 rad.
  const double t = M.trace() / 3.0;
  return t > 0.0 && solve_symmetric3(M, b, 1e-10 * t * t * t, lab_m);
}

// Gauss-Newton on the reprojection error (header comment, step 3):
//   r_i = pi(P_i [X; 1]) - x_i,  pi(h) = (h0, h1) / h2
//   dr_i/dX = (P_i[0:2, 0:3] - pi P_i[2, 0:3]) / h2
// One pass over the views per step; a step that raised the sum of squares
// is undone and ends the iteration.
void refine_point(const View* views, int n, Eigen::Vector3d* lab_m) {
  Eigen::Vector3d X = *lab_m, previous = X;
  double previous_cost = std::numeric_limits<double>::infinity();
  for (int iteration = 0; iteration < 10; ++iteration) {
    Eigen::Matrix3d JtJ = Eigen::Matrix3d::Zero();
    Eigen::Vector3d Jtr = Eigen::Vector3d::Zero();
    double cost = 0.0;
    for (int i = 0; i < n; ++i) {
      const Matrix34d& P = views[i].image_from_lab;
      const Eigen::Vector3d h = P.leftCols<3>() * X + P.col(3);
      const Eigen::Vector2d projected = h.head<2>() / h.z();
      const Eigen::Vector2d r = projected - views[i].ideal_px;
      const Eigen::Matrix<double, 2, 3> J = (P.topLeftCorner<2, 3>() - projected * P.row(2).head<3>()) / h.z();
      JtJ.noalias() += J.transpose() * J;
      Jtr.noalias() += J.transpose() * r;
      cost += r.squaredNorm();
    }
    if (!(cost <= previous_cost)) {  // worse (or not finite): keep the previous point
      X = previous;
      break;
    }
    Eigen::Vector3d step;
    if (!solve_symmetric3(JtJ, Jtr, 0.0, &step)) break;
    previous = X;
    previous_cost = cost;
    X -= step;
    if (step.squaredNorm() < 1e-14) break;  // below 1e-7 m
  }
  *lab_m = X;
}

Triangulation solve(View* views, int n, bool refine) {
  Triangulation t;
  t.n_cameras = n;
  if (n < 2) return t;
  Eigen::Vector3d X;
  if (!intersect(views, n, &X)) return t;
  if (refine) refine_point(views, n, &X);
  double sum_sq = 0.0;
  for (int i = 0; i < n; ++i) {
    Eigen::Vector2d projected;
    if (views[i].camera->has_distortion()) {
      projected = views[i].camera->project(X);
    } else {
      const Eigen::Vector3d h = views[i].image_from_lab.leftCols<3>() * X + views[i].image_from_lab.col(3);
      projected = h.head<2>() / h.z();
    }
    sum_sq += (views[i].measured_px - projected).squaredNorm();
  }
  t.lab_m = X;
  t.residual_px = std::sqrt(sum_sq / n);
  return t;
}

}  // namespace

Triangulation triangulate(std::span<const Camera> cameras, std::span<const Eigen::Vector2d> image_px,
                          bool refine) {
  assert(cameras.size() == image_px.size());
  constexpr std::size_t kOnStack = 16;
  std::array<View, kOnStack> on_stack;
  std::vector<View> on_heap;
  View* views = on_stack.data();
  if (cameras.size() > kOnStack) {
    on_heap.resize(cameras.size());
    views = on_heap.data();
  }
  int n = 0;
  for (std::size_t c = 0; c < cameras.size(); ++c) {
    if (!image_px[c].allFinite()) continue;
    View& v = views[n];
    v.camera = &cameras[c];
    v.measured_px = image_px[c];
    v.ideal_px = cameras[c].undistort(image_px[c]);
    if (!v.ideal_px.allFinite()) continue;  // beyond the distortion model's fold
    v.image_from_lab = cameras[c].image_from_lab();
    ++n;
  }
  return solve(views, n, refine);
}

}  // namespace dropfit::calibration

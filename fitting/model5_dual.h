#pragma once
// The small arithmetic types Model 5's integrator runs on: a 3 x 3 matrix of
// any scalar and a forward-mode dual number.
#include <cmath>

namespace dropfit::fitting::model5_detail {

// A 3 x 3 matrix of any scalar (no Eigen traits needed).
template <typename T>
struct Small3 {
  T m[9];
  T& operator()(int r, int c) { return m[3 * r + c]; }
  const T& operator()(int r, int c) const { return m[3 * r + c]; }
};

// Forward-mode dual number with N derivatives: what simulate_model5_t runs
// on for a ceres::Jet<double, N> (the same arithmetic as the Jet, in plain
// arrays the compiler inlines; Eigen's 8-vectors behind the Jet were not
// inlined here and cost 4x more).
template <int N>
struct Dual {
  double a = 0.0;
  double v[N] = {};
  Dual() = default;
  explicit Dual(double x) : a(x) {}
  Dual& operator+=(const Dual& o) {
    a += o.a;
    for (int i = 0; i < N; ++i) v[i] += o.v[i];
    return *this;
  }
  Dual& operator-=(const Dual& o) {
    a -= o.a;
    for (int i = 0; i < N; ++i) v[i] -= o.v[i];
    return *this;
  }
  Dual& operator*=(const Dual& o) {
    for (int i = 0; i < N; ++i) v[i] = v[i] * o.a + a * o.v[i];
    a *= o.a;
    return *this;
  }
  Dual& operator*=(double s) {
    a *= s;
    for (int i = 0; i < N; ++i) v[i] *= s;
    return *this;
  }
};
template <int N>
inline Dual<N> operator+(Dual<N> x, const Dual<N>& y) { return x += y; }
template <int N>
inline Dual<N> operator-(Dual<N> x, const Dual<N>& y) { return x -= y; }
template <int N>
inline Dual<N> operator-(Dual<N> x) {
  x.a = -x.a;
  for (int i = 0; i < N; ++i) x.v[i] = -x.v[i];
  return x;
}
template <int N>
inline Dual<N> operator*(Dual<N> x, const Dual<N>& y) { return x *= y; }
template <int N>
inline Dual<N> operator*(Dual<N> x, double s) { return x *= s; }
template <int N>
inline Dual<N> operator*(double s, Dual<N> x) { return x *= s; }
template <int N>
inline Dual<N> operator+(Dual<N> x, double s) {
  x.a += s;
  return x;
}
template <int N>
inline Dual<N> operator+(double s, Dual<N> x) {
  x.a += s;
  return x;
}
template <int N>
inline Dual<N> operator-(Dual<N> x, double s) {
  x.a -= s;
  return x;
}
template <int N>
inline Dual<N> operator-(double s, const Dual<N>& x) {
  Dual<N> r = -x;
  r.a += s;
  return r;
}
template <int N>
inline Dual<N> operator/(const Dual<N>& x, const Dual<N>& y) {
  const double inv = 1.0 / y.a;
  Dual<N> r;
  r.a = x.a * inv;
  for (int i = 0; i < N; ++i) r.v[i] = (x.v[i] - r.a * y.v[i]) * inv;
  return r;
}
template <int N>
inline Dual<N> operator/(const Dual<N>& x, double s) { return x * (1.0 / s); }
template <int N>
inline Dual<N> operator/(double s, const Dual<N>& y) { return Dual<N>(s) / y; }
template <int N>
inline Dual<N> exp(const Dual<N>& x) {
  const double e = std::exp(x.a);
  Dual<N> r = x * e;
  r.a = e;
  return r;
}

}  // namespace dropfit::fitting::model5_detail

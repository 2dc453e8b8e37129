// Residual analysis; the methods and their sources are in structure.h.
#include "diagnosis/structure.h"

#include <fmt/format.h>

#include <Eigen/Dense>
#include <algorithm>
#include <boost/math/distributions/chi_squared.hpp>
#include <boost/math/distributions/fisher_f.hpp>
#include <bit>
#include <cassert>
#include <cmath>
#include <complex>
#include <numbers>
#include <unsupported/Eigen/FFT>

#include "core/error.h"
#include "core/validate.h"
#include "diagnosis/internal.h"

namespace dropfit::diagnosis {
namespace {

Eigen::VectorXd concatenate(const std::vector<Eigen::VectorXd>& segments) {
  Eigen::Index n = 0;
  for (const auto& s : segments) n += s.size();
  Eigen::VectorXd out(n);
  Eigen::Index at = 0;
  for (const auto& s : segments) {
    out.segment(at, s.size()) = s;
    at += s.size();
  }
  return out;
}

std::vector<Eigen::VectorXd> split_like(const Eigen::VectorXd& all, const std::vector<Eigen::VectorXd>& segments) {
  std::vector<Eigen::VectorXd> out;
  Eigen::Index at = 0;
  for (const auto& s : segments) {
    out.push_back(all.segment(at, s.size()));
    at += s.size();
  }
  return out;
}

void require_finite(const Eigen::MatrixXd& m, const char* what) {
  if (!m.allFinite()) throw Error(fmt::format("residual analysis: {} has non-finite values", what));
}

// Column centring and scaling shared by linear_fit and stlsq.
struct Scaled {
  Eigen::MatrixXd z;           // active columns, centred, unit RMS
  std::vector<int> active;     // original index of each z column
  Eigen::VectorXd mean, rms;   // per original column
};

Scaled scale_columns(const Eigen::MatrixXd& columns) {
  const Eigen::Index n = columns.rows();
  Scaled s;
  s.mean = columns.colwise().mean().transpose();
  s.rms = Eigen::VectorXd::Zero(columns.cols());
  for (Eigen::Index j = 0; j < columns.cols(); ++j) {
    const double scale = columns.col(j).cwiseAbs().maxCoeff();
    const double rms = std::sqrt((columns.col(j).array() - s.mean(j)).square().sum() / std::max<Eigen::Index>(n, 1));
    s.rms(j) = rms;
    if (n > 0 && rms > 1e-12 * std::max(scale, 1e-300)) s.active.push_back(static_cast<int>(j));
  }
  s.z.resize(n, static_cast<Eigen::Index>(s.active.size()));
  for (std::size_t a = 0; a < s.active.size(); ++a) {
    const int j = s.active[a];
    s.z.col(static_cast<Eigen::Index>(a)) = (columns.col(j).array() - s.mean(j)) / s.rms(j);
  }
  return s;
}

// Least squares of yc (centred) on the scaled columns listed in `use`
// (indices into s.z), ridge relative to the unit diagonal.
Eigen::VectorXd solve_scaled(const Scaled& s, const std::vector<int>& use, const Eigen::VectorXd& yc, double ridge) {
  const Eigen::Index n = s.z.rows();
  const auto q = static_cast<Eigen::Index>(use.size());
  if (q == 0) return {};
  Eigen::MatrixXd a(ridge > 0.0 ? n + q : n, q);
  for (Eigen::Index c = 0; c < q; ++c) a.col(c).head(n) = s.z.col(use[static_cast<std::size_t>(c)]);
  Eigen::VectorXd b = Eigen::VectorXd::Zero(a.rows());
  b.head(n) = yc;
  if (ridge > 0.0) {
    a.bottomRows(q).setZero();
    a.bottomRows(q).diagonal().setConstant(std::sqrt(ridge * static_cast<double>(n)));
    return a.colPivHouseholderQr().solve(b);
  }
  return a.completeOrthogonalDecomposition().solve(b);
}

double rss_of(const Scaled& s, const std::vector<int>& use, const Eigen::VectorXd& yc, const Eigen::VectorXd& beta) {
  Eigen::VectorXd r = yc;
  for (std::size_t c = 0; c < use.size(); ++c) r -= beta(static_cast<Eigen::Index>(c)) * s.z.col(use[c]);
  return r.squaredNorm();
}

double r2_of(const Scaled& s, const std::vector<int>& use, const Eigen::VectorXd& yc) {
  const double tss = yc.squaredNorm();
  if (tss <= 0.0 || use.empty()) return 0.0;
  const Eigen::VectorXd beta = solve_scaled(s, use, yc, 0.0);
  return 1.0 - rss_of(s, use, yc, beta) / tss;
}

// Continuous periodogram |sum e_t exp(-2 pi i f t dt)|^2.
double periodogram_at(const Eigen::VectorXd& e, double dt_s, double f_hz) {
  const double w = 2.0 * std::numbers::pi * f_hz * dt_s;
  // Rotating phasor: exact enough for the few thousand samples used here.
  const std::complex<double> step(std::cos(w), -std::sin(w));
  std::complex<double> phase(1.0, 0.0), sum(0.0, 0.0);
  for (Eigen::Index t = 0; t < e.size(); ++t) {
    sum += e(t) * phase;
    phase *= step;
    if ((t & 255) == 255) phase = std::polar(1.0, -w * static_cast<double>(t + 1));
  }
  return std::norm(sum);
}

// The maximum of f over [lo, hi] by golden-section search (f unimodal there).
template <class F>
double golden_section_max(F f, double lo, double hi, int iterations) {
  const double phi = 0.5 * (std::sqrt(5.0) - 1.0);
  double x1 = hi - phi * (hi - lo), x2 = lo + phi * (hi - lo);
  double f1 = f(x1), f2 = f(x2);
  for (int iter = 0; iter < iterations; ++iter) {
    if (f1 < f2) {
      lo = x1;
      x1 = x2;
      f1 = f2;
      x2 = lo + phi * (hi - lo);
      f2 = f(x2);
    } else {
      hi = x2;
      x2 = x1;
      f2 = f1;
      x1 = hi - phi * (hi - lo);
      f1 = f(x1);
    }
  }
  return 0.5 * (lo + hi);
}

// Least-squares sinusoid (cosine and sine columns, with an intercept) of
// frequency f_hz fitted to e, sampled dt_s apart.
LinearFit sinusoid_fit(const Eigen::VectorXd& e, double dt_s, double f_hz) {
  Eigen::MatrixXd cs(e.size(), 2);
  for (Eigen::Index t = 0; t < e.size(); ++t) {
    const double w = 2.0 * std::numbers::pi * f_hz * dt_s * static_cast<double>(t);
    cs(t, 0) = std::cos(w);
    cs(t, 1) = std::sin(w);
  }
  return linear_fit(cs, e);
}

// Removes the least-squares line (a trend is not a period).
Eigen::VectorXd detrend(const Eigen::VectorXd& y) {
  const Eigen::Index n = y.size();
  Eigen::MatrixXd ramp(n, 1);
  for (Eigen::Index i = 0; i < n; ++i) ramp(i, 0) = static_cast<double>(i);
  return project_out(ramp, y, true);
}

}  // namespace

std::vector<Candidate> state_candidates(const Eigen::VectorXd& t_s, const Eigen::VectorXd& x_m,
                                        const Eigen::VectorXd& xdot_m_s) {
  if (t_s.size() != x_m.size() || x_m.size() != xdot_m_s.size())
    throw Error(fmt::format("state_candidates: t, x and xdot differ in length ({}, {}, {})", t_s.size(), x_m.size(),
                            xdot_m_s.size()));
  const Eigen::ArrayXd x = x_m.array(), v = xdot_m_s.array();
  const Eigen::ArrayXd unloading = (v < 0.0).cast<double>();
  const Eigen::ArrayXd sign = (v > 0.0).cast<double>() - unloading;
  // The loading/unloading indicator itself is sign(xdot) up to the
  // intercept, so it enters only through its products with x and xdot.
  std::vector<Candidate> c;
  c.push_back({"x", "deformation", x.matrix()});
  c.push_back({"xdot", "deformation rate", v.matrix()});
  c.push_back({"sign(xdot)", "the sign of the deformation rate", sign.matrix()});
  c.push_back({"x xdot", "deformation times its rate", (x * v).matrix()});
  c.push_back({"x^2", "deformation squared", x.square().matrix()});
  c.push_back({"x^3", "deformation cubed", x.cube().matrix()});
  c.push_back({"x unloading", "the deformation while unloading", (x * unloading).matrix()});
  c.push_back({"xdot unloading", "the deformation rate while unloading", (v * unloading).matrix()});
  c.push_back({"t", "time", t_s});
  return c;
}

double correlation(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  assert(a.size() == b.size());
  if (a.size() < 2) return 0.0;
  const Eigen::ArrayXd ac = a.array() - a.mean(), bc = b.array() - b.mean();
  const double saa = ac.square().sum(), sbb = bc.square().sum();
  if (saa <= 0.0 || sbb <= 0.0) return 0.0;
  return std::clamp((ac * bc).sum() / std::sqrt(saa * sbb), -1.0, 1.0);
}

Eigen::VectorXd project_out(const Eigen::MatrixXd& basis, const Eigen::VectorXd& y, bool with_constant) {
  if (basis.cols() > 0 && basis.rows() != y.size())
    throw Error(fmt::format("project_out: basis has {} rows, residual {}", basis.rows(), y.size()));
  const Eigen::Index q = basis.cols() + (with_constant ? 1 : 0);
  if (q == 0 || y.size() == 0) return y;
  Eigen::MatrixXd a(y.size(), q);
  if (basis.cols() > 0) a.leftCols(basis.cols()) = basis;
  if (with_constant) a.col(q - 1).setOnes();
  // Scale columns for conditioning.
  for (Eigen::Index j = 0; j < q; ++j) {
    const double norm = a.col(j).norm();
    if (norm > 0.0) a.col(j) /= norm;
  }
  const Eigen::VectorXd beta = a.completeOrthogonalDecomposition().solve(y);
  return y - a * beta;
}

LinearFit linear_fit(const Eigen::MatrixXd& columns, const Eigen::VectorXd& y, double ridge) {
  if (columns.rows() != y.size())
    throw Error(fmt::format("linear_fit: {} rows of columns for {} residuals", columns.rows(), y.size()));
  require_finite(columns, "a candidate column");
  require_finite(y, "the residual");
  const Scaled s = scale_columns(columns);
  const double ymean = y.size() > 0 ? y.mean() : 0.0;
  const Eigen::VectorXd yc = y.array() - ymean;
  std::vector<int> use(s.active.size());
  for (std::size_t a = 0; a < use.size(); ++a) use[a] = static_cast<int>(a);
  LinearFit fit;
  fit.coefficients = Eigen::VectorXd::Zero(columns.cols());
  const Eigen::VectorXd beta = solve_scaled(s, use, yc, std::max(ridge, 0.0));
  fit.intercept = ymean;
  for (std::size_t a = 0; a < use.size(); ++a) {
    const int j = s.active[a];
    fit.coefficients(j) = beta(static_cast<Eigen::Index>(a)) / s.rms(j);
    fit.intercept -= fit.coefficients(j) * s.mean(j);
  }
  fit.rss = use.empty() ? yc.squaredNorm() : rss_of(s, use, yc, beta);
  const double tss = yc.squaredNorm();
  fit.r2 = tss > 0.0 ? 1.0 - fit.rss / tss : 0.0;
  return fit;
}

void SparseOptions::validate() const {
  constexpr std::string_view w = "structure options";
  check::non_negative(w, "sparse.threshold", threshold);
  check::non_negative(w, "sparse.ridge", ridge);
  check::at_least(w, "sparse.max_iterations", max_iterations, 1);
  check::in_range(w, "sparse.min_unique_share", min_unique_share, 0.0, 1.0);
  check::at_least(w, "sparse.max_exhaustive_columns", max_exhaustive_columns, 0);
}

void StructureOptions::validate() const {
  constexpr std::string_view w = "structure options";
  check::at_least(w, "max_lag", max_lag, 0);
  check::at_least(w, "fitted_parameters", fitted_parameters, 0);
  if (!(alpha > 0.0 && alpha < 1.0))
    throw Error(fmt::format("structure options: alpha = {} (a significance level: above 0 and below 1)", alpha));
  sparse.validate();
  check::in_range(w, "min_share", min_share, 0.0, 1.0);
  check::non_negative(w, "dt_s (0: no periodogram)", dt_s);
  check::non_negative(w, "min_frequency_hz", min_frequency_hz);
}

SparseFit stlsq(const Eigen::MatrixXd& columns, const Eigen::VectorXd& y, const SparseOptions& options) {
  options.validate();
  if (columns.rows() != y.size())
    throw Error(fmt::format("stlsq: {} rows of columns for {} residuals", columns.rows(), y.size()));
  require_finite(columns, "a candidate column");
  require_finite(y, "the residual");
  const Scaled s = scale_columns(columns);
  const double ymean = y.size() > 0 ? y.mean() : 0.0;
  const Eigen::VectorXd yc = y.array() - ymean;
  const double yrms = y.size() > 0 ? std::sqrt(yc.squaredNorm() / static_cast<double>(y.size())) : 0.0;

  SparseFit out;
  out.coefficients = Eigen::VectorXd::Zero(columns.cols());
  out.intercept = ymean;
  if (yrms <= 0.0 || s.active.empty()) return out;

  // Support as indices into s.z.
  std::vector<int> support(s.active.size());
  for (std::size_t a = 0; a < support.size(); ++a) support[a] = static_cast<int>(a);
  for (int it = 0; it < options.max_iterations && !support.empty(); ++it) {
    out.iterations = it + 1;
    const Eigen::VectorXd beta = solve_scaled(s, support, yc, options.ridge);
    std::vector<int> kept;
    for (std::size_t c = 0; c < support.size(); ++c)
      if (std::abs(beta(static_cast<Eigen::Index>(c))) / yrms >= options.threshold) kept.push_back(support[c]);
    if (kept == support) break;
    support = std::move(kept);
  }

  // Backward elimination of survivors that add (almost) nothing.
  while (!support.empty()) {
    const double full = r2_of(s, support, yc);
    double least_loss = std::numeric_limits<double>::infinity();
    std::size_t least = 0;
    for (std::size_t c = 0; c < support.size(); ++c) {
      std::vector<int> without = support;
      without.erase(without.begin() + static_cast<std::ptrdiff_t>(c));
      const double loss = full - r2_of(s, without, yc);
      if (loss < least_loss) {
        least_loss = loss;
        least = c;
      }
    }
    if (least_loss >= options.min_unique_share) break;
    support.erase(support.begin() + static_cast<std::ptrdiff_t>(least));
  }

  // Subset check: thresholding and greedy elimination are path dependent on
  // nearly collinear libraries, so for small libraries the smallest subset
  // that explains as much (within min_unique_share per term dropped) is
  // searched for exhaustively; it replaces the STLSQ support when smaller or
  // better at the same size.
  const int p = static_cast<int>(s.active.size());
  if (p <= options.max_exhaustive_columns && !support.empty()) {
    const double target = r2_of(s, support, yc);
    const int k = static_cast<int>(support.size());
    bool replaced = false;
    for (int size = 0; size <= k && !replaced; ++size) {
      double best_r2 = -1.0;
      std::vector<int> best_set;
      for (unsigned mask = 0; mask < (1u << p); ++mask) {
        if (std::popcount(mask) != size) continue;
        std::vector<int> use;
        for (int j = 0; j < p; ++j)
          if (mask & (1u << j)) use.push_back(j);
        const double r2 = r2_of(s, use, yc);
        if (r2 > best_r2) {
          best_r2 = r2;
          best_set = std::move(use);
        }
      }
      const double allowed = target - options.min_unique_share * (k - size) - 1e-12;
      if (best_r2 >= allowed && (size < k || best_r2 > target)) {
        support = std::move(best_set);
        replaced = true;
      }
    }
  }

  if (!support.empty()) {
    const Eigen::VectorXd beta = solve_scaled(s, support, yc, 0.0);
    for (std::size_t c = 0; c < support.size(); ++c) {
      const int j = s.active[static_cast<std::size_t>(support[c])];
      out.coefficients(j) = beta(static_cast<Eigen::Index>(c)) / s.rms(j);
      out.intercept -= out.coefficients(j) * s.mean(j);
      out.support.push_back(j);
    }
    out.r2 = 1.0 - rss_of(s, support, yc, beta) / yc.squaredNorm();
  }
  std::sort(out.support.begin(), out.support.end());
  return out;
}

Eigen::VectorXd autocorrelation(const std::vector<Eigen::VectorXd>& segments, int max_lag) {
  const Eigen::VectorXd all = concatenate(segments);
  max_lag = std::max(max_lag, 0);
  Eigen::VectorXd acf = Eigen::VectorXd::Zero(max_lag);
  if (all.size() < 2) return acf;
  const double mean = all.mean();
  const double c0 = (all.array() - mean).square().sum();
  if (c0 <= 0.0) return acf;
  for (int k = 1; k <= max_lag; ++k) {
    double ck = 0.0;
    for (const auto& s : segments) {
      const Eigen::Index m = s.size() - k;
      if (m <= 0) continue;
      ck += ((s.head(m).array() - mean) * (s.tail(m).array() - mean)).sum();
    }
    acf(k - 1) = ck / c0;
  }
  return acf;
}

Eigen::VectorXd autocorrelation(const Eigen::VectorXd& residual, int max_lag) {
  return autocorrelation(std::vector<Eigen::VectorXd>{residual}, max_lag);
}

double chi_square_sf(double q, double dof) {
  if (!(dof > 0.0)) return kNaN;
  if (!(q > 0.0)) return 1.0;
  if (std::isinf(q)) return 0.0;
  return boost::math::cdf(boost::math::complement(boost::math::chi_squared_distribution<double>(dof), q));
}

Whiteness ljung_box(const std::vector<Eigen::VectorXd>& segments, int max_lag, int fitted_parameters, double alpha) {
  Eigen::Index n = 0;
  for (const auto& s : segments) n += s.size();
  Whiteness w;
  const int h = static_cast<int>(std::min<Eigen::Index>(std::max(max_lag, 1), std::max<Eigen::Index>(n / 4, 1)));
  w.acf = autocorrelation(segments, h);
  w.dof = std::max(1, h - fitted_parameters);
  if (n < 8) return w;  // too short to judge: white by default
  const double nd = static_cast<double>(n);
  double q = 0.0;
  for (int k = 1; k <= h; ++k) {
    double nk = 0.0;
    for (const auto& s : segments) nk += static_cast<double>(std::max<Eigen::Index>(s.size() - k, 0));
    if (nk > 0.0) q += w.acf(k - 1) * w.acf(k - 1) / nk;
  }
  w.q = nd * (nd + 2.0) * q;
  w.p_value = chi_square_sf(w.q, w.dof);
  w.white = w.p_value >= alpha;
  return w;
}

Whiteness ljung_box(const Eigen::VectorXd& residual, int max_lag, int fitted_parameters, double alpha) {
  return ljung_box(std::vector<Eigen::VectorXd>{residual}, max_lag, fitted_parameters, alpha);
}

PeriodicPeak periodogram_peak(const std::vector<Eigen::VectorXd>& segments, double dt_s, double alpha,
                              double min_frequency_hz) {
  if (!(dt_s > 0.0)) throw Error("periodogram_peak: the sample spacing must be positive");
  PeriodicPeak best;
  int tested = 0;
  struct Found {
    const Eigen::VectorXd* seg;
    int k;
    double g, p;
  };
  std::vector<Found> found;
  Eigen::FFT<double> fft;
  for (const auto& seg : segments) {
    const auto n = static_cast<int>(seg.size());
    if (n < 8 || !seg.allFinite()) continue;
    const int m = (n - 1) / 2;
    const Eigen::VectorXd detrended = detrend(seg);
    std::vector<double> e(detrended.data(), detrended.data() + n);
    std::vector<std::complex<double>> spectrum;
    fft.fwd(spectrum, e);
    const double df = 1.0 / (n * dt_s);
    double sum = 0.0, top = 0.0;
    int k_top = 0, m_used = 0;
    for (int k = 1; k <= m; ++k) {
      if (k * df < min_frequency_hz) continue;
      const double ik = std::norm(spectrum[static_cast<std::size_t>(k)]);
      sum += ik;
      ++m_used;
      if (ik > top) {
        top = ik;
        k_top = k;
      }
    }
    if (m_used < 2 || sum <= 0.0) continue;
    ++tested;
    const double g = top / sum;
    const double p = std::min(1.0, m_used * std::pow(1.0 - g, m_used - 1));
    found.push_back({&seg, k_top, g, p});
  }
  if (found.empty()) return best;
  const auto it = std::min_element(found.begin(), found.end(), [](const Found& a, const Found& b) { return a.p < b.p; });
  const Eigen::VectorXd e = detrend(*it->seg);
  const auto n = static_cast<double>(e.size());
  const double df = 1.0 / (n * dt_s);
  // The continuous maximum between the neighbours.
  const double lo = std::max((it->k - 1) * df, 1e-9 * df), hi = std::min((it->k + 1) * df, 0.5 / dt_s);
  double f = golden_section_max([&](double x) { return periodogram_at(e, dt_s, x); }, lo, hi, 40);
  if (periodogram_at(e, dt_s, it->k * df) > periodogram_at(e, dt_s, f)) f = it->k * df;
  const LinearFit fit = sinusoid_fit(e, dt_s, f);
  best.frequency_hz = f;
  best.amplitude = fit.coefficients.norm();
  best.share = fit.r2;
  best.g = it->g;
  best.p_value = std::min(1.0, it->p * tested);
  best.significant = best.p_value < alpha;
  return best;
}

PeriodicPeak common_periodic_peak(const std::vector<Eigen::VectorXd>& segments, double dt_s, double alpha,
                                  double min_frequency_hz) {
  if (!(dt_s > 0.0)) throw Error("common_periodic_peak: the sample spacing must be positive");
  struct Segment {
    Eigen::VectorXd e;
    double mean_ordinate;
  };
  std::vector<Segment> used;
  Eigen::FFT<double> fft;
  double finest_df = std::numeric_limits<double>::infinity(), total = 0.0;
  int longest_m = 0, shortest_m = std::numeric_limits<int>::max();
  for (const auto& seg : segments) {
    const auto n = static_cast<int>(seg.size());
    if (n < 8 || !seg.allFinite()) continue;
    const Eigen::VectorXd e = detrend(seg);
    std::vector<double> v(e.data(), e.data() + n);
    std::vector<std::complex<double>> spectrum;
    fft.fwd(spectrum, v);
    const double df = 1.0 / (n * dt_s);
    double sum = 0.0;
    int m_used = 0;
    for (int k = 1; k <= (n - 1) / 2; ++k) {
      if (k * df < min_frequency_hz) continue;
      sum += std::norm(spectrum[static_cast<std::size_t>(k)]);
      ++m_used;
    }
    if (m_used < 2 || sum <= 0.0) continue;
    used.push_back({e, sum / m_used});
    finest_df = std::min(finest_df, df);
    longest_m = std::max(longest_m, m_used);
    shortest_m = std::min(shortest_m, m_used);
    total += m_used;  // each segment's normalised ordinates sum to m_used
  }
  PeriodicPeak best;
  if (used.empty()) return best;
  auto summed = [&](double f) {
    double s = 0.0;
    for (const auto& u : used) s += periodogram_at(u.e, dt_s, f) / u.mean_ordinate;
    return s;
  };
  const double nyquist = 0.5 / dt_s, step = 0.25 * finest_df;
  double f_top = std::max(min_frequency_hz, step), s_top = -1.0;
  for (double f = std::max(min_frequency_hz, step); f < nyquist; f += step) {
    const double s = summed(f);
    if (s > s_top) {
      s_top = s;
      f_top = f;
    }
  }
  // The continuous maximum between the grid neighbours.
  double f = golden_section_max(summed, std::max(f_top - step, 1e-9), std::min(f_top + step, nyquist), 40);
  double s_best = summed(f);
  if (s_top > s_best) {
    f = f_top;
    s_best = s_top;
  }
  double rss = 0.0, tss = 0.0, amp2 = 0.0;
  for (const auto& u : used) {
    const LinearFit fit = sinusoid_fit(u.e, dt_s, f);
    tss += u.e.squaredNorm();  // detrended: about zero mean
    rss += fit.rss;
    amp2 += fit.coefficients.squaredNorm();
  }
  const auto s_count = static_cast<double>(used.size());
  best.frequency_hz = f;
  best.amplitude = std::sqrt(amp2 / s_count);
  best.share = tss > 0.0 ? 1.0 - rss / tss : 0.0;
  best.g = s_best / total;
  // Each ordinate over its segment's mean of m ordinates is about F(2, 2m);
  // their mean over S segments is taken as F(2S, 2m) with the shortest m.
  const boost::math::fisher_f_distribution<double> null_f(2.0 * s_count, 2.0 * shortest_m);
  best.p_value = std::min(1.0, 2.0 * longest_m * boost::math::cdf(boost::math::complement(null_f, s_best / s_count)));
  best.significant = best.p_value < alpha;
  return best;
}

PeriodicPeak periodogram_peak(const Eigen::VectorXd& residual, double dt_s, double alpha, double min_frequency_hz) {
  return periodogram_peak(std::vector<Eigen::VectorXd>{residual}, dt_s, alpha, min_frequency_hz);
}

InformationCriteria information_criteria(double rss, double n, int k) {
  InformationCriteria ic;
  ic.n = n;
  ic.k = k;
  if (!(n > 0.0)) return ic;
  const double ll = n * std::log(std::max(rss, 1e-300) / n);
  ic.aic = ll + 2.0 * k;
  ic.aicc = (n - k - 1.0) > 0.0 ? ic.aic + 2.0 * k * (k + 1.0) / (n - k - 1.0)
                                : std::numeric_limits<double>::infinity();
  ic.bic = ll + k * std::log(n);
  return ic;
}

double effective_sample_size(double n, double rho1) {
  if (!(n > 0.0)) return 0.0;
  const double rho = std::clamp(std::isfinite(rho1) ? rho1 : 0.0, 0.0, 0.999);
  return std::clamp(n * (1.0 - rho) / (1.0 + rho), std::min(n, 2.0), n);
}

std::string criterion_name(Criterion criterion) {
  switch (criterion) {
    case Criterion::AIC: return "AIC";
    case Criterion::AICc: return "AICc";
    case Criterion::BIC: return "BIC";
  }
  return "?";
}

ModelComparison compare_models(double rss_small, int k_small, double rss_large, int k_large, double n, double rho1,
                               Criterion criterion, double min_drop) {
  ModelComparison c;
  c.n_eff = effective_sample_size(n, rho1);
  // The likelihood term uses the per-sample variance RSS / n, weighted by
  // the effective number of independent samples.
  auto criteria = [&](double rss, int k) {
    InformationCriteria ic = information_criteria(rss / n * c.n_eff, c.n_eff, k);
    return ic;
  };
  c.smaller = criteria(rss_small, k_small);
  c.larger = criteria(rss_large, k_large);
  auto pick = [&](const InformationCriteria& ic) {
    switch (criterion) {
      case Criterion::AIC: return ic.aic;
      case Criterion::AICc: return ic.aicc;
      case Criterion::BIC: return ic.bic;
    }
    return kNaN;
  };
  const double a = pick(c.smaller), b = pick(c.larger);
  c.delta = (std::isinf(a) && std::isinf(b)) ? kNaN : b - a;
  c.larger_supported = std::isfinite(b) && c.delta < -min_drop;
  return c;
}

PairedImprovement paired_improvement(const Eigen::VectorXd& before, const Eigen::VectorXd& after, double t_critical,
                                     double min_relative, double min_absolute) {
  if (before.size() != after.size() || before.size() == 0)
    throw Error(fmt::format("paired_improvement: {} errors before, {} after", before.size(), after.size()));
  PairedImprovement p;
  const Eigen::VectorXd d = before - after;
  const auto n = static_cast<double>(d.size());
  p.mean_before = before.mean();
  p.mean_after = after.mean();
  p.mean_drop = d.mean();
  if (d.size() > 1) p.se = std::sqrt((d.array() - p.mean_drop).square().sum() / (n - 1.0) / n);
  if (p.se > 0.0)
    p.t = p.mean_drop / p.se;
  else
    p.t = p.mean_drop > 0.0 ? std::numeric_limits<double>::infinity() : 0.0;
  p.significant = p.mean_drop > 0.0 && p.t >= t_critical && p.mean_drop >= min_relative * std::abs(p.mean_before) &&
                  p.mean_drop > min_absolute;
  return p;
}

double log_paired_t(const std::vector<double>& before, const std::vector<double>& after) {
  std::vector<double> lb, la;
  for (std::size_t i = 0; i < before.size() && i < after.size(); ++i)
    if (before[i] > 0.0 && after[i] > 0.0) {
      lb.push_back(std::log(before[i]));
      la.push_back(std::log(after[i]));
    }
  if (lb.size() < 3) return std::numeric_limits<double>::quiet_NaN();
  return paired_improvement(detail::to_vector(lb), detail::to_vector(la), 0.0, 0.0, 0.0).t;
}

const TermScore* StructureReport::best() const {
  if (terms.empty() || terms.front().share_alone < min_share) return nullptr;
  return &terms.front();
}

const TermScore* StructureReport::find(const std::string& name) const {
  for (const auto& t : terms)
    if (t.name == name) return &t;
  return nullptr;
}

std::string StructureReport::summary() const {
  std::string s = structured ? "structured" : "white";
  s += fmt::format(": Ljung-Box Q = {:.1f} on {} lags (p = {:.2g}), rho1 = {:.2f}", whiteness.q, whiteness.dof,
                   whiteness.p_value, whiteness.rho1());
  if (const TermScore* b = best())
    s += fmt::format("; best term {} (r = {:.2f}, {:.0f} % alone)", b->name, b->r, 100.0 * b->share_alone);
  if (!sparse.support.empty()) {
    std::string names;
    for (const auto& t : terms)
      if (t.kept) names += (names.empty() ? "" : ", ") + t.name;
    s += fmt::format("; sparse fit {{{}}} explains {:.0f} %", names, 100.0 * explained_share);
  }
  if (peak.significant)
    s += fmt::format("; periodic at {:.3g} Hz ({:.0f} %, p = {:.2g})", peak.frequency_hz, 100.0 * peak.share,
                     peak.p_value);
  return s;
}

StructureReport analyse_residual(const std::vector<Eigen::VectorXd>& segments, const std::vector<Candidate>& candidates,
                                 const StructureOptions& options, const Eigen::MatrixXd& nuisance) {
  options.validate();
  const Eigen::VectorXd raw = concatenate(segments);
  const Eigen::Index n = raw.size();
  require_finite(raw, "the residual");
  for (const auto& c : candidates) {
    if (c.values.size() != n)
      throw Error(fmt::format("analyse_residual: candidate {} has {} values for {} residuals", c.name, c.values.size(),
                              n));
    require_finite(c.values, "a candidate column");
  }
  if (nuisance.cols() > 0 && nuisance.rows() != n)
    throw Error(fmt::format("analyse_residual: nuisance has {} rows for {} residuals", nuisance.rows(), n));

  if (options.centre_segments && nuisance.cols() > 0)
    throw Error("analyse_residual: centre_segments and nuisance columns together (give one)");
  const bool centre = options.centre_segments;
  const bool project = nuisance.cols() > 0 || centre;
  auto projected = [&](const Eigen::VectorXd& v) -> Eigen::VectorXd {
    if (!centre) return nuisance.cols() > 0 ? project_out(nuisance, v) : v;
    Eigen::VectorXd out = v;
    Eigen::Index at = 0;
    for (const auto& segment : segments) {
      auto part = out.segment(at, segment.size());
      if (part.size() > 0) part.array() -= part.mean();
      at += segment.size();
    }
    return out;
  };
  const Eigen::VectorXd e = projected(raw);
  Eigen::MatrixXd columns(n, static_cast<Eigen::Index>(candidates.size()));
  for (std::size_t j = 0; j < candidates.size(); ++j) {
    auto col = columns.col(static_cast<Eigen::Index>(j));
    col = projected(candidates[j].values);
    // A candidate the model already spans leaves only rounding noise: zero.
    const double before = (candidates[j].values.array() - candidates[j].values.mean()).matrix().norm();
    if (project && col.norm() <= 1e-9 * before) col.setZero();
  }

  StructureReport rep;
  rep.n = static_cast<int>(n);
  rep.min_share = options.min_share;
  const std::vector<Eigen::VectorXd> parts = split_like(e, segments);
  rep.whiteness = ljung_box(parts, options.max_lag, options.fitted_parameters, options.alpha);
  if (options.dt_s > 0.0) rep.peak = periodogram_peak(parts, options.dt_s, options.alpha, options.min_frequency_hz);

  rep.sparse = stlsq(columns, e, options.sparse);
  rep.explained_share = rep.sparse.r2;
  for (std::size_t j = 0; j < candidates.size(); ++j) {
    TermScore t;
    t.name = candidates[j].name;
    t.description = candidates[j].description;
    t.index = static_cast<int>(j);
    t.r = correlation(columns.col(static_cast<Eigen::Index>(j)), e);
    t.share_alone = t.r * t.r;
    t.kept = std::find(rep.sparse.support.begin(), rep.sparse.support.end(), static_cast<int>(j)) !=
             rep.sparse.support.end();
    t.coefficient = rep.sparse.coefficients(static_cast<Eigen::Index>(j));
    if (t.kept) {
      std::vector<int> others;
      for (int k : rep.sparse.support)
        if (k != static_cast<int>(j)) others.push_back(k);
      Eigen::MatrixXd sub(n, static_cast<Eigen::Index>(others.size()));
      for (std::size_t k = 0; k < others.size(); ++k) sub.col(static_cast<Eigen::Index>(k)) = columns.col(others[k]);
      t.share_unique = rep.sparse.r2 - (others.empty() ? 0.0 : linear_fit(sub, e).r2);
    }
    rep.terms.push_back(std::move(t));
  }
  std::stable_sort(rep.terms.begin(), rep.terms.end(),
                   [](const TermScore& a, const TermScore& b) { return a.share_alone > b.share_alone; });
  rep.structured = !rep.whiteness.white || rep.peak.significant ||
                   (!rep.terms.empty() && rep.terms.front().share_alone >= options.min_share);
  return rep;
}

StructureReport analyse_residual(const Eigen::VectorXd& residual, const std::vector<Candidate>& candidates,
                                 const StructureOptions& options, const Eigen::MatrixXd& nuisance) {
  return analyse_residual(std::vector<Eigen::VectorXd>{residual}, candidates, options, nuisance);
}

}  // namespace dropfit::diagnosis

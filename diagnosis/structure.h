#pragma once
// Residual analysis: is a stage's residual white noise, or does it carry
// structure that a named term would explain? Plain Eigen in and out, no I/O.
//
// Methods, each where it is used below:
//
// - Candidate regression. The residual is regressed on candidate columns
//   (for a mat: x, xdot, sign(xdot), x xdot, x^2, x^3, the unloading
//   indicator, time; for a camera: image radius, ...). Every column is
//   centred and scaled to unit RMS first, because raw polynomial columns are
//   badly conditioned, and a ridge term (Hoerl & Kennard, Technometrics 12
//   (1970) 55) keeps nearly collinear columns apart. Columns the model
//   already fits ("nuisance", e.g. a model's own sensitivities) are projected
//   out of the residual and of every candidate first (Frisch-Waugh-Lovell),
//   so that a candidate is credited only with what the model cannot absorb.
// - Sparse selection: SINDy's sequentially thresholded least squares
//   (Brunton, Proctor & Kutz, PNAS 113 (2016) 3932): ridge least squares,
//   zero the standardised coefficients below a threshold, refit on the
//   survivors, repeat until the support stops changing. Nearly collinear
//   columns (x^2 and x^3 over a half-sine) can both survive thresholding with
//   opposite large coefficients, so a backward-elimination pass follows:
//   the survivor whose removal costs the least explained variance is dropped
//   while that cost is below min_unique_share. For small libraries (up to
//   max_exhaustive_columns) the smallest subset explaining as much (within
//   min_unique_share per term fewer) is then found by exhaustive search and
//   replaces the support when it is smaller or, at the same size, better.
//   The final coefficients come from an unregularised fit on the kept terms.
// - Explained share: the R^2 of a term alone (its squared correlation with
//   the residual) and its unique share (the R^2 lost when it is removed from
//   the sparse fit).
// - Whiteness: the sample autocorrelation at lags 1..h and the Ljung-Box
//   statistic (Ljung & Box, Biometrika 65 (1978) 297),
//     Q = n (n + 2) sum_{k=1..h} rho_k^2 / (n - k),
//   chi-square with h - p degrees of freedom under white noise. Several
//   segments (trials) are pooled: products never straddle two segments.
// - Periodic structure: the periodogram's largest ordinate and Fisher's g
//   test (Fisher, Proc. R. Soc. A 125 (1929) 54), g = max I_k / sum I_k,
//   P(g > x) <= m (1 - x)^(m - 1) over m Fourier frequencies (the first,
//   dominant term of the exact series); the peak frequency is then refined
//   between the neighbouring bins by maximising the continuous periodogram.
// - Information criteria on N residuals with k parameters (Akaike, IEEE
//   TAC 19 (1974) 716; Hurvich & Tsai, Biometrika 76 (1989) 297; Schwarz,
//   Ann. Stat. 6 (1978) 461):
//     AIC = N ln(RSS/N) + 2k,  AICc = AIC + 2k(k+1)/(N-k-1),
//     BIC = N ln(RSS/N) + k ln N.
//   Residuals of a time series are correlated, so N overstates the
//   evidence; compare_models uses the AR(1) effective sample size
//   N_eff = N (1 - rho1) / (1 + rho1) (e.g. Bretherton et al., J. Climate 12
//   (1999) 1990) in place of N. Held-out error is the stronger test; the
//   diagnosis loop asks for both.
#include <Eigen/Core>
#include <limits>
#include <string>
#include <vector>

namespace dropfit::diagnosis {

inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// One candidate column of the regression library.
struct Candidate {
  std::string name;         // short symbol, e.g. "x^3"
  std::string description;  // words for evidence text, e.g. "deformation cubed"
  Eigen::VectorXd values;   // one value per residual sample
};

// The usual library for a one-dimensional mechanical state (SINDy-style):
// x, xdot, sign(xdot), x xdot, x^2, x^3, x and xdot while unloading
// (times the indicator xdot < 0; the indicator alone is sign(xdot) up to the
// intercept), and time. x in metres (deformation, positive
// compressed), xdot in m/s, t in s; all three the same length (throws
// dropfit::Error otherwise).
std::vector<Candidate> state_candidates(const Eigen::VectorXd& t_s, const Eigen::VectorXd& x_m,
                                        const Eigen::VectorXd& xdot_m_s);

// ---- Regression ----------------------------------------------------------

// Pearson correlation; 0 when either vector is constant. Same length
// (asserted).
double correlation(const Eigen::VectorXd& a, const Eigen::VectorXd& b);

// Removes from y its least-squares projection onto the columns of basis
// (plus a constant when with_constant): the Frisch-Waugh-Lovell residual.
Eigen::VectorXd project_out(const Eigen::MatrixXd& basis, const Eigen::VectorXd& y, bool with_constant = true);

struct LinearFit {
  Eigen::VectorXd coefficients;  // one per column, in the columns' own units
  double intercept = 0.0;
  double rss = 0.0;              // residual sum of squares of y - fit
  double r2 = 0.0;               // share of y's variance about its mean that the fit explains
};

// Ridge least squares of y on the columns (n x p) with an intercept: every
// column centred and scaled to unit RMS, then
//   minimise |y_c - Z b|^2 + ridge n |b|^2
// (ridge is dimensionless: relative to the unit diagonal of Z'Z / n), solved
// by QR of the augmented system. ridge = 0 is ordinary least squares;
// constant columns get a zero coefficient. Throws dropfit::Error on a size
// mismatch or non-finite values.
LinearFit linear_fit(const Eigen::MatrixXd& columns, const Eigen::VectorXd& y, double ridge = 0.0);

struct SparseOptions {
  // A term survives thresholding while its standardised coefficient
  // (coefficient x column RMS / residual RMS) is at least this.
  double threshold = 0.05;
  double ridge = 1e-4;
  int max_iterations = 20;
  // Backward elimination: drop a survivor whose removal costs less R^2.
  double min_unique_share = 0.02;
  // Exhaustive subset check up to this many (non-constant) columns.
  int max_exhaustive_columns = 12;

  // Throws dropfit::Error naming the field and value when one is out of
  // range (NaN, negative, shares outside 0-1, no iteration); stlsq calls it.
  void validate() const;
};

struct SparseFit {
  std::vector<int> support;      // kept column indices, ascending
  Eigen::VectorXd coefficients;  // every column, zero off the support (final unregularised fit)
  double intercept = 0.0;
  double r2 = 0.0;
  int iterations = 0;            // thresholding rounds until the support settled
};

// STLSQ (Brunton, Proctor & Kutz 2016) with the backward-elimination pass
// described at the top of this file.
SparseFit stlsq(const Eigen::MatrixXd& columns, const Eigen::VectorXd& y, const SparseOptions& options = {});

// ---- Whiteness and periodicity -------------------------------------------

// Pooled sample autocorrelation at lags 1..max_lag (about the overall
// mean, normalised by the lag-0 sum; products never straddle segments).
Eigen::VectorXd autocorrelation(const std::vector<Eigen::VectorXd>& segments, int max_lag);
Eigen::VectorXd autocorrelation(const Eigen::VectorXd& residual, int max_lag);

struct Whiteness {
  Eigen::VectorXd acf;  // lags 1..h
  double q = 0.0;       // Ljung-Box statistic
  int dof = 0;          // h - fitted_parameters (at least 1)
  double p_value = 1.0; // P(chi2_dof > q)
  bool white = true;    // p_value >= alpha
  double rho1() const { return acf.size() > 0 ? acf(0) : 0.0; }
};

// Ljung-Box test over lags 1..max_lag (capped at n / 4).
Whiteness ljung_box(const std::vector<Eigen::VectorXd>& segments, int max_lag, int fitted_parameters = 0,
                    double alpha = 0.01);
Whiteness ljung_box(const Eigen::VectorXd& residual, int max_lag, int fitted_parameters = 0, double alpha = 0.01);

// Upper tail of the chi-square distribution, P(chi2_dof > q) (Boost.Math's
// chi_squared_distribution); NaN for dof <= 0, 1 for q <= 0 (or NaN).
double chi_square_sf(double q, double dof);

struct PeriodicPeak {
  double frequency_hz = kNaN;  // refined peak frequency
  double amplitude = 0.0;      // of the least-squares sinusoid at that frequency, residual units
  double share = 0.0;          // of the residual's variance that sinusoid explains
  double g = 0.0;              // Fisher's g (largest Fourier ordinate over their sum)
  double p_value = 1.0;        // Fisher's bound, times the number of segments tested (Bonferroni)
  bool significant = false;    // p_value < alpha
};

// Fisher's g test on each segment at least 8 samples long, dt_s apart,
// after removing the segment's least-squares line;
// Fourier frequencies below min_frequency_hz are not candidates (a trend is
// not a period). Reports the most significant segment's peak.
PeriodicPeak periodogram_peak(const std::vector<Eigen::VectorXd>& segments, double dt_s, double alpha = 0.01,
                              double min_frequency_hz = 0.0);
PeriodicPeak periodogram_peak(const Eigen::VectorXd& residual, double dt_s, double alpha = 0.01,
                              double min_frequency_hz = 0.0);

// A period common to several segments (the held-out trials' residuals, each
// short): each segment's detrended periodogram over its mean Fourier
// ordinate above min_frequency_hz (so a loud segment does not outvote the
// others), summed over the segments on a grid of a quarter of the finest
// Fourier spacing; the largest sum refined by golden section. A period every
// segment shares adds up while each segment's own misfit does not, and the
// sum resolves a frequency better than one short segment's bins. Under white
// noise an ordinate over its segment's mean of m ordinates is about
// F(2, 2m), and the mean over S segments is taken as F(2S, 2m) with the
// shortest m: p_value is that tail times twice the longest segment's Fourier
// count (the grid is oversampled), g the largest sum over the sum of all the
// normalised ordinates. amplitude and share: a sinusoid at that
// frequency fitted to each segment with its own phase (amplitude their RMS,
// share the pooled explained variance).
PeriodicPeak common_periodic_peak(const std::vector<Eigen::VectorXd>& segments, double dt_s, double alpha = 0.01,
                                  double min_frequency_hz = 0.0);

// ---- Model comparison ----------------------------------------------------

struct InformationCriteria {
  double n = 0.0;  // sample size used (may be effective)
  int k = 0;
  double aic = kNaN;
  double aicc = kNaN;  // +inf when n <= k + 1
  double bic = kNaN;
};

InformationCriteria information_criteria(double rss, double n, int k);

// N (1 - rho1) / (1 + rho1) with rho1 clamped to [0, 0.999]; never below
// min(n, 2) and never above n.
double effective_sample_size(double n, double rho1);

enum class Criterion { AIC, AICc, BIC };
std::string criterion_name(Criterion criterion);

struct ModelComparison {
  double n_eff = 0.0;
  InformationCriteria smaller, larger;  // both on n_eff
  double delta = 0.0;                   // larger minus smaller on the chosen criterion
  bool larger_supported = false;        // delta < -min_drop
};

// Compares a model with k_small parameters against one with k_large > k_small
// on the same n residuals. rho1 is the lag-1 autocorrelation of the larger
// model's residual (the better estimate of the noise when the larger model
// is right): both criteria use the same N_eff. min_drop = 2 asks for more
// than weak support.
ModelComparison compare_models(double rss_small, int k_small, double rss_large, int k_large, double n, double rho1,
                               Criterion criterion = Criterion::AICc, double min_drop = 2.0);

struct PairedImprovement {
  double mean_before = 0.0, mean_after = 0.0;
  double mean_drop = 0.0;  // mean of before - after
  double se = 0.0;         // standard error of that mean (0 for a single pair)
  double t = 0.0;          // mean_drop / se (inf when se = 0 and the drop is positive)
  bool significant = false;
};

// Paired held-out errors (per trial, per check marker): the improvement is
// significant when the mean drop exceeds t_critical standard errors, exceeds
// min_relative of the mean error before, and exceeds min_absolute (the
// error that noise alone produces).
PairedImprovement paired_improvement(const Eigen::VectorXd& before, const Eigen::VectorXd& after,
                                     double t_critical = 2.0, double min_relative = 0.1, double min_absolute = 0.0);

// The paired t on the logarithms of positive errors (each pair's ratio),
// for errors that span orders of magnitude, where one large error before
// hides a fall in all the others from the differences' t (a marker label
// slip spoils the other markers' errors by very unequal amounts). Pairs
// with an error not above 0 are left out; NaN with fewer than 3 left.
double log_paired_t(const std::vector<double>& before, const std::vector<double>& after);

// ---- The whole test ------------------------------------------------------

struct StructureOptions {
  int max_lag = 20;          // Ljung-Box lags
  int fitted_parameters = 0; // degrees of freedom the Ljung-Box test loses
  double alpha = 0.01;       // significance of the whiteness and periodogram tests
  SparseOptions sparse;
  // A candidate counts as structure only when it explains at least this
  // share of the residual's variance alone.
  double min_share = 0.1;
  double dt_s = 0.0;               // sample spacing; 0 skips the periodogram
  double min_frequency_hz = 0.0;   // see periodogram_peak
  // Each segment's own mean taken out of the residual and of every
  // candidate column (the projection onto per-segment intercepts, e.g. one
  // zero offset per trial) by centring each segment: O(n), where the same
  // intercepts as nuisance columns cost a dense n x segments matrix.
  // Not together with nuisance columns.
  bool centre_segments = false;

  // Throws dropfit::Error naming the field and value when one is out of
  // range (negative lags or spacing, alpha outside (0, 1), NaN), and
  // sparse.validate(); analyse_residual calls it.
  void validate() const;
};

struct TermScore {
  std::string name, description;
  int index = -1;             // into the candidate list
  double r = 0.0;             // correlation with the (projected) residual
  double share_alone = 0.0;   // r^2
  double share_unique = 0.0;  // R^2 lost when dropped from the sparse fit (0 when not kept)
  bool kept = false;          // in the sparse fit
  double coefficient = 0.0;   // in the sparse fit, candidate units
};

struct StructureReport {
  int n = 0;
  Whiteness whiteness;
  PeriodicPeak peak;
  std::vector<TermScore> terms;  // every candidate, best share_alone first
  SparseFit sparse;
  double explained_share = 0.0;  // R^2 of the sparse fit
  // Not white (Ljung-Box), or a significant periodogram peak, or a
  // candidate explaining at least min_share.
  bool structured = false;

  // The best single term, or nullptr when none reaches min_share.
  const TermScore* best() const;
  const TermScore* find(const std::string& name) const;
  std::string summary() const;  // one line
  double min_share = 0.1;
};

// segments: the residual, one vector per trial (or one vector); candidates:
// columns over the concatenated samples; nuisance: columns the model already
// fits (n x q, may be empty), projected out first. Throws dropfit::Error on
// mismatched lengths or non-finite values.
StructureReport analyse_residual(const std::vector<Eigen::VectorXd>& segments, const std::vector<Candidate>& candidates,
                                 const StructureOptions& options = {}, const Eigen::MatrixXd& nuisance = {});
StructureReport analyse_residual(const Eigen::VectorXd& residual, const std::vector<Candidate>& candidates,
                                 const StructureOptions& options = {}, const Eigen::MatrixXd& nuisance = {});

}  // namespace dropfit::diagnosis

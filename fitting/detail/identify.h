#pragma once
// Identifiability beyond the linearised covariance (internal to fitting/).
//
// The layered chain's second basin. In Model 4 the layers m1 -(k2)- m2
// -(k3)- ground, with the impactor's spring k1 on m1, form a two-mass chain
// whose part of the plate's force is set mostly by its two natural
// frequencies and their damping. The squared frequencies are the
// eigenvalues of M^-1 K, K = [[k1 + k2, -k2], [-k2, k2 + k3]], M =
// diag(m1, m2): their sum T = (k1 + k2)/m1 + (k2 + k3)/m2 and product
// D = (k1 k2 + k1 k3 + k2 k3)/(m1 m2). With k1 and the masses fixed, k3
// follows from T linearly and D is then a quadratic in k2: two pairs
// (k2, k3) share both frequencies, the one fitted and its conjugate, the
// layers' roles exchanged in part (the softer of the two springs below the
// top moves to the other side of m2). The damping matrix has the same
// form, so the dampings (r2, r3) map the same way with r1. Where the mode
// shapes matter little to the plate (drops of one speed, noise above the
// difference) both fit as well. Levenberg-Marquardt runs from the conjugate
// of the best optimum, so that whichever basin the multi-start found, the
// other one is found too.
//
// Likelihood-ratio intervals. The cost is a Gaussian log-likelihood whose
// weights take the residuals as white; they are not (AR noise, the inputs'
// errors: the error budget's sandwich covariance V). The profile statistic
// of parameter j is calibrated by the ratio of the white-noise variance to
// the sandwich one: W_j(theta) = 2 (C_j(theta) - C) B_jj / V_jj, C_j the
// cost minimised over everything else with u_j held at theta, B = (J^T
// J)^-1. Linearised, W_j is (theta - u_j)^2 / V_jj, the Wald statistic, so
// where the model is linear in the parameters the interval is the Wald
// one; where it is not, the set W_j <= 3.84 (chi-square, one degree of
// freedom, 95 %) is asymmetric, reaches a bound, or includes another basin.
#include <atomic>
#include <vector>

#include "fitting/detail/objective.h"
#include "fitting/detail/search.h"
#include "fitting/detail/space.h"
#include "fitting/error_budget.h"
#include "fitting/fit.h"

namespace dropfit::fitting::internal {

// The conjugate of u (see above), or an empty vector when the model has no
// such pair (not Model 4, k2 or k3 not free, no positive conjugate) or it
// lies within 20 % of u in k2, k3, r2 and r3.
Eigen::VectorXd conjugate_start(const ParamSpace& space, const Eigen::VectorXd& u);

// Levenberg-Marquardt from the conjugate of the best optimum; the result
// joins s->others, or becomes the best when it ends lower.
void search_conjugate(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
                      std::atomic<long>* evals, Search* s);

// The intervals the linearisation cannot give, from the profile statistic
// (above): for a parameter at its bound or weakly determined, and for one
// whose cost at its Wald ends (along the linear profile path) departs from
// the linear prediction by more than 10 % in the statistic's square root,
// the profile interval replaces the Wald one on that side; then every
// other optimum the search found that the data do not reject against the
// best (the likelihood ratio of the two under the noise as it is, AR(1)
// blocks, at most 3.84: the 95 % profile set of a parameter that differs
// reaches it) makes each parameter whose value there lies outside its
// interval not identifiable, its interval spanning both basins
// (FitResult::alternatives, each estimate's note). Estimates (free ones
// first, in the space's order) must hold covariance()'s result.
void refine_intervals(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
                      const Search& s, const ErrorBudget& budget, std::atomic<long>* evals, FitResult* res);

}  // namespace dropfit::fitting::internal

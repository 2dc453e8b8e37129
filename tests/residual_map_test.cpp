// diagnosis::map_residual: the held-out residual's form told from its map.
// Five held-out contacts (a half sine of travel, 4-6.5 m/s) whose measured
// force is the prediction plus one known missing term: a cubic elastic
// term, a dashpot, a relaxing (Maxwell) stress, or a per-trial offset that
// grows with recording order. Noise 20 N.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "diagnosis/model_choice.h"

namespace dropfit::diagnosis {
namespace {

enum class Missing { Cubic, Dashpot, Maxwell, Order };

struct Sessionlet {
  std::vector<fitting::TrialData> trials;
  std::vector<fitting::TrialReport> reports;
};

Sessionlet make(Missing what) {
  Sessionlet s;
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 20.0);
  const double speeds[5] = {5.25, 4.3, 6.5, 4.8, 5.75};  // recording order is not speed order
  for (int k = 0; k < 5; ++k) {
    const double v = speeds[k], T = 0.06, amp = v * T / M_PI;
    fitting::TrialData tr;
    tr.id = "trial" + std::to_string(k + 1);
    tr.impact_velocity_m_s = v;
    tr.force_noise_n = 20.0;
    const int n = 90;
    tr.t_s.resize(n);
    tr.grf_n.resize(n);
    tr.impactor_m.resize(n);
    fitting::TrialReport rep;
    rep.id = tr.id;
    rep.train = k == 0;
    rep.window_end_s = 0.07;
    rep.simulation.t_s = tr.t_s;
    rep.simulation.grf_n.resize(n);
    rep.simulation.impactor_m.resize(n);
    double q = 0.0;
    for (int i = 0; i < n; ++i) {
      const double t = (i - 5) * 1e-3;
      const double x = t < 0.0 || t > T ? 0.0 : amp * std::sin(M_PI * t / T);
      const double xd = t < 0.0 || t > T ? 0.0 : amp * M_PI / T * std::cos(M_PI * t / T);
      const double f = 7e4 * x;
      q += 1e-3 * (2.5e4 * xd - q / 0.02);  // a Maxwell arm, 20 ms
      double missing = 0.0;
      if (what == Missing::Cubic) missing = 4e6 * x * x * x;
      if (what == Missing::Dashpot) missing = 120.0 * xd;
      if (what == Missing::Maxwell) missing = q;
      if (what == Missing::Order) missing = t >= 0.0 && t <= T ? 60.0 * k : 0.0;
      tr.t_s[i] = t;
      tr.impactor_m[i] = x;
      tr.grf_n[i] = f + missing + noise(rng);
      rep.simulation.grf_n[i] = f;
      rep.simulation.impactor_m[i] = x;
    }
    rep.simulation.t_s = tr.t_s;
    s.trials.push_back(tr);
    s.reports.push_back(rep);
  }
  return s;
}

TEST(ResidualMap, ACubicTermIsElastic) {
  const Sessionlet s = make(Missing::Cubic);
  const ResidualMap m = map_residual(s.trials, s.reports);
  EXPECT_EQ(m.form, "elastic") << m.proposal;
  ASSERT_EQ(m.axes.size(), 4u);
  EXPECT_GT(m.axes[0].r2, 0.8);
  // The residual grows with the deflection: largest in the deepest bin.
  EXPECT_GT(m.axes[0].mean_sd.back(), m.axes[0].mean_sd.front() + 5.0);
}

TEST(ResidualMap, ADashpotIsViscous) {
  const Sessionlet s = make(Missing::Dashpot);
  const ResidualMap m = map_residual(s.trials, s.reports);
  EXPECT_EQ(m.form, "viscous") << m.proposal;
  EXPECT_GT(m.axes[1].r2, 0.8);
}

TEST(ResidualMap, ARelaxingStressIsMemory) {
  const Sessionlet s = make(Missing::Maxwell);
  const ResidualMap m = map_residual(s.trials, s.reports);
  EXPECT_EQ(m.form, "memory") << m.proposal;
}

TEST(ResidualMap, AMatThatChangesBetweenTrialsTrendsWithOrder) {
  const Sessionlet s = make(Missing::Order);
  const ResidualMap m = map_residual(s.trials, s.reports);
  EXPECT_EQ(m.form, "trial_to_trial") << m.proposal;
  // 60 N per trial over 20 N noise, on 61 of the window's 71 samples.
  EXPECT_NEAR(m.order_slope_sd, 3.0 * 61.0 / 71.0, 0.3);
  EXPECT_EQ(m.axes[3].centre.size(), 4u);  // the four held-out trials
}

}  // namespace
}  // namespace dropfit::diagnosis

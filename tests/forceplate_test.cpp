// Force plate: eight channels synthesised from known resultants and centre of
// pressure (the Kistler formulas inverted), plate offsets, channel noise and
// quantisation; the processing must give the truth back.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "core/error.h"
#include "forceplate/forceplate.h"

namespace fp = dropfit::forceplate;

namespace {

constexpr double kPi = 3.14159265358979323846;

// A contact pulse F = peak * sin(pi tau / T)^p for 0 < tau < T: p sets the
// shape of the initial rise (1 linear, 1.5 Hertz-like, 2 quadratic).
struct Pulse {
  double peak_n = 7000.0;
  double duration_s = 0.100;
  double power = 2.0;
  double operator()(double tau) const {
    if (tau <= 0.0 || tau >= duration_s) return 0.0;
    return peak_n * std::pow(std::sin(kPi * tau / duration_s), power);
  }
};

struct Synthetic {
  Eigen::VectorXd t_s;         // force clock, trigger sample at 0
  Eigen::MatrixXd channels;    // n x 8
  Eigen::MatrixXd f_true;      // n x 3 (no offset, no noise)
  Eigen::MatrixXd cop_true;    // n x 2
  double contact_s = 0.0;      // force clock
  double crossing_s = 0.0;     // noiseless 25 N crossing, force clock
  double peak_time_s = 0.0;
  double end_s = 0.0;
  double fz_offset_n = 0.0;
  int pretrigger = 0;
};

struct SynthOptions {
  Pulse fz;
  double fs_hz = 1000.0;
  int n = 3000;
  int pretrigger = 300;
  double channel_noise_n = 1.0;  // per channel: Fz (sum of four) has 2 N
  double quantum_n = 0.05;
  bool offsets = true;
  unsigned seed = 7;
};

// Fx = 2 % of Fz, Fy = -1 %, COP moving 50 mm in x over the contact; the
// channels from the inverted formulas with no free moment and no twist:
//   My = Fx az0 - ax Fz, Mx = ay Fz - Fy az0,
//   Fz1 = (Fz + Mx/b - My/a)/4, Fz2 = (Fz + Mx/b + My/a)/4,
//   Fz3 = (Fz - Mx/b + My/a)/4, Fz4 = (Fz - Mx/b - My/a)/4.
Synthetic synthesise(const SynthOptions& o, const fp::PlateGeometry& plate) {
  const double contact_acq = 0.4 + 0.37e-3;  // acquisition time of contact, off the sample grid
  const double dt = 1.0 / o.fs_hz;
  // The acquisition's trigger: the first noiseless sample at 25 N (two
  // samples after contact for a pulse that never gets there).
  int k_trig = 0;
  while (k_trig * dt < contact_acq + o.fz.duration_s && o.fz(k_trig * dt - contact_acq) < 25.0) ++k_trig;
  if (o.fz.peak_n < 25.0) k_trig = static_cast<int>(contact_acq / dt) + 2;
  Synthetic s;
  s.pretrigger = o.pretrigger;
  s.contact_s = contact_acq - k_trig * dt;
  {
    // Noiseless crossing instant, linearly interpolated like the processing.
    const double f0 = o.fz((k_trig - 1) * dt - contact_acq), f1 = o.fz(k_trig * dt - contact_acq);
    s.crossing_s = -dt + (25.0 - f0) / (f1 - f0) * dt;
  }
  s.peak_time_s = s.contact_s + 0.5 * o.fz.duration_s;
  s.end_s = s.contact_s + o.fz.duration_s;
  s.t_s.resize(o.n);
  s.channels.resize(o.n, 8);
  s.f_true.resize(o.n, 3);
  s.cop_true.resize(o.n, 2);
  std::mt19937 rng(o.seed);
  std::normal_distribution<double> unit(0.0, 1.0);
  const double offsets[8] = {0.5, -0.3, 0.2, 0.4, 3.0, -2.0, 1.5, 0.7};
  s.fz_offset_n = o.offsets ? 3.0 - 2.0 + 1.5 + 0.7 : 0.0;
  const double a = plate.a_m, b = plate.b_m, az0 = plate.az0_m;
  for (int i = 0; i < o.n; ++i) {
    const int k = k_trig - o.pretrigger + i;
    s.t_s[i] = (k - k_trig) * dt;
    const double tau = k * dt - contact_acq;
    const double fz = o.fz(tau);
    const double fx = 0.02 * fz, fy = -0.01 * fz;
    const double ax = 0.02 + 0.05 * std::clamp(tau / o.fz.duration_s, 0.0, 1.0), ay = -0.03;
    const double my = fx * az0 - ax * fz, mx = ay * fz - fy * az0;
    const double ch[8] = {fx / 2, fx / 2, fy / 2, fy / 2, (fz + mx / b - my / a) / 4, (fz + mx / b + my / a) / 4,
                          (fz - mx / b + my / a) / 4, (fz - mx / b - my / a) / 4};
    for (int c = 0; c < 8; ++c) {
      double v = ch[c] + (o.offsets ? offsets[c] : 0.0) + o.channel_noise_n * unit(rng);
      if (o.quantum_n > 0) v = o.quantum_n * std::round(v / o.quantum_n);
      s.channels(i, c) = v;
    }
    s.f_true.row(i) << fx, fy, fz;
    s.cop_true.row(i) << ax, ay;
  }
  return s;
}

fp::ProcessOptions options_for(const Synthetic& s) {
  fp::ProcessOptions o;
  o.pretrigger_samples = s.pretrigger;
  return o;
}

void expect_error_containing(const std::function<void()>& f, const std::vector<std::string>& parts) {
  try {
    f();
    ADD_FAILURE() << "expected dropfit::Error";
  } catch (const dropfit::Error& e) {
    const std::string what = e.what();
    for (const auto& p : parts) EXPECT_NE(what.find(p), std::string::npos) << "'" << p << "' not in: " << what;
  }
}

}  // namespace

TEST(ForcePlate, EightChannelFormulasGiveBackForcesMomentsAndCop) {
  const fp::PlateGeometry plate{0.120, 0.200, -0.048};
  SynthOptions o;
  o.channel_noise_n = 0.0;
  o.quantum_n = 0.0;
  o.offsets = false;
  const Synthetic s = synthesise(o, plate);
  const fp::Resultants r = fp::from_eight_channels(s.t_s, s.channels, plate, 50.0);
  ASSERT_EQ(r.f_n.rows(), o.n);
  EXPECT_LT((r.f_n - s.f_true).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_LT(r.m_n_m.col(2).cwiseAbs().maxCoeff(), 1e-9);  // no free moment synthesised
  int with_cop = 0;
  for (int i = 0; i < o.n; ++i) {
    if (std::abs(s.f_true(i, 2)) >= 50.0) {
      ++with_cop;
      EXPECT_NEAR(r.cop_m(i, 0), s.cop_true(i, 0), 1e-9);
      EXPECT_NEAR(r.cop_m(i, 1), s.cop_true(i, 1), 1e-9);
    } else {
      EXPECT_TRUE(std::isnan(r.cop_m(i, 0)) && std::isnan(r.cop_m(i, 1))) << "sample " << i;
    }
  }
  EXPECT_GT(with_cop, 80);
}

TEST(ForcePlate, ProcessRecoversOffsetTriggerContactPeakAndCop) {
  const fp::PlateGeometry plate;
  const Synthetic s = synthesise(SynthOptions{}, plate);
  const fp::ForceTrial f = fp::process(fp::from_eight_channels(s.t_s, s.channels, plate), options_for(s));
  EXPECT_NEAR(f.offset[2], s.fz_offset_n, 0.3);
  EXPECT_NEAR(f.noise_n, 2.0, 0.3);
  EXPECT_EQ(f.declared_trigger_index, s.pretrigger);
  EXPECT_NEAR(f.plate.t_s[s.pretrigger], 0.0, 1e-12);
  EXPECT_NEAR(f.trigger_time_s, s.crossing_s, 0.3e-3);
  // The onset is found before the 25 N crossing, within 1 ms of true contact.
  EXPECT_LT(f.contact_time_s, f.trigger_time_s - 0.5e-3);
  EXPECT_LT(f.contact_time_s, f.plate.t_s[f.trigger_index - 1]);
  EXPECT_NEAR(f.contact_time_s, s.contact_s, 1e-3);
  EXPECT_NEAR(f.peak_fz_n, 7000.0, 0.005 * 7000.0);
  EXPECT_NEAR(f.time_to_peak_s, s.peak_time_s - s.contact_s, 1e-3);
  EXPECT_TRUE(f.end_found);
  EXPECT_NEAR(f.end_time_s, s.end_s, 1.5e-3);
  // Zeroed Fz against the truth: within 5 noise SDs everywhere.
  EXPECT_LT((f.plate.f_n.col(2) - s.f_true.col(2)).cwiseAbs().maxCoeff(), 10.0);
  // COP within 5 mm wherever Fz is large enough to mean anything.
  int checked = 0;
  for (int i = 0; i < s.t_s.size(); ++i) {
    if (s.f_true(i, 2) < 500.0) continue;
    ++checked;
    EXPECT_NEAR(f.plate.cop_m(i, 0), s.cop_true(i, 0), 5e-3) << "sample " << i;
    EXPECT_NEAR(f.plate.cop_m(i, 1), s.cop_true(i, 1), 5e-3) << "sample " << i;
  }
  EXPECT_GT(checked, 50);
}

// The onset must not depend on the rise having one particular shape.
TEST(ForcePlate, ContactOnsetForLinearHertzianAndQuadraticRises) {
  const fp::PlateGeometry plate;
  for (double power : {1.0, 1.5, 2.0}) {
    for (unsigned seed : {1u, 2u, 3u}) {
      SynthOptions o;
      o.fz.power = power;
      o.seed = seed;
      const Synthetic s = synthesise(o, plate);
      const fp::ForceTrial f = fp::process(fp::from_eight_channels(s.t_s, s.channels, plate), options_for(s));
      EXPECT_NEAR(f.contact_time_s, s.contact_s, 0.5e-3) << "power " << power << " seed " << seed;
      EXPECT_LT(f.contact_time_s, f.plate.t_s[f.trigger_index]) << "power " << power << " seed " << seed;
    }
  }
}

// A slow rise starts many samples before the trigger; the zero offset must
// still come from the quiet part and the onset from the force.
TEST(ForcePlate, SlowRiseStartsLongBeforeTheTrigger) {
  const fp::PlateGeometry plate;
  SynthOptions o;
  o.fz.peak_n = 3000.0;
  o.fz.duration_s = 0.600;  // 25 N after about 17 ms
  o.n = 4000;
  o.pretrigger = 400;
  const Synthetic s = synthesise(o, plate);
  ASSERT_LT(s.contact_s, -0.015);
  const fp::ForceTrial f = fp::process(fp::from_eight_channels(s.t_s, s.channels, plate), options_for(s));
  EXPECT_NEAR(f.offset[2], s.fz_offset_n, 0.3);
  EXPECT_NEAR(f.contact_time_s, s.contact_s, 1e-3);
}

// BioWare's resultants and the eight channels are the same record: same Fz,
// same clock (an absolute time column rebased), same onset, same COP.
TEST(ForcePlate, ResultantPathGivesSameFzAsEightChannels) {
  const fp::PlateGeometry plate;
  const Synthetic s = synthesise(SynthOptions{}, plate);
  const fp::Resultants r8 = fp::from_eight_channels(s.t_s, s.channels, plate);
  Eigen::MatrixXd columns(s.t_s.size(), 9);
  columns << r8.f_n, r8.m_n_m, r8.cop_m, Eigen::VectorXd::Zero(s.t_s.size());  // an extra column is ignored
  const Eigen::VectorXd absolute = s.t_s.array() + 17.25 + 0.3;
  const fp::ProcessOptions po = options_for(s);
  const fp::ForceTrial a = fp::process(r8, po);
  const fp::ForceTrial b = fp::process(fp::from_resultant_columns(absolute, columns, 50.0, plate.az0_m), po);
  EXPECT_LT((a.plate.f_n.col(2) - b.plate.f_n.col(2)).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_LT((a.plate.t_s - b.plate.t_s).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_NEAR(a.contact_time_s, b.contact_time_s, 1e-9);
  EXPECT_NEAR(a.peak_fz_n, b.peak_fz_n, 1e-9);
  for (int i = 0; i < s.t_s.size(); ++i) {
    if (std::isnan(a.plate.cop_m(i, 0))) {
      EXPECT_TRUE(std::isnan(b.plate.cop_m(i, 0)));
    } else {
      EXPECT_NEAR(a.plate.cop_m(i, 0), b.plate.cop_m(i, 0), 1e-9);
    }
  }
  // Without az0, BioWare's own Ax Ay are kept (masked by the zeroed Fz).
  const fp::ForceTrial c = fp::process(fp::from_resultant_columns(absolute, columns), po);
  const int at_peak = a.declared_trigger_index + static_cast<int>(std::lround(a.peak_time_s * 1000.0));
  EXPECT_NEAR(c.plate.cop_m(at_peak, 0), r8.cop_m(at_peak, 0), 1e-12);
  EXPECT_NEAR(c.plate.cop_m(at_peak, 0), s.cop_true(at_peak, 0), 5e-3);
}

TEST(ForcePlate, NoTriggerIsAnError) {
  const fp::PlateGeometry plate;
  SynthOptions o;
  o.fz.peak_n = 15.0;  // a bump that never reaches 25 N
  const Synthetic s = synthesise(o, plate);
  expect_error_containing([&] { fp::process(fp::from_eight_channels(s.t_s, s.channels, plate), options_for(s)); },
                          {"no trigger"});
}

TEST(ForcePlate, SaturatedChannelIsAnError) {
  const fp::PlateGeometry plate;
  const Synthetic s = synthesise(SynthOptions{}, plate);
  Eigen::MatrixXd clipped = s.channels;
  const double range = 0.8 * s.channels.col(5).maxCoeff();
  clipped.col(5) = clipped.col(5).cwiseMin(range);
  expect_error_containing([&] { fp::process(fp::from_eight_channels(s.t_s, clipped, plate), options_for(s)); },
                          {"Fz2", "saturated"});
  // A known amplifier range flags a channel reaching it, even unclipped.
  fp::ProcessOptions po = options_for(s);
  po.saturation_n = range;
  expect_error_containing([&] { fp::process(fp::from_eight_channels(s.t_s, s.channels, plate), po); },
                          {"saturated"});
  // The unclipped record passes (smooth quantised peaks are not flat tops).
  EXPECT_NO_THROW(fp::process(fp::from_eight_channels(s.t_s, s.channels, plate), options_for(s)));
}

TEST(ForcePlate, NanInAChannelIsAnError) {
  const fp::PlateGeometry plate;
  const Synthetic s = synthesise(SynthOptions{}, plate);
  Eigen::MatrixXd broken = s.channels;
  broken(1234, 6) = std::numeric_limits<double>::quiet_NaN();
  expect_error_containing([&] { fp::from_eight_channels(s.t_s, broken, plate); }, {"Fz3", "1234"});
  expect_error_containing([&] { fp::from_eight_channels(s.t_s, broken.leftCols(7), plate); }, {"8 channels"});
}

// The vertical channels' sign reversed (an export in a plate frame whose z
// points down): the load reads as tension, and the error says so rather than
// that the trigger is misplaced.
TEST(ForcePlate, ReversedVerticalSignIsNamed) {
  const fp::PlateGeometry plate;
  const Synthetic s = synthesise(SynthOptions{}, plate);
  Eigen::MatrixXd reversed = s.channels;
  reversed.rightCols(4) *= -1.0;
  expect_error_containing([&] { fp::process(fp::from_eight_channels(s.t_s, reversed, plate), options_for(s)); },
                          {"read the load as tension", "sign is reversed"});
}

// One sample of 400 N on Fz2 long before the contact (an electrical glitch)
// crosses the trigger threshold: named as a glitch, not as a pre-trigger
// share that does not match.
TEST(ForcePlate, GlitchBeforeTheTriggerIsNamed) {
  const fp::PlateGeometry plate;
  const Synthetic s = synthesise(SynthOptions{}, plate);
  Eigen::MatrixXd glitched = s.channels;
  glitched(20, 5) += 400.0;
  expect_error_containing([&] { fp::process(fp::from_eight_channels(s.t_s, glitched, plate), options_for(s)); },
                          {"at sample 20 for one sample", "a glitch on the force channels, not a contact"});
}

TEST(ForcePlate, TooFewPreTriggerSamplesIsAnError) {
  const fp::PlateGeometry plate;
  SynthOptions o;
  o.pretrigger = 60;
  const Synthetic s = synthesise(o, plate);
  expect_error_containing([&] { fp::process(fp::from_eight_channels(s.t_s, s.channels, plate), options_for(s)); },
                          {"too few pre-trigger samples"});
}

TEST(ForcePlate, TriggerFarFromTheDeclaredShareIsAnError) {
  const fp::PlateGeometry plate;
  const Synthetic s = synthesise(SynthOptions{}, plate);
  fp::ProcessOptions po;
  po.pretrigger_fraction = 0.2;  // the record has 10 %
  expect_error_containing([&] { fp::process(fp::from_eight_channels(s.t_s, s.channels, plate), po); },
                          {"does not match"});
}

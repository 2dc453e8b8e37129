// The lab world of samples/generator: each realistic feature and injected
// effect is present in the session with the size the truth states.
#include <gtest/gtest.h>

#include <cmath>
#include <set>

#include "core/error.h"
#include "samples/generator/synth.h"

namespace dropfit::synth {
namespace {

SynthOptions quiet_lab(std::vector<double> velocities = {5.25}) {
  SynthOptions o = lab_session_options(21);
  o.impact_velocities_m_s = std::move(velocities);
  o.pixel_noise_px = 0.0;
  o.calibration_pixel_noise_px = 0.0;
  o.channel_noise_n = 0.0;
  o.channel_offset_sd_n = 0.0;
  o.random_gaps_per_trial = 0;
  return o;
}

double zeroed_fz(const ForceRecord& f, const TrialTruth& t, Eigen::Index j) {
  return f.data.row(j).tail<4>().sum() - t.channel_offsets_n.tail<4>().sum();
}

// Force sample j matches video frame f when both clocks tick at 1 kHz and no
// offset is injected: t = (j - npre) / fs = (f - trigger_frame) / fps.
Eigen::Index sample_of_frame(const SynthOptions& o, const TrialTruth& t, int f) {
  return f - o.trigger_frame + t.trigger_index;
}

TEST(GeneratorWorld, ForceScaleMakesThePlatePeakHighByItsSize) {
  SynthOptions o = quiet_lab();
  o.effects.force_scale = 1.05;
  const SyntheticSession s = make_session(o);
  const TrialTruth& t = s.truth.trials[0];
  const ForceRecord& f = s.session.trials[0].force;
  double plate_peak = 0.0;
  for (Eigen::Index j = 0; j < f.t_s.size(); ++j) plate_peak = std::max(plate_peak, zeroed_fz(f, t, j));
  // Against the true GRF at the same samples: 5 % high, to the writer's
  // six decimals.
  EXPECT_NEAR(plate_peak / t.grf_n.maxCoeff(), 1.05, 1e-6);
  ASSERT_EQ(s.truth.effects.size(), 1u);
  EXPECT_EQ(s.truth.effects[0].name, "force_scale");
}

TEST(GeneratorWorld, MatMarkersMoveWithTheTopLayerTimesTheirDishFactor) {
  const SynthOptions o = quiet_lab();
  const SyntheticSession s = make_session(o);
  const TrialTruth& t = s.truth.trials[0];
  ASSERT_EQ(t.dish_factors.size(), 4u);
  double face_max = 0.0, marker_max = 0.0, worst = 0.0;
  for (int k = 0; k < 4; ++k) {
    const Eigen::Vector2d xy = s.truth.mat_markers_xy_m[k];
    EXPECT_GE(xy.norm(), 0.22 - 1e-12);
    EXPECT_LE(xy.norm(), 0.32 + 1e-12);
    const double d = (xy - t.impact_point_m).norm();
    EXPECT_NEAR(t.dish_factors[k], std::exp(-std::pow((d - 0.125) / 0.25, 2)), 1e-12);
  }
  for (int f = t.digitised_first_frame; f <= t.digitised_last_frame; ++f) {
    const Eigen::Index j = sample_of_frame(o, t, f);
    for (int k = 0; k < 4; ++k) {
      const double travel = s.truth.mat_top_z_m - t.markers_lab_m(f, 3 * (2 + k) + 2);
      worst = std::max(worst, std::abs(travel - t.dish_factors[k] * t.layer1_travel_m(j)));
      marker_max = std::max(marker_max, travel);
    }
    face_max = std::max(face_max, t.impactor_travel_m(j));
  }
  EXPECT_LT(worst, 1e-9);
  // A few millimetres beside the footprint while the face travels ~100 mm.
  EXPECT_GT(face_max, 0.08);
  EXPECT_GT(marker_max, 0.001);
  EXPECT_LT(marker_max, 0.2 * face_max);
}

TEST(GeneratorWorld, BaseMarkersAtTheFacesDiagonalCornersAtFaceHeight) {
  const SyntheticSession s = make_session(quiet_lab());
  ASSERT_EQ(s.truth.base_markers_impactor_m.size(), 2u);
  EXPECT_TRUE(s.truth.base_markers_impactor_m[0].isApprox(Eigen::Vector3d(0.125, 0.125, 0.0)));
  EXPECT_TRUE(s.truth.base_markers_impactor_m[1].isApprox(Eigen::Vector3d(-0.125, -0.125, 0.0)));
  EXPECT_EQ(s.session.manifest.impactor.base_marker_height_m, 0.0);
}

TEST(GeneratorWorld, DigitisedWindowAboutContactWithShortGaps) {
  SynthOptions o = lab_session_options(4);
  const SyntheticSession s = make_session(o);
  int both = 0, gaps = 0;
  for (std::size_t i = 0; i < s.session.trials.size(); ++i) {
    const TrialTruth& t = s.truth.trials[i];
    const MarkerTracks2D& tr = s.session.trials[i].tracks;
    for (int f = 0; f < tr.uv_px.rows(); ++f) {
      const double tau = t.frame_force_time_s(f) - t.contact_time_s;
      const bool inside = tau >= -0.1 && tau <= 0.15;
      if (!inside) EXPECT_TRUE(tr.uv_px.row(f).array().isNaN().all()) << "frame " << f;
    }
    // About 250 frames digitised.
    EXPECT_NEAR(t.digitised_last_frame - t.digitised_first_frame + 1, 250, 1);
    for (const Gap& g : t.gaps) {
      ++gaps;
      both += g.camera < 0;
      EXPECT_GE(g.n_frames, 1);
      EXPECT_LE(g.n_frames, 5);
      const int p = static_cast<int>(std::find(tr.points.begin(), tr.points.end(), g.point) - tr.points.begin());
      for (int c = 0; c < 2; ++c)
        if (g.camera < 0 || g.camera == c)
          EXPECT_TRUE(std::isnan(tr.uv_px(g.first_frame, tr.column(p, c))));
    }
  }
  EXPECT_EQ(gaps, 4 * 5);
  EXPECT_GT(both, 0);  // some gaps in both cameras
}

TEST(GeneratorWorld, FiveSecondRecordsStillOnlyAfterTheVideoEnds) {
  const SynthOptions o = quiet_lab({4.3, 6.5});
  const SyntheticSession s = make_session(o);
  for (std::size_t i = 0; i < s.truth.trials.size(); ++i) {
    const TrialTruth& t = s.truth.trials[i];
    EXPECT_EQ(t.t_s.size(), 5000);
    EXPECT_NEAR(t.t_s(t.t_s.size() - 1) - t.t_s(0), 4.999, 1e-9);
    const Eigen::Index j_end = sample_of_frame(o, t, t.digitised_last_frame);
    // Still moving when digitising stops (the mat rings down, the impactor
    // is in the air or caught) ...
    double late = 0.0;
    for (Eigen::Index j = j_end - 20; j <= j_end; ++j) late = std::max(late, std::abs(t.grf_n(j)));
    EXPECT_GT(late, 5.0) << t.id;
    // ... and still within a newton in the record's last second.
    EXPECT_LT(t.grf_n.tail(1000).cwiseAbs().maxCoeff(), 1.0) << t.id;
  }
}

TEST(GeneratorWorld, PlateOnsetLagsVideoContactThroughTheMatMasses) {
  const SyntheticSession s = make_session(quiet_lab());
  const TrialTruth& t = s.truth.trials[0];
  // The plate's onset: the true GRF's first reaching 1 % of its peak, after
  // contact by a fraction of a millisecond (the two layer masses first
  // have to move); the contact time is on the same clock.
  double onset = std::numeric_limits<double>::quiet_NaN();
  const double peak = t.grf_n.maxCoeff();
  for (Eigen::Index j = 1; j < t.grf_n.size(); ++j)
    if (t.grf_n(j) >= 0.01 * peak) {
      const double a = t.grf_n(j - 1), b = t.grf_n(j);
      onset = t.t_s(j - 1) + (0.01 * peak - a) / (b - a) * (t.t_s(j) - t.t_s(j - 1));
      break;
    }
  const double lag = onset - t.contact_time_s;
  EXPECT_GT(lag, 0.3e-3);
  EXPECT_LT(lag, 3e-3);
}

TEST(GeneratorWorld, NoiseAndDriftOfTheForceChannels) {
  SynthOptions o = lab_session_options(8);
  o.impact_velocities_m_s = {5.0};
  o.effects.baseline_drift_n_s = 5.0;  // 25 N over the 5 s record
  const SyntheticSession s = make_session(o);
  const TrialTruth& t = s.truth.trials[0];
  const ForceRecord& f = s.session.trials[0].force;
  const int npre = t.trigger_index;
  for (int c = 0; c < 8; ++c) {
    // Pre-trigger (quiet, before contact minus 5 ms): SD 1.5 N per channel
    // (drift removed; 490 samples give the SD to ~5 %).
    const int n = npre - 10;
    Eigen::VectorXd x(n);
    for (int j = 0; j < n; ++j) x(j) = f.data(j, c) - (c >= 4 ? 0.25 * t.plate_fz_noise_free_n(j) : 0.0);
    const double mean = x.mean();
    const double sd = std::sqrt((x.array() - mean).square().sum() / (n - 1));
    EXPECT_NEAR(sd, 1.5, 0.2) << "channel " << c;
  }
  // Drift: the plate's noise-free Fz ends 25 N above where it starts, the
  // true GRF being zero at both ends.
  const Eigen::Index last = t.t_s.size() - 1;
  EXPECT_NEAR(t.plate_fz_noise_free_n(last) - t.plate_fz_noise_free_n(0), 5.0 * 4.999, 0.05);
}

TEST(GeneratorWorld, CalibrationSlipSwapsTwoFitMarkersInOneCamera) {
  SynthOptions o = quiet_lab();
  o.effects.outlier_swap = true;
  const SyntheticSession s = make_session(o);
  std::vector<std::string> off;
  for (std::size_t c = 0; c < 2; ++c)
    for (const CameraObservation& ob : s.session.images[c].observations) {
      const auto it = std::find_if(s.truth.calibration_markers.begin(), s.truth.calibration_markers.end(),
                                   [&](const TrueCalibrationMarker& m) { return m.id == ob.id; });
      if ((it->image_px[c] - ob.image_px).norm() > 1e-5) {
        EXPECT_EQ(c, 1u);
        EXPECT_EQ(it->role, MarkerRole::Fit);
        off.push_back(ob.id);
        // It holds the other one's pixel.
        bool found = false;
        for (const TrueCalibrationMarker& m : s.truth.calibration_markers)
          found |= m.id != ob.id && (m.image_px[c] - ob.image_px).norm() < 1e-5;
        EXPECT_TRUE(found);
      }
    }
  EXPECT_EQ(off.size(), 2u);
  ASSERT_EQ(s.truth.effects.size(), 1u);
  EXPECT_EQ(s.truth.effects[0].name, "outlier_marker");
}

TEST(GeneratorWorld, LensDistortionOfAboutOnePixelAtTheMarkers) {
  SynthOptions o = quiet_lab();
  o.effects.lens_distortion_px = 1.0;
  const SyntheticSession s = make_session(o);
  ASSERT_EQ(s.truth.effects.size(), 1u);
  EXPECT_EQ(s.truth.effects[0].name, "lens_distortion");
  EXPECT_LT(s.truth.effects[0].magnitude, 0.0);  // barrel
  // The largest move of a trial marker at contact, between the distorted and
  // the pinhole pixel: 1 px (the k1 was solved for it).
  const TrialTruth& t = s.truth.trials[0];
  const int f0 = t.digitised_first_frame + 100;  // ~contact
  double largest = 0.0;
  for (const TrueCamera& cam : s.truth.cameras) {
    TrueCamera pinhole = cam;
    pinhole.camera.distortion.clear();
    for (int p = 0; p < 6; ++p) {
      const Eigen::Vector3d x = t.markers_lab_m.row(f0).segment<3>(3 * p).transpose();
      largest = std::max(largest, (project_px(cam, x) - project_px(pinhole, x)).norm());
    }
  }
  EXPECT_NEAR(largest, 1.0, 0.1);  // markers at contact vs at rest: within 10 %
}

TEST(GeneratorWorld, TimeOffsetPutsTheVideoClockAhead) {
  SynthOptions o = quiet_lab();
  o.effects.time_offset_ms = 2.5;
  const SyntheticSession s = make_session(o);
  const TrialTruth& t = s.truth.trials[0];
  EXPECT_DOUBLE_EQ(t.video_offset_s, 0.0025);
  for (int f : {0, 400, 999})
    EXPECT_NEAR(t.frame_force_time_s(f), (f - o.trigger_frame) / 1000.0 - 0.0025, 1e-12);
}

TEST(GeneratorWorld, ElasticHysteresisAndMaxwellArmChangeTheMatAsStated) {
  SynthOptions base = quiet_lab();
  SynthOptions h = base, mx = base;
  h.effects.hysteresis_h = 0.25;
  mx.effects.maxwell_k_n_m = 28000.0;
  mx.effects.maxwell_tau_s = 0.025;
  const auto s0 = make_session(base), sh = make_session(h), sm = make_session(mx);
  EXPECT_EQ(sh.truth.params.k1_hysteresis, 0.25);
  EXPECT_EQ(sh.truth.effects[0].name, "hysteresis");
  EXPECT_EQ(sh.truth.effects[0].unit, "h");
  // Loading is the same (within the tanh switch's width); the rebound is
  // weaker: a lower elastic force while unloading returns less energy.
  EXPECT_LT(sh.truth.trials[0].impact_velocity_after_m_s, 0.95 * s0.truth.trials[0].impact_velocity_after_m_s);
  EXPECT_EQ(sm.truth.params.maxwell_k_n_m, 28000.0);
  // A weak arm: the peak force changes by a few per cent at most, the
  // travel by millimetres.
  const double dpeak = sm.truth.trials[0].peak_force_n / s0.truth.trials[0].peak_force_n - 1.0;
  const double dtravel = s0.truth.trials[0].max_deformation_m - sm.truth.trials[0].max_deformation_m;
  EXPECT_LT(std::abs(dpeak), 0.05);
  EXPECT_GT(dtravel, 0.5e-3);
  EXPECT_LT(dtravel, 10e-3);
}

TEST(GeneratorWorld, LayerMassDiffersFromTheDeclaredLayers) {
  SynthOptions o = quiet_lab();
  o.effects.layer_mass_shift_kg = 0.8;
  const SyntheticSession s = make_session(o);
  EXPECT_NEAR(s.truth.params.m1_kg, 2.44 + 0.8, 1e-12);
  EXPECT_NEAR(s.truth.params.m2_kg, 3.66 - 0.8, 1e-12);
  EXPECT_EQ(s.session.manifest.mat.layers[1].mass_kg, 2.44);
  EXPECT_EQ(s.session.manifest.mat.layers[2].mass_kg, 3.66);
}

TEST(GeneratorWorld, IndependentWorldDrawsPlausibleMats) {
  for (std::uint64_t seed = 1; seed <= 8; ++seed) {
    const SynthOptions o = independent_world_options(seed);
    EXPECT_GE(o.params.k1_n_m, 2e4);
    EXPECT_LE(o.params.k1_n_m, 1e5);
    for (double k : {o.params.k2_n_m, o.params.k3_n_m}) {
      EXPECT_GE(k, 5e5);
      EXPECT_LE(k, 2e6);
    }
    EXPECT_TRUE(o.effects.k1_cubic_n_m3 == 0.0 || (o.effects.k1_cubic_n_m3 >= 2e6 && o.effects.k1_cubic_n_m3 <= 8e6));
    for (double v : o.impact_velocities_m_s) {
      EXPECT_GE(v, 4.0);
      EXPECT_LE(v, 6.2);
    }
  }
  const SyntheticSession s = make_session(independent_world_options(3));
  for (const TrialTruth& t : s.truth.trials) {
    EXPECT_LT(t.max_deformation_m, 0.75 * 0.205);
    EXPECT_TRUE(std::isfinite(t.separation_time_s));
  }
}

TEST(GeneratorWorld, RandomEffectsGiveNoneOneOrSeveral) {
  std::set<int> counts;
  std::set<std::string> names;
  for (std::uint64_t seed = 1; seed <= 40; ++seed) {
    SynthOptions o = lab_session_options(seed);
    add_random_effects(o, seed);
    int n = 0;
    const Effects& e = o.effects;
    n += e.lens_distortion_px > 0.0, n += e.outlier_swap, n += e.time_offset_ms != 0.0;
    n += e.baseline_drift_n_s != 0.0, n += e.force_scale != 1.0, n += e.hysteresis_h != 0.0;
    n += e.maxwell_k_n_m != 0.0, n += e.layer_mass_shift_kg != 0.0;
    counts.insert(std::min(n, 2));
    if (seed <= 12) {
      o.impact_velocities_m_s = {5.0};
      for (const InjectedEffect& ie : make_session(o).truth.effects) names.insert(ie.name);
    }
  }
  EXPECT_EQ(counts, (std::set<int>{0, 1, 2}));
  EXPECT_GE(names.size(), 5u);
}

TEST(GeneratorWorld, ModelChoiceAcceptsOtherEnumerationsWithTheSameNumbers) {
  enum class Other { A = 1, B = 2, C = 3, D = 4 };
  SynthOptions o;
  o.model = Other::C;
  EXPECT_EQ(o.model, ModelKind::Model3);
  EXPECT_EQ(o.model, Other::C);
}

}  // namespace
}  // namespace dropfit::synth

// One synthetic trial: the impactor's pose, the generator's own physics
// from first contact, the force plate's eight channels with the plate
// effects and instrument faults, and the markers rendered into both
// cameras with their gaps (samples/generator/synth.h).
#include <Eigen/Geometry>
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>

#include "samples/generator/synth_internal.h"

namespace dropfit::synth {
namespace detail {
namespace {

constexpr double kTriggerSearch_s = 0.15;  // longest contact-to-trigger delay allowed

// ---- Impactor pose ---------------------------------------------------------
// Rotation of the impactor (its frame: X front, Z up from the face) whose
// face has travel slopes (sx, sy) = d(travel)/dx, d(travel)/dy: positive sx
// means the +x side is lower. (sx, 0) is a rotation by atan(sx) about +Y.
Eigen::Matrix3d impactor_rotation(double sx, double sy) {
  const Eigen::Vector3d ex = Eigen::Vector3d(1.0, 0.0, -sx).normalized();
  Eigen::Vector3d ey(0.0, 1.0, -sy);
  ey = (ey - ey.dot(ex) * ex).normalized();
  Eigen::Matrix3d r;
  r.col(0) = ex;
  r.col(1) = ey;
  r.col(2) = ex.cross(ey);
  return r;
}

double deviation_deg(double sx, double sy) { return std::atan(std::hypot(sx, sy)) / kDeg; }

// Whether the channel faults and saturation apply to trial ti.
bool faulty_trial(const InstrumentFaults& f, std::size_t ti) {
  return f.trials.empty() || std::find(f.trials.begin(), f.trials.end(), static_cast<int>(ti)) != f.trials.end();
}

// The analog force the amplifier passes on: x (sampled every dt) through a
// Butterworth low-pass of order 2 or 4 at corner_hz (cascaded second-order
// sections, bilinear transform with the corner prewarped), from rest.
Eigen::VectorXd butterworth(const Eigen::VectorXd& x, double dt, double corner_hz, int order) {
  Eigen::VectorXd y = x;
  const double k = std::tan(kPi * corner_hz * dt);
  for (int section = 0; section < order / 2; ++section) {
    // Pole pair angle: q = 1 / (2 sin((2 section + 1) pi / (2 order))).
    const double q = 1.0 / (2.0 * std::sin((2.0 * section + 1.0) * kPi / (2.0 * order)));
    const double norm = 1.0 / (1.0 + k / q + k * k);
    const double b0 = k * k * norm, b1 = 2.0 * b0, b2 = b0;
    const double a1 = 2.0 * (k * k - 1.0) * norm, a2 = (1.0 - k / q + k * k) * norm;
    const Eigen::VectorXd in = y;
    double x1 = 0.0, x2 = 0.0, y1 = 0.0, y2 = 0.0;
    for (Eigen::Index i = 0; i < in.size(); ++i) {
      const double out = b0 * in[i] + b1 * x1 + b2 * x2 - a1 * y1 - a2 * y2;
      x2 = x1, x1 = in[i], y2 = y1, y1 = out;
      y[i] = out;
    }
  }
  return y;
}

// The mat of trial ti: every stiffness times (1 - softening)^ti.
MatParams trial_params(const SynthOptions& o, const MatParams& params, std::size_t ti) {
  MatParams p = params;
  const double f = std::pow(1.0 - o.faults.softening_per_trial, static_cast<double>(ti));
  p.k1_n_m *= f, p.k2_n_m *= f, p.k3_n_m *= f, p.k1_cubic_n_m3 *= f, p.maxwell_k_n_m *= f;
  return p;
}

// The foam column of trial ti: each foam's elastic stresses (modulus,
// plateau, hardening, densification) times (1 - softening)^ti, as a foam
// damaged by repeated impacts loses stiffness (Mullins-type); its
// relaxation (relative Prony weights, time constants) and viscosity kept.
FoamColumn trial_foam(const SynthOptions& o, const FoamColumn& column, std::size_t ti) {
  FoamColumn c = column;
  const double f = std::pow(1.0 - o.faults.softening_per_trial, static_cast<double>(ti));
  for (FoamLayer* l : {&c.top, &c.base})
    l->modulus_pa *= f, l->plateau_pa *= f, l->hardening_pa *= f, l->densification_pa *= f;
  return c;
}


// The impactor's tilt, impact point, shear share and channel offsets; returns the face slopes.
Eigen::Vector2d draw_trial_pose(const SynthOptions& o, std::size_t ti, TrialTruth& tt) {
  Rng r(o.seed, kStreamTrial + ti);
  const double tilt_abs_deg = std::abs(o.tilt_mean_deg + o.tilt_sd_deg * r.normal());
  const double tilt_sign = r.uniform() < 0.5 ? -1.0 : 1.0;
  const double tilt_rad = tilt_sign * tilt_abs_deg * kDeg;
  tt.impact_point_m = Eigen::Vector2d(r.normal(), r.normal()) * o.impact_point_sd_m;
  tt.cop_m = tt.impact_point_m;
  tt.shear_fraction = Eigen::Vector2d(2.0 * r.uniform() - 1.0, 2.0 * r.uniform() - 1.0) * o.shear_fraction_max;
  for (int c = 0; c < 8; ++c) tt.channel_offsets_n(c) = o.channel_offset_sd_n * r.normal();
  // Face slopes (d travel / dx, d travel / dy): about lab Y, or about a
  // random horizontal axis (its own stream: the classic draws stay).
  Eigen::Vector2d face_slopes(std::tan(tilt_rad), 0.0);
  tt.tilt_axis_deg = 90.0;
  if (o.tilt_random_axis) {
    Rng ax(o.seed, kStreamTrial + 500 + ti);
    const double phi = 2.0 * kPi * ax.uniform();  // direction of steepest descent of the face
    face_slopes = std::tan(tilt_abs_deg * kDeg) * Eigen::Vector2d(std::cos(phi), std::sin(phi));
    tt.tilt_axis_deg = std::remainder(phi / kDeg + 90.0, 360.0);
  }
  tt.tilt_about_y_deg = std::atan(face_slopes.x()) / kDeg;
  return face_slopes;
}

// The chain simulation from first contact (the generator's own physics.h) and the rebound speed.
ChainSimulation simulate_trial_impact(const TrialSetup& setup, const MatParams& params, double v, std::size_t ti,
                                      TrialTruth& tt) {
  const SynthOptions& o = setup.o;
  const double g = setup.g, fs = setup.fs, t_end_force = setup.t_end_force, t_end_video = setup.t_end_video;
  // -- Physics from first contact: the generator's own (physics.h).
  ChainImpact impact;
  impact.mass_kg = o.impactor_mass_kg;
  impact.velocity_m_s = v;
  impact.gravity_m_s2 = g;
  impact.duration_s = std::max(t_end_force, t_end_video) + kTriggerSearch_s + 2.0 / fs;
  impact.output_dt_s = kSimDt;
  impact.catch_at_apex = o.catch_at_apex;
  const ChainSimulation sim =
      o.foam ? simulate_foam_column(trial_foam(o, *o.foam, ti), impact) : simulate_chain(o.model, params, impact);
  require(sim.grf_n.size() >= 2, "simulation returned no samples");
  tt.impact_velocity_after_m_s = kNaN;
  if (std::isfinite(sim.separation_s))
    tt.impact_velocity_after_m_s = -interp(sim.impactor_v_m_s, sim.separation_s, kSimDt);
  return sim;
}

// Travels (m, down) of the face, the mat surface and the layers at time tau from contact.
struct TrialMotion {
  const ChainSimulation& sim;
  double v, g;
  bool has_layer;

  // The face: the simulation after contact, free fall from the release before.
  double face_travel(double tau) const {
    const double d0 = 0.0;
    if (tau >= 0.0) return interp(sim.impactor_m, tau, kSimDt);
    const double tau_release = -v / g;  // held at rest before the release
    const double t = std::max(tau, tau_release);
    return d0 + v * t + 0.5 * g * t * t;
  }
  // The mat surface (element 1's top).
  double surface_travel(double tau) const { return tau >= 0.0 ? interp(sim.surface_m, tau, kSimDt) : 0.0; }
  // A layer's travel record y.
  double layer_travel(const Eigen::VectorXd& y, double tau) const { return tau >= 0.0 ? interp(y, tau, kSimDt) : 0.0; }
  // What the mat markers follow: the top layer (or, with no layer mass, element 1's top).
  double top_layer_travel(double tau) const {
    return has_layer ? layer_travel(sim.layer1_m, tau) : surface_travel(tau);
  }
};

// Contact summary (first contact up to separation): peak force, deformation, travel and tilt.
void summarise_contact(const ChainSimulation& sim, const Eigen::Vector2d& face_slopes, TrialTruth& tt) {
  const Eigen::Index n_sim = sim.grf_n.size();
  Eigen::Index end = n_sim;
  if (std::isfinite(sim.separation_s))
    end = std::min<Eigen::Index>(n_sim, static_cast<Eigen::Index>(std::ceil(sim.separation_s / kSimDt)) + 1);
  Eigen::Index k_peak = 0;
  tt.peak_force_n = sim.grf_n.head(end).maxCoeff(&k_peak);
  tt.time_to_peak_s = static_cast<double>(k_peak) * kSimDt;
  tt.max_deformation_m = sim.impactor_m.head(end).maxCoeff();
  tt.max_surface_travel_m = sim.surface_m.head(end).maxCoeff();
  double dev = 0.0;
  for (Eigen::Index k = 0; k < end; ++k) {
    const Eigen::Vector2d sl = face_slopes;
    dev = std::max(dev, deviation_deg(sl.x(), sl.y()));
  }
  tt.tilt_deg = dev;
}

// The time from contact to the noise-free trigger crossing (s); throws when the force never reaches it.
double contact_to_trigger_s(const SynthOptions& o, const Eigen::VectorXd& plate_grf_n, double fs,
                            const std::string& id) {
  const Effects& fx = o.effects;
  // -- Trigger: the plate's zeroed Fz (gain, drift and noise included)
  // first reaches the threshold at sample npre (t = 0); contact sits a
  // random sub-sample phase before the noise-free crossing.
  const double scale = fx.force_scale;
  double tau25 = -1.0;
  for (Eigen::Index k = 0; k < plate_grf_n.size(); ++k)
    if (scale * plate_grf_n(k) >= o.trigger_threshold_n) {
      if (k == 0) {
        tau25 = 0.0;
      } else {
        const double a = scale * plate_grf_n(k - 1), b = scale * plate_grf_n(k);
        tau25 = (static_cast<double>(k - 1) + (o.trigger_threshold_n - a) / (b - a)) * kSimDt;
      }
      break;
    }
  require(tau25 >= 0.0 && tau25 + 1.0 / fs < kTriggerSearch_s,
          fmt::format("trial {}: the force never reaches the {} N trigger within {} s of contact", id,
                      o.trigger_threshold_n, kTriggerSearch_s));
  return tau25;
}

// The force record: sample times, true GRF and the eight channels with the plate effects.
struct ForceRecord {
  Eigen::VectorXd t_s, grf;
  Eigen::MatrixXd data;
};

// Records the plate's channels, placing contact so the trigger fires at sample npre.
ForceRecord record_force(const TrialSetup& setup, std::size_t ti, const ChainSimulation& sim,
                         const Eigen::VectorXd& plate_grf_n, double tau25, TrialTruth& tt) {
  const SynthOptions& o = setup.o;
  const Effects& fx = o.effects;
  const InstrumentFaults& faults = o.faults;
  const bool faulty = faulty_trial(faults, ti);
  const int n = setup.n, npre = setup.npre;
  const double fs = setup.fs;
  const double scale = fx.force_scale;
  ForceRecord rec;
  Eigen::VectorXd& t_s = rec.t_s;
  Eigen::VectorXd& grf = rec.grf;
  Eigen::MatrixXd& data = rec.data;
  Rng fr(o.seed, kStreamForceNoise + ti);
  t_s.resize(n);
  grf.resize(n);
  data.resize(n, 8);
  bool triggered = false;
  for (int attempt = 0; attempt < 200 && !triggered; ++attempt) {
    const double phase = fr.uniform();
    tt.contact_time_s = -(tau25 + phase / fs);
    for (int j = 0; j < n; ++j) {
      const double t = six_decimals(static_cast<double>(j - npre) / fs);
      t_s(j) = t;
      const double tau = t - tt.contact_time_s;
      grf(j) = tau < 0.0 ? 0.0 : interp(sim.grf_n, tau, kSimDt);
      const double fz = scale * (tau < 0.0 ? 0.0 : interp(plate_grf_n, tau, kSimDt));
      const Eigen::Vector3d f(tt.shear_fraction.x() * fz, tt.shear_fraction.y() * fz, fz);
      Eigen::Matrix<double, 8, 1> ch = kistler_channels(f, tt.cop_m, o.plate_a_m, o.plate_b_m, o.plate_az0_m);
      double drift = 0.0;
      if (fx.baseline_drift_whole_record)
        drift = fx.baseline_drift_n_s * (t - t_s(0));
      else if (t > 0.0)
        drift = fx.baseline_drift_n_s * t;
      ch.tail<4>().array() += 0.25 * drift;
      if (faulty && faults.saturation_n > 0.0) ch = ch.cwiseMax(-faults.saturation_n).cwiseMin(faults.saturation_n);
      if (faulty && faults.dead_channel >= 0) ch(faults.dead_channel) = 0.0;
      if (faulty && faults.reversed_channel >= 0) ch(faults.reversed_channel) = -ch(faults.reversed_channel);
      for (int c = 0; c < 8; ++c) ch(c) += o.channel_noise_n * fr.normal();
      data.row(j) = ch.transpose();
    }
    // The zeroed Fz as the plate's trigger sees it.
    int first = -1;
    for (int j = 0; j < n && first < 0; ++j)
      if (data.row(j).tail<4>().sum() >= o.trigger_threshold_n) first = j;
    triggered = first == npre;
  }
  if (faulty && faults.exchange_a >= 0 && faults.exchange_b >= 0) data.col(faults.exchange_a).swap(data.col(faults.exchange_b));
  require(triggered, fmt::format("trial {}: cannot place the trigger at sample {} with {} N channel noise", tt.id,
                                 npre, o.channel_noise_n));
  for (int j = 0; j < n; ++j)
    for (int c = 0; c < 8; ++c) data(j, c) = six_decimals(data(j, c) + tt.channel_offsets_n(c));
  tt.separation_time_s = std::isfinite(sim.separation_s) ? tt.contact_time_s + sim.separation_s : kNaN;
  return rec;
}

// The truth's travels and noise-free plate Fz at the force samples.
void fill_force_truth(const TrialSetup& setup, const ChainSimulation& sim, const TrialMotion& motion,
                      const ForceRecord& rec, TrialTruth& tt) {
  const Effects& fx = setup.o.effects;
  const int n = setup.n;
  const double scale = fx.force_scale;
  const Eigen::VectorXd& t_s = rec.t_s;
  const Eigen::VectorXd& grf = rec.grf;
  tt.t_s = t_s;
  tt.grf_n = grf;
  tt.impactor_travel_m.resize(n);
  tt.surface_travel_m.resize(n);
  tt.layer1_travel_m.resize(n);
  tt.layer2_travel_m.resize(n);
  tt.plate_fz_noise_free_n.resize(n);
  for (int j = 0; j < n; ++j) {
    const double tau = t_s(j) - tt.contact_time_s;
    tt.impactor_travel_m(j) = motion.face_travel(tau);
    tt.surface_travel_m(j) = motion.surface_travel(tau);
    tt.layer1_travel_m(j) = motion.layer_travel(sim.layer1_m, tau);
    tt.layer2_travel_m(j) = motion.layer_travel(sim.layer2_m, tau);
    double drift = 0.0;
    if (fx.baseline_drift_whole_record)
      drift = fx.baseline_drift_n_s * (t_s(j) - t_s(0));
    else if (t_s(j) > 0.0)
      drift = fx.baseline_drift_n_s * t_s(j);
    tt.plate_fz_noise_free_n(j) = scale * grf(j) + drift;
  }
}

// Renders the markers into both cameras over the digitised window (pixel noise, visibility).
MarkerTracks2D render_markers(const TrialSetup& setup, std::size_t ti, const TrialMotion& motion,
                              const Eigen::Vector2d& face_slopes, TrialTruth& tt) {
  const SynthOptions& o = setup.o;
  const Manifest& m = setup.m;
  const int n_pts = setup.n_pts, n_cam = setup.n_cam;
  const double offset_s = setup.offset_s, mat_top_m = setup.mat_top_m;
  const Eigen::Vector3d(&base_offset)[2] = setup.layout.base_offset;
  const Eigen::Vector2d(&mat_xy)[4] = setup.layout.mat_xy;
  // -- Video.
  Rng pr(o.seed, kStreamPixelNoise + ti);
  MarkerTracks2D tracks;
  tracks.points = m.video.points;
  tracks.cameras = m.video.cameras;
  tracks.uv_px.setConstant(o.n_frames, 2 * n_pts * n_cam, kNaN);
  tt.frame_force_time_s.resize(o.n_frames);
  tt.markers_lab_m.resize(o.n_frames, 3 * n_pts);
  tt.digitised_first_frame = -1;
  tt.digitised_last_frame = -1;
  for (int f = 0; f < o.n_frames; ++f) {
    const double tf = static_cast<double>(f - o.trigger_frame) / o.frame_rate_hz - offset_s;
    tt.frame_force_time_s(f) = tf;
    const double tau = tf - tt.contact_time_s;
    const bool digitised = tau >= o.digitised_from_s && tau <= o.digitised_to_s;
    if (digitised) {
      if (tt.digitised_first_frame < 0) tt.digitised_first_frame = f;
      tt.digitised_last_frame = f;
    }
    const double d = motion.face_travel(tau);
    const double st = motion.surface_travel(tau);
    const Eigen::Vector2d sl = face_slopes;
    const Eigen::Matrix3d rot = impactor_rotation(sl.x(), sl.y());
    const Eigen::Vector3d face(tt.impact_point_m.x(), tt.impact_point_m.y(), mat_top_m - d);
    std::vector<Eigen::Vector3d> pts;
    pts.push_back(face + rot * base_offset[0]);
    pts.push_back(face + rot * base_offset[1]);
    const double top = motion.top_layer_travel(tau);
    for (int k = 0; k < 4; ++k) {
      const double travel = o.mat_marker_motion == MatMarkerMotion::Dish ? tt.dish_factors[k] * top : st;
      pts.emplace_back(mat_xy[k].x(), mat_xy[k].y(), mat_top_m - travel);
    }
    for (int p = 0; p < n_pts; ++p) {
      tt.markers_lab_m.row(f).segment<3>(3 * p) = pts[p].transpose();
      for (int c = 0; c < n_cam; ++c) {
        const Eigen::Vector2d e(pr.normal(), pr.normal());  // drawn always: visibility changes nothing else
        double depth = 0.0;
        pinhole_px(setup.cameras[c], pts[p], &depth);
        const Eigen::Vector2d clean = project_px(setup.cameras[c], pts[p]);
        if (!digitised || !in_image(setup.cameras[c], clean, depth)) continue;
        const Eigen::Vector2d uv = clean + o.pixel_noise_px * e;
        const int col = tracks.column(p, c);
        tracks.uv_px(f, col) = six_decimals(uv.x());
        tracks.uv_px(f, col + 1) = six_decimals(uv.y());
      }
    }
  }
  require(tt.digitised_first_frame >= 0,
          fmt::format("trial {}: no video frame lies in the digitised window", tt.id));
  return tracks;
}

// Hides the requested and the random gaps (inside the digitised window) in the tracks.
void apply_gaps(const TrialSetup& setup, std::size_t ti, MarkerTracks2D& tracks, TrialTruth& tt) {
  const SynthOptions& o = setup.o;
  const Manifest& m = setup.m;
  const int n_pts = setup.n_pts, n_cam = setup.n_cam;
  // Random gaps inside the digitised window (their own stream).
  std::vector<Gap> trial_gaps = o.gaps;
  {
    Rng gr(o.seed, kStreamGaps + ti);
    const int span = tt.digitised_last_frame - tt.digitised_first_frame + 1;
    for (int k = 0; k < o.random_gaps_per_trial && span > 2; ++k) {
      Gap gap;
      gap.trial = static_cast<int>(ti);
      gap.point = m.video.points[std::min<std::size_t>(m.video.points.size() - 1,
                                                       static_cast<std::size_t>(gr.uniform() * n_pts))];
      gap.n_frames = 1 + std::min(o.gap_max_frames - 1, static_cast<int>(gr.uniform() * o.gap_max_frames));
      gap.first_frame =
          tt.digitised_first_frame + std::min(span - 1, static_cast<int>(gr.uniform() * std::max(1, span - gap.n_frames)));
      gap.camera = gr.uniform() < o.gap_both_cameras_fraction
                       ? -1
                       : std::min(n_cam - 1, static_cast<int>(gr.uniform() * n_cam));
      trial_gaps.push_back(gap);
    }
  }
  for (const Gap& gap : trial_gaps) {
    if (gap.trial != static_cast<int>(ti)) continue;
    const auto it = std::find(tracks.points.begin(), tracks.points.end(), gap.point);
    require(it != tracks.points.end(), fmt::format("gap names unknown point '{}'", gap.point));
    require(gap.camera >= -1 && gap.camera < n_cam, fmt::format("gap names camera {} of {}", gap.camera, n_cam));
    const int p = static_cast<int>(it - tracks.points.begin());
    for (int f = gap.first_frame; f < std::min(o.n_frames, gap.first_frame + gap.n_frames); ++f)
      for (int c = 0; c < n_cam; ++c)
        if (gap.camera < 0 || gap.camera == c) {
          tracks.uv_px(f, tracks.column(p, c)) = kNaN;
          tracks.uv_px(f, tracks.column(p, c) + 1) = kNaN;
        }
    tt.gaps.push_back(gap);
  }
}

}  // namespace

// Simulates trial ti: pose, physics, force record, video and gaps.
SimulatedTrial simulate_trial(const TrialSetup& setup, std::size_t ti) {
  const SynthOptions& o = setup.o;
  const double g = setup.g, offset_s = setup.offset_s, fs = setup.fs;
  const int npre = setup.npre;
  const Eigen::Vector2d(&mat_xy)[4] = setup.layout.mat_xy;
  SimulatedTrial out;
  TrialTruth& tt = out.tt;
  const double v = o.impact_velocities_m_s[ti];
  tt.id = fmt::format("trial{}", ti + 1);
  tt.impact_velocity_m_s = v;
  tt.model = o.model;
  const MatParams params = trial_params(o, setup.params, ti);
  tt.params = params;
  tt.video_offset_s = offset_s;
  tt.trigger_index = npre;
  tt.drop_height_m = v * v / (2.0 * g);

  const Eigen::Vector2d face_slopes = draw_trial_pose(o, ti, tt);
  const ChainSimulation sim = simulate_trial_impact(setup, params, v, ti, tt);
  const TrialMotion motion{sim, v, g, o.foam || o.model != ModelKind::Model1};
  tt.dish_factors.clear();
  for (const Eigen::Vector2d& xy : mat_xy) {
    const double dist = (xy - tt.impact_point_m).norm();
    tt.dish_factors.push_back(o.mat_marker_motion == MatMarkerMotion::Dish
                                  ? std::exp(-std::pow((dist - o.dish_centre_m) / o.dish_width_m, 2))
                                  : 1.0);
  }
  summarise_contact(sim, face_slopes, tt);
  // What reaches the ADC: the analog force, through the amplifier's low-pass when there is one.
  const Eigen::VectorXd plate_grf_n =
      o.faults.amplifier_lowpass_hz > 0.0
          ? butterworth(sim.grf_n, kSimDt, o.faults.amplifier_lowpass_hz, o.faults.amplifier_lowpass_order)
          : sim.grf_n;
  const double tau25 = contact_to_trigger_s(o, plate_grf_n, fs, tt.id);
  const ForceRecord rec = record_force(setup, ti, sim, plate_grf_n, tau25, tt);
  fill_force_truth(setup, sim, motion, rec, tt);
  MarkerTracks2D tracks = render_markers(setup, ti, motion, face_slopes, tt);
  apply_gaps(setup, ti, tracks, tt);
  const Eigen::VectorXd& t_s = rec.t_s;
  const Eigen::MatrixXd& data = rec.data;

  TrialRecording& trial = out.trial;
  trial.spec = {tt.id, fmt::format("trials/{}", tt.id)};
  trial.tracks = std::move(tracks);
  trial.force.layout = ForceLayout::EightChannel;
  trial.force.sample_rate_hz = fs;
  trial.force.pretrigger_samples = npre;
  trial.force.trigger = fmt::format("Fz > {} N", o.trigger_threshold_n);
  trial.force.t_s = t_s;
  trial.force.data = data;
  return out;
}

}  // namespace detail

Eigen::Matrix<double, 8, 1> kistler_channels(const Eigen::Vector3d& f_n, const Eigen::Vector2d& cop_m, double a_m,
                                             double b_m, double az0_m) {
  // From ax = (Fx az0 - My) / Fz and ay = (Fy az0 + Mx) / Fz:
  const double my = f_n.x() * az0_m - cop_m.x() * f_n.z();
  const double mx = cop_m.y() * f_n.z() - f_n.y() * az0_m;
  // Fz = s1+s2+s3+s4, Mx/b = s1+s2-s3-s4, My/a = -s1+s2+s3-s4, and no twist
  // 0 = s1-s2+s3-s4: orthogonal rows of norm^2 4, so s = H^T rhs / 4.
  const double fz = f_n.z(), mxb = mx / b_m, mya = my / a_m;
  Eigen::Matrix<double, 8, 1> ch;
  ch << 0.5 * f_n.x(), 0.5 * f_n.x(), 0.5 * f_n.y(), 0.5 * f_n.y(),  //
      0.25 * (fz + mxb - mya), 0.25 * (fz + mxb + mya), 0.25 * (fz - mxb + mya), 0.25 * (fz - mxb - mya);
  return ch;
}

}  // namespace dropfit::synth

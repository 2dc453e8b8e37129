#pragma once
// Co-simulation of a fitted landing mat: a foot or impactor whose
// motion another simulator owns (a musculoskeletal model, a game engine, a
// MuJoCo body) steps the mat with its contact position and velocity and gets
// back the vertical force on it and the ground reaction force (GRF) under the
// mat. The mat is one of Models 1-4 of Mills, Pain & Yeadon (2006), Fig. 2,
// exactly as fitting/models.h defines them (same coordinates, same elements,
// same GRF), without the effect terms (cubic, hysteresis, Maxwell: Error).
//
// Inputs per step: penetration_m = the contact face's travel below the
// undeformed mat top (the mat at rest under its own weight), down positive,
// negative above the mat; velocity_m_s its rate (down positive); dt_s the
// time since the previous step. Outputs: foot_n = upward force of the mat on
// the foot (>= 0: the mat never pulls; Models 2 and 3 add their landing
// impulse, see below), grf_n = the plate's reading change from static.
// Gravity on the foot is the caller's business; the mat's own weight is
// static (deviation coordinates, as fitting::simulate).
//
// What each model means here:
//   Model 1: massless (k1, r1) on the ground. foot = GRF = k1 y + r1 y' while
//            the foot is on the surface and the element pushes. After a
//            separation the surface recovers on its own (k1 e + r1 e' = 0,
//            exactly) and contact resumes when the foot reaches it.
//   Model 4: the foot presses on massless (k1, r1) over m1 -(k2, r2)- m2
//            -(k3, r3)- ground. foot = k1 (y - y1) + r1 (y' - y1'), unilateral
//            as Model 1 (surface = m1 + relaxing compression when free);
//            GRF = k3 y2 + r3 y2'.
//   Models 2, 3 ("rigid top"): the foot carries the top mass (Model 2 m_eff,
//            Model 3 m1) while it presses: that mass follows the prescribed
//            foot motion exactly (position and velocity), and the foot feels
//            its inertia through the foot's acceleration, estimated from
//            successive velocities: foot = m_top (v_n - v_{n-1}) / dt + F of
//            the element under m_top. GRF = element on the ground (Model 2:
//            k1 y + r1 y'; Model 3: k2 y2 + r2 y2'). Separation when that foot
//            force turns negative (decided at the step's end): the top mass
//            then moves on its own. Landing (first contact or re-contact) is
//            a perfectly plastic collision, as in fitting::simulate: the top
//            mass takes the foot's velocity and the impulse m_top dv is
//            returned as the mean force over that step. In a closed loop the
//            inertia term is lagged one step: stable while m_top is smaller
//            than the foot's mass (the usual added-mass condition); for a
//            lighter foot, use Model 4 or a smaller dt.
//
// Integration: within a step the foot's travel is the cubic Hermite through
// (y, y') at both ends; each contact phase is linear, so the layer masses
// are advanced by the exact discrete form of that forced linear system (one
// matrix exponential of the state augmented with the polynomial input,
// cached per dt; Van Loan's construction), i.e. without a step-size limit:
// any dt is stable, and the result is exact up to the Hermite interpolation
// of the foot motion (fourth order in dt). Models 1 and 4: the separation
// instant (element 1's force crossing zero) and the landing instant (the
// foot reaching the surface) are located inside the step (regula falsi on
// the exact partial-step solution, linear interpolation of the gap), the
// remainder integrated in the new phase. Models 2 and 3 switch phase at the
// step's end.
//
// Usage (a point foot of mass M landing under gravity, semi-implicit Euler):
//
//   const auto fit = report::parse_fit_json(text, "fit.json");
//   fitting::MatContact mat(fit.model, fit.params);
//   double y = -0.01, v = 5.0;            // 1 cm above the mat, 5 m/s down
//   mat.reset(y, v);                      // optional: the foot's state at t = 0
//   for (int n = 0; n < 300; ++n) {
//     y += v * dt;                        // the caller's own integrator
//     const fitting::ContactForces f = mat.step(y, v, dt);
//     v += (g - f.foot_n / M) * dt;       // f.grf_n: what the plate reads
//   }
#include "fitting/models.h"

#include <Eigen/Core>

namespace dropfit::fitting {

struct ContactForces {
  double foot_n = 0.0;     // upward force of the mat on the foot
  double grf_n = 0.0;      // ground reaction force, zeroed with the mat at rest
  bool contact = false;    // the foot presses on the mat at the step's end
};

class MatContact {
 public:
  // Models 1-4, linear (params.has_effects() false); stiffness and damping
  // >= 0, the model's masses > 0 (Model 2: m_eff = 0 is Model 1). Throws
  // dropfit::Error otherwise. The mat starts at rest, the foot not touching.
  MatContact(ModelKind kind, const MatParams& params);

  // The mat back at rest and the foot at (penetration_m, velocity_m_s) now,
  // without advancing time (a foot already below the surface lands now). The
  // first step() without reset() assumes the foot came at constant velocity.
  void reset(double penetration_m, double velocity_m_s);

  // Advances the mat by dt_s > 0 to the foot's new state; forces at the
  // step's end. Throws dropfit::Error for a non-finite input or dt_s <= 0.
  ContactForces step(double penetration_m, double velocity_m_s, double dt_s);

  ModelKind kind() const { return kind_; }
  bool in_contact() const { return contact_; }
  // Mat travel below its rest position (m, down positive): the surface under
  // the foot (the top of element 1 in Models 1 and 4, the top mass in 2 and
  // 3) and the layer masses (Model 2: m_eff as layer 1; zero if absent).
  double surface_m() const;
  double layer1_m() const { return x_[0]; }
  double layer2_m() const { return x_[2]; }

 private:
  using Vec4 = Eigen::Vector4d;
  using Mat4 = Eigen::Matrix4d;
  struct Propagator {  // over a fraction L of the step
    Mat4 phi;          // free response
    Mat4 ry, rv;       // column m: response to forcing by * tau^m, bw * tau^m
  };
  void build(bool contact, Mat4& b, Vec4& by, Vec4& bw) const;
  Propagator make(bool contact, double fraction) const;
  Vec4 propagate(bool contact, const Vec4& z, const double poly[4], double s0, double s1) const;
  double element1_force(const Vec4& z, double y, double w) const;  // massless top, scaled state
  double relax_factor(double fraction) const;
  void set_dt(double dt_s);

  ModelKind kind_;
  bool rigid_top_ = false;
  int n_mass_ = 0, n_elem_ = 1;
  int upper_[3] = {0, 0, 0}, lower_[3] = {-1, -1, -1};
  double k_[3] = {0, 0, 0}, r_[3] = {0, 0, 0}, m_[3] = {0, 0, 0};  // m_[1], m_[2]: layer masses

  Vec4 x_ = Vec4::Zero();  // physical: y1, v1, y2, v2
  double e_ = 0.0;         // compression of the free element 1 (Models 1, 4)
  bool contact_ = false;
  bool started_ = false;
  double y_prev_ = 0.0, v_prev_ = 0.0;

  double dt_ = 0.0;
  Propagator full_[2];  // [0] free, [1] contact, fraction 1 of dt_
};

}  // namespace dropfit::fitting

#pragma once
// The generator's own mat physics: its own equations and its own integrator,
// sharing no code with fitting/ ("a generator that is not
// the fitter"). tests/generator_independence_test.cpp and a configure-time
// check in samples/generator/CMakeLists.txt fail if dropfit_synth links
// dropfit_fitting or includes a fitting/ header.
//
// Coordinates (as in Mills, Pain & Yeadon 2006, Fig. 2): every position is
// travel DOWNWARDS from where that point sat at first contact, the mat at
// rest under its own weight; the mat masses' weights are carried by the
// static pre-compression of the springs below them, so only the impactor
// feels gravity in these deviation coordinates, and the ground reaction
// force (GRF) is what a plate zeroed with the mat at rest reads.
//
//   Model 1: impactor M -[k1, r1]- ground (element 1's top is massless).
//   Model 2: impactor resting rigidly on the mat's effective mass m_eff while
//            in contact (a plastic collision at first contact);
//            m_eff -[k1, r1]- ground.
//   Model 3: impactor resting rigidly on the top layer m1 (plastic collision);
//            m1 -[k1, r1]- m2 -[k2, r2]- ground.
//   Model 4: impactor M -[k1, r1]- m1 -[k2, r2]- m2 -[k3, r3]- ground.
// The impactor-mat contact is unilateral (it pushes, never pulls); the
// layers and the ground are bilateral, so the GRF can dip below zero.
// Model 5 (area-elastic, geometric) is not generated here.
//
// Element 1 (k1, r1) carries the effects, each off by default:
//   F1 = e(d) * H(d') + r(d') d' + Fm
//   e(d)  = k1 d + k1_cubic d^3                      (cubic stiffening)
//   H(d') = 1 - h (1 - tanh(d' / v_h)) / 2            (elastic hysteresis: the
//           elastic force is (1 - h) times lower while element 1 extends)
//   r(d') = r1 while compressing, r1_unload (when >= 0) while extending
//   dFm/dt = maxwell_k d' - Fm / maxwell_tau           (a Maxwell arm beside it)
// d being element 1's compression. After separation element 1's top is
// free: it relaxes so that F1 = 0 (solved for d' at every evaluation).
//
// Integration: Dormand-Prince 5(4) with adaptive steps and error control
// (Hairer, Norsett & Wanner, Solving ODEs I, II.5), cubic Hermite dense
// output, and event location (separation, re-contact, the impactor caught
// at its apex) by the Illinois method on the dense output.
#include <Eigen/Core>
#include <functional>
#include <limits>
#include <ostream>
#include <type_traits>

namespace dropfit::synth {

enum class ModelKind { Model1 = 1, Model2 = 2, Model3 = 3, Model4 = 4, Model5 = 5 };

// A model number that also accepts another library's model enumeration
// with the same numbering (fitting::ModelKind), so code written against
// the older generator keeps compiling, without this library including it.
struct ModelChoice {
  int number = 4;
  constexpr ModelChoice() = default;
  constexpr ModelChoice(ModelKind k) : number(static_cast<int>(k)) {}  // NOLINT: implicit on purpose
  template <class E>
    requires std::is_enum_v<E>
  constexpr ModelChoice(E e) : number(static_cast<int>(e)) {}  // NOLINT: implicit on purpose
  constexpr ModelKind kind() const { return static_cast<ModelKind>(number); }
  friend constexpr bool operator==(ModelChoice a, ModelChoice b) { return a.number == b.number; }
  friend std::ostream& operator<<(std::ostream& os, ModelChoice m) { return os << "model" << m.number; }
};

// All parameters, SI (names as fitting::MatParams, plus the elastic hysteresis).
struct MatParams {
  double k1_n_m = 0.0, k2_n_m = 0.0, k3_n_m = 0.0;
  double r1_n_s_m = 0.0, r2_n_s_m = 0.0, r3_n_s_m = 0.0;
  double m_eff_kg = 0.0;            // Model 2
  double m1_kg = 0.0, m2_kg = 0.0;  // Models 3, 4
  double k1_cubic_n_m3 = 0.0;       // cubic stiffening of element 1
  double r1_unload_n_s_m = -1.0;    // element 1's damping while extending (negative = r1)
  double maxwell_k_n_m = 0.0;       // Maxwell arm beside element 1 (0 = off)
  double maxwell_tau_s = 0.0;
  double k1_hysteresis = 0.0;       // h: elastic force (1 - h) times lower while unloading (0 = off)
  double hysteresis_transition_m_s = 0.05;  // v_h of the tanh switch

  // Converts to any parameter struct with the same field names (e.g.
  // fitting::MatParams); the elastic hysteresis has no counterpart there.
  template <class P>
    requires requires(P p) {
      p.k1_n_m = 0.0;
      p.m_eff_kg = 0.0;
      p.r1_unload_n_s_m = 0.0;
      p.maxwell_tau_s = 0.0;
    } && (!std::is_same_v<P, MatParams>)
  operator P() const {  // NOLINT: implicit on purpose
    P p{};
    p.k1_n_m = k1_n_m, p.k2_n_m = k2_n_m, p.k3_n_m = k3_n_m;
    p.r1_n_s_m = r1_n_s_m, p.r2_n_s_m = r2_n_s_m, p.r3_n_s_m = r3_n_s_m;
    p.m_eff_kg = m_eff_kg, p.m1_kg = m1_kg, p.m2_kg = m2_kg;
    p.k1_cubic_n_m3 = k1_cubic_n_m3, p.r1_unload_n_s_m = r1_unload_n_s_m;
    p.maxwell_k_n_m = maxwell_k_n_m, p.maxwell_tau_s = maxwell_tau_s;
    return p;
  }
};

// ---- The integrator -----------------------------------------------------------

using OdeState = Eigen::Matrix<double, 8, 1>;
using OdeRhs = std::function<OdeState(double t, const OdeState& y)>;

struct OdeOptions {
  double rtol = 1e-9;
  double atol = 1e-12;
  double h_initial_s = 1e-6;
  double h_max_s = 2e-4;
};

// One accepted step with its dense output (cubic Hermite through y0, f0, y1, f1).
struct OdeStep {
  double t0 = 0.0, t1 = 0.0;
  OdeState y0, y1, f0, f1;
  OdeState at(double t) const;
};

// Dormand-Prince 5(4), FSAL, with the standard PI-free step control
// (safety 0.9, growth within [0.2, 5]).
class DormandPrince {
 public:
  DormandPrince(OdeRhs f, double t0, const OdeState& y0, const OdeOptions& options = {});
  // Advances by one accepted step, never beyond t_stop.
  OdeStep step(double t_stop);
  // Starts again from (t, y) (after an event changed the equations).
  void restart(double t, const OdeState& y);
  double t() const { return t_; }
  const OdeState& y() const { return y_; }
  long n_rhs() const { return n_rhs_; }

 private:
  OdeRhs f_;
  OdeOptions o_;
  double t_ = 0.0, h_ = 0.0;
  OdeState y_, f0_;
  long n_rhs_ = 0;
};

// ---- The mat ------------------------------------------------------------------

struct ChainImpact {
  double mass_kg = 24.0;
  double velocity_m_s = 5.0;  // downward at first contact
  double gravity_m_s2 = 9.81;
  double duration_s = 0.3;    // from first contact
  double output_dt_s = 1e-5;  // spacing of the returned samples, from t = 0
  // After separation: false = the impactor flies freely and may land again;
  // true = it is caught at the top of its rebound (a lab's catcher) and held.
  bool catch_at_apex = false;
  OdeOptions ode;
};

struct ChainSimulation {
  Eigen::VectorXd t_s;          // i * output_dt_s from first contact
  Eigen::VectorXd grf_n;        // ground reaction force (plate zeroed with the mat at rest)
  Eigen::VectorXd contact_n;    // impactor-mat contact force
  Eigen::VectorXd impactor_m;   // impactor face travel below the undeformed mat top
  Eigen::VectorXd impactor_v_m_s;
  Eigen::VectorXd surface_m;    // mat top under the impactor (element 1's top; the rigid mass in Models 2, 3)
  Eigen::VectorXd layer1_m, layer2_m;  // travel of the mat masses (Model 2: m_eff; 3, 4: m1, m2)
  Eigen::VectorXd layer1_v_m_s, layer2_v_m_s;
  Eigen::VectorXd maxwell_n;    // Maxwell arm force
  double separation_s = std::numeric_limits<double>::quiet_NaN();  // first separation
  double caught_s = std::numeric_limits<double>::quiet_NaN();      // impactor caught (catch_at_apex)
  int n_contacts = 0;           // landings (1 + re-contacts)
  long n_rhs = 0;               // right-hand-side evaluations
};

// Throws dropfit::Error for parameters the model cannot use (negative
// stiffness or damping, a missing mass, h outside [0, 1), Model 5).
ChainSimulation simulate_chain(ModelChoice model, const MatParams& params, const ChainImpact& impact);

// Element 1's force law (above), public for the tests.
double element1_force_n(const MatParams& p, double d_m, double d_rate_m_s, double maxwell_n);

}  // namespace dropfit::synth

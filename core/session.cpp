#include "core/session.h"

namespace dropfit {

double MatSpec::thickness_m() const {
  double sum = 0.0;
  for (const LayerSpec& layer : layers) sum += layer.thickness_m;
  return sum;
}

double MatSpec::mass_kg() const {
  double sum = 0.0;
  for (const LayerSpec& layer : layers) sum += layer.mass_kg;
  return sum;
}

}  // namespace dropfit

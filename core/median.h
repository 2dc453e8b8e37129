#pragma once
// The median of a sample: the middle value, or the mean of the two middle
// values of an even count; NaN for an empty sample. Takes a copy it may
// reorder.
#include <algorithm>
#include <cstddef>
#include <limits>
#include <vector>

namespace dropfit {

inline double median(std::vector<double> v) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  double m = *mid;
  if (v.size() % 2 == 0) m = 0.5 * (m + *std::max_element(v.begin(), mid));
  return m;
}

}  // namespace dropfit

#pragma once
// Range checks for option structs: each throws dropfit::Error naming the
// options (`where`, e.g. "forceplate options"), the field and the value, so
// that a stage refuses a NaN, a negative rate or a zero count at its entry
// instead of computing nonsense from it. Used by the stages' validate().
#include <string_view>

namespace dropfit::check {

// Finite and > 0.
void positive(std::string_view where, std::string_view field, double value);
// Finite and >= 0.
void non_negative(std::string_view where, std::string_view field, double value);
// Finite (any sign).
void finite(std::string_view where, std::string_view field, double value);
// Finite and within [lo, hi]; `upper_open`: within [lo, hi).
void in_range(std::string_view where, std::string_view field, double value, double lo, double hi,
              bool upper_open = false);
// value >= min.
void at_least(std::string_view where, std::string_view field, long long value, long long min);
// min <= value <= max.
void int_in_range(std::string_view where, std::string_view field, long long value, long long min, long long max);

}  // namespace dropfit::check

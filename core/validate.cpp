#include "core/validate.h"

#include <fmt/format.h>

#include <cmath>

#include "core/error.h"

namespace dropfit::check {
namespace {

[[noreturn]] void fail(std::string_view where, std::string_view field, double value, std::string_view want) {
  throw Error(fmt::format("{}: {} = {} ({})", where, field, value, want));
}

}  // namespace

void positive(std::string_view where, std::string_view field, double value) {
  if (!(std::isfinite(value) && value > 0.0)) fail(where, field, value, "must be a positive finite number");
}

void non_negative(std::string_view where, std::string_view field, double value) {
  if (!(std::isfinite(value) && value >= 0.0)) fail(where, field, value, "must be a finite number, 0 or more");
}

void finite(std::string_view where, std::string_view field, double value) {
  if (!std::isfinite(value)) fail(where, field, value, "must be a finite number");
}

void in_range(std::string_view where, std::string_view field, double value, double lo, double hi, bool upper_open) {
  const bool ok = std::isfinite(value) && value >= lo && (upper_open ? value < hi : value <= hi);
  if (!ok) fail(where, field, value, fmt::format("must be within [{}, {}{}", lo, hi, upper_open ? ")" : "]"));
}

void at_least(std::string_view where, std::string_view field, long long value, long long min) {
  if (value < min) throw Error(fmt::format("{}: {} = {} (must be {} or more)", where, field, value, min));
}

void int_in_range(std::string_view where, std::string_view field, long long value, long long min, long long max) {
  if (value < min || value > max)
    throw Error(fmt::format("{}: {} = {} (must be {} to {})", where, field, value, min, max));
}

}  // namespace dropfit::check

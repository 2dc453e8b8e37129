#include "core/error.h"

#include <fmt/format.h>

namespace dropfit {
namespace {
std::string describe(const std::string& file, int line, int column, const std::string& field,
                     const std::string& reason) {
  std::string where = file;
  if (line > 0) where += fmt::format(":{}", line);
  if (column > 0) where += fmt::format(":{}", column);
  if (!field.empty()) where += fmt::format(" [{}]", field);
  return fmt::format("{}: {}", where, reason);
}
}  // namespace

InputError::InputError(std::string file, int line, int column, std::string field, std::string reason)
    : Error(describe(file, line, column, field, reason)),
      file_(std::move(file)),
      line_(line),
      column_(column),
      field_(std::move(field)),
      reason_(std::move(reason)) {}

}  // namespace dropfit

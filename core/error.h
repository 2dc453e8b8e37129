#pragma once
// Errors a user can cause (bad files, impossible geometry) are exceptions,
// caught once in the command line's main. Broken invariants are assertions.
#include <stdexcept>
#include <string>

namespace dropfit {

// Something about the data or the request that a user must fix.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A problem located in an input file: names the file, the line (1-based,
// 0 when the file as a whole is at fault), the column (1-based, 0 when not
// known) and the field (column name or manifest key), then says why.
class InputError : public Error {
 public:
  InputError(std::string file, int line, int column, std::string field, std::string reason);

  const std::string& file() const { return file_; }
  int line() const { return line_; }
  int column() const { return column_; }
  const std::string& field() const { return field_; }
  const std::string& reason() const { return reason_; }

 private:
  std::string file_;
  int line_;
  int column_;
  std::string field_;
  std::string reason_;
};

}  // namespace dropfit
